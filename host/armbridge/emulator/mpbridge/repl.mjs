// The raw REPL's executor: the real MicroPython interpreter (the WebAssembly
// port from npm) running the programs an emulated board's REPL receives
// (armbridge/emulator/repl.py), on the board's filesystem (replfs.py's
// BoardFs, mounted at /).
//
//   node repl.mjs MICROPYTHON_MJS HEAP_BYTES
//
// Prints `READY <micropython version>`, then answers each line on stdin with
// one line on stdout:
//   F NAME HEX      put a file into the filesystem (the emulator's copy)  -> OK
//   D NAME          make a folder                                         -> OK
//   X HEX           run a program (utf-8 source, hex)
//                   -> R OUT_HEX ERR_HEX RESET CHANGES_HEX
// OUT/ERR are what it printed and its traceback, RESET is "-", "hard" or
// "soft" (machine.reset() / soft_reset()), CHANGES a JSON list of the
// filesystem changes it made (["w", name, hex], ["rm", name], ["mkdir", name],
// ["rmdir", name], ["mv", a, b]). Exit status 2: it could not start.

import fs from "node:fs";
import path from "node:path";
import { fileURLToPath, pathToFileURL } from "node:url";

const here = path.dirname(fileURLToPath(import.meta.url));
const [mjs, heap] = process.argv.slice(2);

function fail(msg) {
  process.stderr.write("repl: " + msg + "\n");
  process.exit(2);
}

const hex = (s) => Buffer.from(s, "utf8").toString("hex") || "-";

async function main() {
  if (!mjs || !fs.existsSync(mjs)) fail("MicroPython package not found: " + mjs);
  const { loadMicroPython } = await import(pathToFileURL(mjs).href);
  let stray = "";  // what a module's own print wrote (not the captured print)
  const mp = await loadMicroPython({
    heapsize: parseInt(heap, 10),
    stdout: (line) => { stray += line + "\n"; },
    stderr: (line) => { stray += line + "\n"; },
  });
  mp.FS.mkdir("/bridge");
  mp.FS.writeFile("/bridge/replfs.py", fs.readFileSync(path.join(here, "replfs.py"), "utf8"));
  mp.runPython(`
import sys
sys.path.insert(0, "/bridge")
import io, os, json, binascii, hashlib
import replfs
sys.path.pop(0)
replfs.setup()
_version = "%d.%d.%d" % sys.implementation.version[:3]
`);
  const replfs = mp.pyimport("replfs");
  process.stdout.write("READY " + mp.globals.get("_version") + "\n");
  let pending = "";
  process.stdin.setEncoding("latin1");
  process.stdin.on("data", (chunk) => {
    pending += chunk;
    let nl;
    while ((nl = pending.indexOf("\n")) >= 0) {
      const line = pending.slice(0, nl);
      pending = pending.slice(nl + 1);
      process.stdout.write(answer(line) + "\n");
    }
  });
  process.stdin.on("end", () => process.exit(0));

  function answer(line) {
    const [cmd, a, b] = line.split(" ");
    try {
      if (cmd === "F") {
        mp.globals.set("_name", a);
        mp.globals.set("_data", b === "-" ? "" : b);
        mp.runPython("replfs.fs.files[_name] = binascii.unhexlify(_data)");
        return "OK";
      }
      if (cmd === "D") {
        mp.globals.set("_name", a);
        mp.runPython("replfs.fs.dirs.add(_name)");
        return "OK";
      }
      if (cmd === "X") {
        stray = "";
        const res = replfs.run_hex(a).split(" ");
        if (stray) res[0] = hex(stray + (res[0] === "-" ? "" : Buffer.from(res[0], "hex").toString("utf8")));
        return "R " + res.join(" ");
      }
      return "E " + hex("unknown request " + cmd);
    } catch (e) {
      return "E " + hex(e && e.message ? e.message : String(e));
    }
  }
}

main().catch((e) => fail(e && e.stack ? e.stack : String(e)));
