// A MicroPython board in Node: the real MicroPython interpreter (the WebAssembly
// port from npm, @micropython/micropython-webassembly-pyscript) running the
// firmware on the bridge HAL of bridgehal.py.
//
//   node bridge.mjs MICROPYTHON_MJS HEAP_BYTES BOARD_MODULE CONFIG_MODULE MODE DIR...
//
// DIRs are the firmware folders in import order (e.g. firmware/esp32 then
// firmware/common); their *.py files are copied into the interpreter's
// filesystem, one folder each, ahead of this folder's bridgehal.py and
// fwcost.py on sys.path. `@micropython.native` / `@micropython.viper` lines are
// commented out on the way (this port has no native emitter), as in
// tests/mpy/run_tests.mjs; nothing else is changed.
//
// MODE "serve": prints `READY <micropython version>`, then answers every line
// on stdin with one line on stdout (bridgehal.step; the protocol is in
// bridgehal.py's docstring) until stdin closes. MODE "bench:<json>": runs
// fwcost.py's items (mp_start(<json>), mp_run per item, mp_result) and prints
// the JSON result as one line. What the
// firmware prints goes to stderr. Exit status 2: it could not start.

import fs from "node:fs";
import path from "node:path";
import { fileURLToPath, pathToFileURL } from "node:url";

import { copyPy } from "./mpfs.mjs";

const here = path.dirname(fileURLToPath(import.meta.url));
const [mjs, heap, boardModule, configModule, mode, ...dirs] = process.argv.slice(2);

function fail(msg) {
  process.stderr.write("bridge: " + msg + "\n");
  process.exit(2);
}

async function main() {
  if (!mjs || !fs.existsSync(mjs)) fail("MicroPython package not found: " + mjs);
  if (!mode || dirs.length === 0) fail("usage: bridge.mjs MICROPYTHON_MJS HEAP BOARD CONFIG MODE DIR...");
  const { loadMicroPython } = await import(pathToFileURL(mjs).href);
  const mp = await loadMicroPython({
    heapsize: parseInt(heap, 10),
    stdout: (line) => process.stderr.write("micropython: " + line + "\n"),
    stderr: (line) => process.stderr.write("micropython: " + line + "\n"),
  });
  // The bench's clock: time.ticks_us() of this port counts whole milliseconds.
  mp.registerJsModule("jsclock", { us: () => performance.now() * 1000 });
  const FS = mp.FS;
  const paths = [];
  dirs.forEach((d, i) => {
    copyPy(FS, d, "/fw/" + i);
    paths.push("/fw/" + i);
  });
  copyPy(FS, here, "/bridge", (n) => n === "bridgehal.py" || n === "fwcost.py");
  paths.push("/bridge");
  mp.runPython(`
import sys
sys.path[:] = ${JSON.stringify(paths)}
import bridgehal
bridgehal.setup(${JSON.stringify(boardModule)}, ${JSON.stringify(configModule)})
_version = "%d.%d.%d" % sys.implementation.version[:3]
`);
  if (mode.startsWith("bench:")) {
    // One call per item, a collection between them: this port collects
    // garbage only when control is back in JS, so within a call the heap
    // just grows (give it room: HEAP_BYTES).
    const fwcost = mp.pyimport("fwcost");
    const items = JSON.parse(fwcost.mp_start(mode.slice(6)));
    for (const name of items) {
      mp.runPython("import gc; gc.collect()");
      fwcost.mp_run(name);
    }
    process.stdout.write(fwcost.mp_result() + "\n");
    return;
  }
  if (mode !== "serve") fail("unknown mode " + mode);
  const step = mp.pyimport("bridgehal").step;
  process.stdout.write("READY " + mp.globals.get("_version") + "\n");
  let pending = "";
  process.stdin.setEncoding("latin1");
  process.stdin.on("data", (chunk) => {
    pending += chunk;
    let nl;
    while ((nl = pending.indexOf("\n")) >= 0) {
      const line = pending.slice(0, nl);
      pending = pending.slice(nl + 1);
      let answer;
      try {
        answer = step(line);
      } catch (e) {
        answer = "CRASHED\t!" + JSON.stringify("bridge: " + (e && e.message ? e.message : String(e)));
      }
      process.stdout.write(answer + "\n");
    }
  });
  process.stdin.on("end", () => process.exit(0));
}

main().catch((e) => fail(e && e.stack ? e.stack : String(e)));
