// The board's Cartesian IK (firmware/esp32/ik3r.py + mlp.py) under the real
// MicroPython interpreter (the WebAssembly port from npm), on targets given by
// the caller: tests/test_board_ik.py and `armbridge bench board-ik` use it.
//
//   node tests/mpy/board_ik.mjs REPO_ROOT WEIGHTS_FILE < targets.json > results.json
//
// stdin: {"targets": [[x_m, y_m, theta_rad], ...], "config": {NAME: value, ...}}
// ("config" optional: attributes set on the firmware config before BoardIK is built).
// stdout: one JSON object: {"q": [[q1, q2, q3] | null, ...], "error_m": [...],
// "guess": [[q1, q2, q3], ...] (the int8 net alone; only with "time_net": true), "native": bool (mlp.NATIVE),
// "macs": int, "ram_bytes": int, "us_solve": total us of the solves,
// "us_net": total us of the nets alone, "heap_used": bytes}. Times are
// MicroPython's time.ticks_us. Exit status 2 when it could not run.

import fs from "node:fs";
import path from "node:path";
import { pathToFileURL } from "node:url";

import { copyPy, mkdirs } from "../../host/armbridge/emulator/mpbridge/mpfs.mjs";

const root = path.resolve(process.argv[2] || ".");
const weights = process.argv[3];
const pkg = path.join(root, "node_modules", "@micropython",
  "micropython-webassembly-pyscript", "micropython.mjs");

async function main() {
  if (!fs.existsSync(pkg)) {
    console.error("micropython package missing: " + pkg);
    process.exit(2);
  }
  const input = fs.readFileSync(0, "utf8");
  const { loadMicroPython } = await import(pathToFileURL(pkg).href);
  const mp = await loadMicroPython({
    heapsize: 16 * 1024 * 1024,
    stdout: (line) => process.stderr.write(line + "\n"),
    stderr: (line) => process.stderr.write(line + "\n"),
  });
  const FS = mp.FS;
  copyPy(FS, path.join(root, "firmware", "esp32"), "/fw",
    (n) => n === "config.py" || n === "mlp.py" || n === "ik3r.py");
  mkdirs(FS, "/io");
  FS.writeFile("/io/in.json", input);
  FS.writeFile("/io/weights.bin", fs.readFileSync(weights));
  mp.runPython(`
import sys, gc, json, time
sys.path.insert(0, "/fw")
import config, mlp, ik3r
with open("/io/in.json") as f:
    _inp = json.load(f)
for _k, _v in (_inp.get("config") or {}).items():
    setattr(config, _k, _v)
with open("/io/weights.bin", "rb") as f:
    _w = f.read()
gc.collect()
_free0 = gc.mem_free()
_ik = ik3r.BoardIK(config, _w)
gc.collect()
_heap = _free0 - gc.mem_free()
_t = _inp["targets"]
_q = []
_err = []
_t0 = time.ticks_us()
for _p in _t:
    _r = _ik.solve(_p[0], _p[1], _p[2])
    _q.append(_r)
    _err.append(_ik.error)
_us_solve = time.ticks_diff(time.ticks_us(), _t0)
_g = []
_t0 = time.ticks_us()
for _p in (_t if _inp.get("time_net") else ()):
    _g.append(_ik.guess(_p[0], _p[1], _p[2]))
_us_net = time.ticks_diff(time.ticks_us(), _t0)
with open("/io/out.json", "w") as f:
    json.dump({"q": _q, "error_m": _err, "guess": _g, "native": mlp.NATIVE,
               "macs": _ik.net.macs(), "ram_bytes": _ik.net.ram_bytes(),
               "heap_used": _heap, "us_solve": _us_solve, "us_net": _us_net}, f)
`);
  process.stdout.write(FS.readFile("/io/out.json", { encoding: "utf8" }) + "\n");
}

main().catch((e) => {
  console.error("board_ik runner error: " + (e && e.message ? e.message : e));
  process.exit(2);
});
