// Runs the firmware unit tests (tests/firmware/test_*.py) under a real
// MicroPython interpreter: the WebAssembly port from npm
// (@micropython/micropython-webassembly-pyscript).
//
//   node tests/mpy/run_tests.mjs [REPO_ROOT]
//
// The repo layout is mirrored in the interpreter's filesystem under /repo
// (firmware/common/*.py, the generated protocol table protodef.py among them,
// firmware/esp32/{config,arm,arm_cal,arm_pen,ik3r,mlp}.py, firmware/masr_ma/*.py but its
// machine-bound hal_ma.py and main.py, tests/firmware/*.py,
// tests/vectors/lines.json), so the tests find the vectors (and the MA tests
// masr_ma's config.py) relative to their own files, as under CPython.
// firmware/masr_ma is last on the path: the flat name `config` is the arm's,
// as in tests/firmware/conftest.py. `@micropython.native` / `@micropython.viper`
// decorators are commented out (this port has no native emitter).
// Prints one line per test, `PASS module::name` or `FAIL module::name: error`
// (a traceback follows, indented), then `SUMMARY passed=N failed=M`.
// Exit status: 0 when every test passed, 1 otherwise, 2 when it could not run.

import fs from "node:fs";
import path from "node:path";
import { fileURLToPath, pathToFileURL } from "node:url";

import { copyPy, mkdirs } from "../../host/armbridge/emulator/mpbridge/mpfs.mjs";

const here = path.dirname(fileURLToPath(import.meta.url));
const root = path.resolve(process.argv[2] || path.join(here, "..", ".."));
const pkg = path.join(root, "node_modules", "@micropython",
  "micropython-webassembly-pyscript", "micropython.mjs");

function copyRepo(FS, relDir, filter) {
  return copyPy(FS, path.join(root, relDir), "/repo/" + relDir, filter);
}

async function main() {
  if (!fs.existsSync(pkg)) {
    console.error("micropython package missing: " + pkg);
    process.exit(2);
  }
  const { loadMicroPython } = await import(pathToFileURL(pkg).href);
  const mp = await loadMicroPython({
    heapsize: 4 * 1024 * 1024,
    stdout: (line) => process.stdout.write(line + "\n"),
    stderr: (line) => process.stderr.write(line + "\n"),
  });
  const FS = mp.FS;
  const common = copyRepo(FS, "firmware/common");
  if (!common.includes("protodef.py")) {
    console.error("firmware/common/protodef.py missing (python -m armbridge.link.codegen writes it)");
    process.exit(2);
  }
  copyRepo(FS, "firmware/esp32", (n) => ["config.py", "arm.py", "arm_cal.py", "arm_pen.py", "ik3r.py", "mlp.py"].includes(n));
  const ma = copyRepo(FS, "firmware/masr_ma", (n) => !["hal_ma.py", "main.py"].includes(n));
  if (!ma.includes("ma.py") || !ma.includes("config.py")) {
    console.error("firmware/masr_ma/ma.py or config.py missing");
    process.exit(2);
  }
  const tests = copyRepo(FS, "tests/firmware", (n) => n !== "conftest.py");
  mkdirs(FS, "/repo/tests/vectors");
  FS.writeFile("/repo/tests/vectors/lines.json",
    fs.readFileSync(path.join(root, "tests", "vectors", "lines.json")));
  const modules = tests.filter((n) => n.startsWith("test_")).map((n) => n.slice(0, -3));

  const driver = `
import sys, gc
sys.path.insert(0, "/repo/firmware/common")
sys.path.insert(0, "/repo/firmware/esp32")
sys.path.insert(0, "/repo/tests/firmware")
sys.path.append("/repo/firmware/masr_ma")

def _trace(e):
    try:
        import io
        buf = io.StringIO()
        sys.print_exception(e, buf)
        for ln in buf.getvalue().split("\\n"):
            if ln:
                print("    " + ln)
    except Exception:
        pass

_passed = 0
_failed = 0
for _m in ${JSON.stringify(modules)}:
    try:
        _mod = __import__(_m)
    except Exception as _e:
        _failed += 1
        print("FAIL %s::<import>: %s %s" % (_m, type(_e).__name__, _e))
        _trace(_e)
        continue
    for _n in sorted([n for n in dir(_mod) if n.startswith("test_")]):
        _f = getattr(_mod, _n)
        if not callable(_f):
            continue
        try:
            _f()
            _passed += 1
            print("PASS %s::%s" % (_m, _n))
        except Exception as _e:
            _failed += 1
            _msg = str(_e).replace("\\n", " ")
            if len(_msg) > 300:
                _msg = _msg[:300] + "..."
            print("FAIL %s::%s: %s %s" % (_m, _n, type(_e).__name__, _msg))
            _trace(_e)
    gc.collect()
print("SUMMARY passed=%d failed=%d" % (_passed, _failed))
`;
  try {
    mp.runPython(driver);
  } catch (e) {
    console.error("driver crashed: " + (e && e.message ? e.message : e));
    process.exit(2);
  }
  const failed = mp.globals.get("_failed");
  const passed = mp.globals.get("_passed");
  process.exit(failed === 0 && passed > 0 ? 0 : 1);
}

main().catch((e) => {
  console.error("runner error: " + (e && e.stack ? e.stack : e));
  process.exit(2);
});
