// Runs a Python script under the real MicroPython interpreter (the WebAssembly
// port from npm) with firmware/esp32 on its path (firmware/common at /fwc and
// firmware/masr_ma at /fwma, the emulator's bridge modules at /bridge, for a
// script to put on its path), and prints what
// the script wrote to /io/out.json: tests/test_pca9685.py runs the PCA9685
// driver and the servo bank this way, tests/test_hal_ma_micropython.py the MA's HAL.
//
//   node tests/mpy/run_script.mjs REPO_ROOT < script.py > out.json
//
// Exit status 2 when it could not run; a Python exception is printed on stderr
// and exits 1.

import fs from "node:fs";
import path from "node:path";
import { pathToFileURL } from "node:url";

import { copyPy, mkdirs } from "../../host/armbridge/emulator/mpbridge/mpfs.mjs";

const root = path.resolve(process.argv[2] || ".");
const pkg = path.join(root, "node_modules", "@micropython",
  "micropython-webassembly-pyscript", "micropython.mjs");

async function main() {
  if (!fs.existsSync(pkg)) {
    console.error("micropython package missing: " + pkg);
    process.exit(2);
  }
  const script = fs.readFileSync(0, "utf8");
  const { loadMicroPython } = await import(pathToFileURL(pkg).href);
  const mp = await loadMicroPython({
    heapsize: 4 * 1024 * 1024,
    stdout: (line) => process.stderr.write(line + "\n"),
    stderr: (line) => process.stderr.write(line + "\n"),
  });
  const FS = mp.FS;
  copyPy(FS, path.join(root, "firmware", "esp32"), "/fw");
  copyPy(FS, path.join(root, "firmware", "common"), "/fwc");
  copyPy(FS, path.join(root, "firmware", "masr_ma"), "/fwma");
  copyPy(FS, path.join(root, "host", "armbridge", "emulator", "mpbridge"), "/bridge");
  mkdirs(FS, "/io");
  try {
    mp.runPython("import sys\nsys.path.insert(0, '/fw')\n" + script);
  } catch (e) {
    console.error(String(e));
    process.exit(1);
  }
  process.stdout.write(FS.readFile("/io/out.json", { encoding: "utf8" }) + "\n");
}

main().catch((e) => { console.error(e); process.exit(2); });
