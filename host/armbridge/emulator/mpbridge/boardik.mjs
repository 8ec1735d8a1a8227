// The board's Cartesian IK (firmware/esp32/ik3r.py + mlp.py) under the real
// MicroPython interpreter (the WebAssembly port from npm), on targets given by
// the caller: armbridge.bench.board_ik.under_micropython runs it, for
// `armbridge bench board-ik` and tests/test_board_ik.py.
//
//   node boardik.mjs MICROPYTHON_MJS FIRMWARE_DIR WEIGHTS_FILE < in.json > out.json
//
// FIRMWARE_DIR holds config.py, mlp.py and ik3r.py (copied into the interpreter's
// filesystem with the viper decorators stripped, as everywhere: mpfs.mjs).
// stdin: {"targets": [[x_m, y_m, theta_rad], ...], "time": bool, "config": {NAME: value}}
// ("config": attributes set on the firmware config before BoardIK is built).
// stdout: one JSON object: {"q": [[q1, q2, q3] | null, ...], "error_m": [...] (-1
// outside the disc), "native": mlp.NATIVE, "macs", "ram_bytes" (mlp's buffers),
// "heap_bytes" (the heap BoardIK took), "us_solve" (all solves); with "time" also
// "guess" (the net's q per target), "us_net" (all nets alone) and "us_refine" (all
// FABRIK passes alone, from the net's q)}. Times from performance.now(). Exit 2:
// it could not run.

import fs from "node:fs";
import { pathToFileURL } from "node:url";

import { copyPy, mkdirs } from "./mpfs.mjs";

const [pkg, fwDir, weights] = process.argv.slice(2);

async function main() {
  if (!pkg || !fwDir || !weights) {
    console.error("usage: boardik.mjs MICROPYTHON_MJS FIRMWARE_DIR WEIGHTS_FILE < in.json");
    process.exit(2);
  }
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
  mp.registerJsModule("jsclock", { us: () => performance.now() * 1000 });
  const FS = mp.FS;
  copyPy(FS, fwDir, "/fw",
    (n) => n === "config.py" || n === "mlp.py" || n === "ik3r.py");
  mkdirs(FS, "/io");
  FS.writeFile("/io/in.json", input);
  FS.writeFile("/io/weights.bin", fs.readFileSync(weights));
  mp.runPython(`
import sys, gc, json
import jsclock
sys.path.insert(0, "/fw")
import config, mlp, ik3r
with open("/io/in.json") as f:
    _inp = json.load(f)
for _k, _v in (_inp.get("config") or {}).items():
    setattr(config, _k, _v)
with open("/io/weights.bin", "rb") as f:
    _w = f.read()
`);
  // Three calls: this port frees garbage only between calls (control back in JS).
  mp.runPython("gc.collect(); _free0 = gc.mem_free()");
  mp.runPython("_ik = ik3r.BoardIK(config, _w)");
  mp.runPython("gc.collect(); _heap = _free0 - gc.mem_free()");
  mp.runPython(`
_out = {"native": mlp.NATIVE, "macs": _ik.net.macs(), "ram_bytes": _ik.net.ram_bytes(), "heap_bytes": _heap}
_t = _inp["targets"]
_q = []
_err = []
_t0 = jsclock.us()
for _p in _t:
    _q.append(_ik.solve(_p[0], _p[1], _p[2]))
    _err.append(_ik.error)
_out["us_solve"] = jsclock.us() - _t0
_out["q"] = _q
_out["error_m"] = _err
if _inp.get("time"):
    _g = []
    _t0 = jsclock.us()
    for _p in _t:
        _g.append(_ik.guess(_p[0], _p[1], _p[2]))
    _out["us_net"] = jsclock.us() - _t0
    _t0 = jsclock.us()
    for _i in range(len(_t)):
        _p = _t[_i]
        _ik.refine(_p[0], _p[1], _p[2], _g[_i], _ik.passes)
    _out["us_refine"] = jsclock.us() - _t0
    _out["guess"] = _g
with open("/io/out.json", "w") as f:
    json.dump(_out, f)
`);
  process.stdout.write(FS.readFile("/io/out.json", { encoding: "utf8" }) + "\n");
}

main().catch((e) => {
  console.error("board_ik runner error: " + (e && e.message ? e.message : e));
  process.exit(2);
});
