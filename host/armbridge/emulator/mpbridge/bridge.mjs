// A MicroPython board in Node: the real MicroPython interpreter (the WebAssembly
// port from npm, @micropython/micropython-webassembly-pyscript) running the
// firmware on the bridge HAL of bridgehal.py.
//
//   node bridge.mjs MICROPYTHON_MJS HEAP_BYTES BOARD_MODULE CONFIG_MODULE MODE DIR...
//
// DIRs are the firmware folders in import order (e.g. firmware/esp32 then
// firmware/common); their *.py files are copied into the interpreter's
// filesystem, one folder each, ahead of this folder's bridgehal.py,
// bridgerigs.py, fwcost.py and fwcost_mp.py on sys.path. `@micropython.native` / `@micropython.viper` lines are
// commented out on the way (this port has no native emitter), as in
// tests/mpy/run_tests.mjs; nothing else is changed.
//
// MODE "serve": prints `READY <micropython version>`, then answers every line
// on stdin with one line on stdout (bridgehal.step; the protocol is in
// bridgehal.py's docstring) until stdin closes. Reading and writing are
// synchronous, so that a question in the middle of a step (jsbridge.ask: a
// `?` line out, its answer line in) is answered before the step goes on. MODE "bench:<json>": runs
// fwcost.py's items through fwcost_mp.py (mp_start(<json>), mp_run per item,
// heap marks between them, mp_result) and prints
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
  mp.registerJsModule("jsbridge", { ask: (line) => { writeLine(line); return readLine(); } });
  const FS = mp.FS;
  const paths = [];
  dirs.forEach((d, i) => {
    copyPy(FS, d, "/fw/" + i);
    paths.push("/fw/" + i);
  });
  copyPy(FS, here, "/bridge", (n) => ["bridgehal.py", "bridgerigs.py", "fwcost.py", "fwcost_mp.py"].includes(n));
  paths.push("/bridge");
  mp.runPython(`
import sys
sys.path[:] = ${JSON.stringify(paths)}
import bridgehal
import bridgerigs
bridgehal.setup(${JSON.stringify(boardModule)}, ${JSON.stringify(configModule)})
_version = "%d.%d.%d" % sys.implementation.version[:3]
`);
  if (mode.startsWith("bench:")) {
    // One call per item, a collection between them: this port collects
    // garbage only when control is back in JS, so within a call the heap
    // just grows (give it room: HEAP_BYTES).
    // The heap is measured in calls of their own, after a collection there
    // (inside a call the garbage of that call is not collected yet).
    const fwcost = mp.pyimport("fwcost_mp");
    const mark = (what) => mp.runPython(`import gc; gc.collect(); import fwcost_mp; fwcost_mp.heap_mark("${what}")`);
    mark("base");
    const items = JSON.parse(fwcost.mp_start(mode.slice(6)));
    mark("after_boot");
    const measured = { lines: {}, ticks: {}, codec: {} };
    for (const name of items) {
      mp.runPython("import gc; gc.collect()");
      const [group, n, st] = JSON.parse(fwcost.mp_run(name));
      measured[group][n] = st;
      mp.runPython("import gc; gc.collect(); import fwcost_mp; fwcost_mp.heap_mark_item()");
    }
    mark("after_run");
    process.stdout.write(JSON.stringify(Object.assign(JSON.parse(fwcost.mp_result()), measured)) + "\n");
    return;
  }
  if (mode !== "serve") fail("unknown mode " + mode);
  const step = mp.pyimport("bridgehal").step;
  writeLine("READY " + mp.globals.get("_version"));
  for (;;) {
    const line = readLine();
    let answer;
    try {
      answer = step(line);
    } catch (e) {
      answer = "CRASHED\t!" + JSON.stringify("bridge: " + (e && e.message ? e.message : String(e)));
    }
    writeLine(answer);
  }
}

// ------------------------------------------------------------ synchronous lines
const chunk = Buffer.alloc(1 << 16);
const nap = new Int32Array(new SharedArrayBuffer(4));
let pending = "";

function writeLine(text) {
  const data = Buffer.from(text + "\n", "latin1");
  let off = 0;
  while (off < data.length) {
    try {
      off += fs.writeSync(1, data, off);
    } catch (e) {
      if (e.code !== "EAGAIN") throw e;
      Atomics.wait(nap, 0, 0, 1);
    }
  }
}

// The next line of stdin (without its newline); stdin's end ends the process.
function readLine() {
  for (;;) {
    const nl = pending.indexOf("\n");
    if (nl >= 0) {
      const line = pending.slice(0, nl);
      pending = pending.slice(nl + 1);
      return line;
    }
    let n;
    try {
      n = fs.readSync(0, chunk, 0, chunk.length, null);
    } catch (e) {
      if (e.code === "EAGAIN") {
        Atomics.wait(nap, 0, 0, 1);
        continue;
      }
      if (e.code === "EOF") process.exit(0);
      throw e;
    }
    if (n === 0) process.exit(0);
    pending += chunk.toString("latin1", 0, n);
  }
}

main().catch((e) => fail(e && e.stack ? e.stack : String(e)));
