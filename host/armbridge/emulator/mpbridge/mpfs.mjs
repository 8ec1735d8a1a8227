// Firmware files into the MicroPython WebAssembly interpreter's filesystem:
// the one piece the emulator's bridge (bridge.mjs) and the firmware unit-test
// runner (tests/mpy/run_tests.mjs) share.
//
// `@micropython.native` / `@micropython.viper` lines are commented out on the
// way: this port has no native emitter (they are a SyntaxError there), and
// nothing else about the source is changed.

import fs from "node:fs";
import path from "node:path";

export function mkdirs(FS, dir) {
  let cur = "";
  for (const part of dir.split("/").filter(Boolean)) {
    cur += "/" + part;
    try { FS.mkdir(cur); } catch (e) { /* exists */ }
  }
}

export function stripNative(src) {
  return src.replace(/^(\s*)@micropython\.(native|viper)\b.*$/gm, "$1# (stripped) @micropython.$2");
}

// Copies the *.py files of host folder `from` that pass `filter` (sorted by
// name) to interpreter folder `to`; returns their names.
export function copyPy(FS, from, to, filter = () => true) {
  const names = fs.readdirSync(from).filter((n) => n.endsWith(".py") && filter(n)).sort();
  mkdirs(FS, to);
  for (const n of names) {
    FS.writeFile(to + "/" + n, stripNative(fs.readFileSync(path.join(from, n), "utf8")));
  }
  return names;
}
