"""The raw REPL's executor under MicroPython (repl.mjs loads it; MicroPython only).

`BoardFs` is a user VFS (MicroPython's `os.mount` protocol) over a dict of
files and a set of folders, mounted at "/" in place of the WebAssembly port's
own filesystem, so that `open`, `os.listdir`/`ilistdir`/`stat`/`remove`/
`mkdir`/`rmdir`/`rename` and `import` behave as on the board and fail with
MicroPython's errno numbers (`OSError: [Errno 2] ENOENT`). Every change is
logged (`take_changes`) so the emulator keeps the authoritative copy.

`run(src)` compiles and runs one raw-REPL program in one persistent global
namespace (mpremote's `f=open(...)` and its later `w(...)` are separate
programs), with `print` captured, and returns (stdout, stderr); the traceback
is MicroPython's own (`sys.print_exception`).

`machine` here is a stand-in for the ESP32's: `reset()` / `soft_reset()`
record the request (the emulator then resets the board) and stop the program,
as they never return on the chip.
"""

import binascii
import io
import json
import os
import sys

S_IFDIR = 0x4000
S_IFREG = 0x8000
ENOENT = 2
EEXIST = 17
ENOTDIR = 20
EISDIR = 21
ENOTEMPTY = 39


def _norm(p):
    parts = []
    for x in p.split("/"):
        if x == "..":
            if parts:
                parts.pop()
        elif x and x != ".":
            parts.append(x)
    return "/".join(parts)


class _Writer(io.BytesIO):
    def __init__(self, fs, path, text, data=b""):
        super().__init__()
        self._fs = fs
        self._path = path
        self._text = text
        if data:
            super().write(data)

    def write(self, b):
        if self._text:
            b = b.encode()
        return super().write(b)

    def flush(self):
        self._fs._put(self._path, self.getvalue())

    def close(self):
        if self._fs is not None:
            self._fs._put(self._path, self.getvalue())
            self._fs = None

    def __exit__(self, *a):
        self.close()


class BoardFs:
    def __init__(self):
        self.files = {}
        self.dirs = {""}
        self.cwd = ""
        self.changes = []

    # changes, for the emulator
    def _put(self, p, data):
        self.files[p] = bytes(data)
        self.changes.append(["w", p, bytes(data).hex()])

    def take_changes(self):
        c = self.changes
        self.changes = []
        return c

    def _abs(self, p):
        return _norm(p if p.startswith("/") else self.cwd + "/" + p)

    def _parent_ok(self, p):
        i = p.rfind("/")
        if (p[:i] if i >= 0 else "") not in self.dirs:
            raise OSError(ENOENT)

    # the VFS protocol
    def mount(self, readonly, mkfs):
        pass

    def umount(self):
        pass

    def statvfs(self, p):
        used = sum(len(v) for v in self.files.values()) // 4096 + 1
        return (4096, 4096, 512, 512 - used, 512 - used, 0, 0, 0, 0, 255)

    def chdir(self, p):
        p = self._abs(p)
        if p not in self.dirs:
            raise OSError(ENOENT)
        self.cwd = p

    def getcwd(self):
        return "/" + self.cwd

    def stat(self, p):
        p = self._abs(p)
        if p in self.dirs:
            return (S_IFDIR, 0, 0, 0, 0, 0, 0, 0, 0, 0)
        if p in self.files:
            return (S_IFREG, 0, 0, 0, 0, 0, len(self.files[p]), 0, 0, 0)
        raise OSError(ENOENT)

    def ilistdir(self, p):
        p = self._abs(p)
        if p not in self.dirs:
            raise OSError(ENOTDIR if p in self.files else ENOENT)
        pre = p + "/" if p else ""
        out = []
        for d in sorted(self.dirs):
            if d and d.startswith(pre) and "/" not in d[len(pre):]:
                out.append((d[len(pre):], S_IFDIR, 0, 0))
        for f in sorted(self.files):
            if f.startswith(pre) and "/" not in f[len(pre):]:
                out.append((f[len(pre):], S_IFREG, 0, len(self.files[f])))
        return iter(out)

    def mkdir(self, p):
        p = self._abs(p)
        if p in self.dirs or p in self.files:
            raise OSError(EEXIST)
        self._parent_ok(p)
        self.dirs.add(p)
        self.changes.append(["mkdir", p])

    def rmdir(self, p):
        p = self._abs(p)
        if p not in self.dirs or not p:
            raise OSError(ENOENT)
        pre = p + "/"
        if any(x.startswith(pre) for x in self.files) or any(x.startswith(pre) for x in self.dirs):
            raise OSError(ENOTEMPTY)
        self.dirs.discard(p)
        self.changes.append(["rmdir", p])

    def remove(self, p):
        p = self._abs(p)
        if p in self.dirs:
            raise OSError(EISDIR)
        if p not in self.files:
            raise OSError(ENOENT)
        del self.files[p]
        self.changes.append(["rm", p])

    def rename(self, a, b):
        a, b = self._abs(a), self._abs(b)
        if a not in self.files:
            raise OSError(ENOENT)
        self._parent_ok(b)
        self.files[b] = self.files.pop(a)
        self.changes.append(["mv", a, b])

    def open(self, p, mode):
        p = self._abs(p)
        if p in self.dirs:
            raise OSError(EISDIR)
        text = "b" not in mode
        if "w" in mode or "a" in mode:
            self._parent_ok(p)
            old = self.files.get(p, b"") if "a" in mode else b""
            w = _Writer(self, p, text, old)
            self._put(p, old)
            return w
        if p not in self.files:
            raise OSError(ENOENT)
        data = self.files[p]
        return io.StringIO(data.decode()) if text else io.BytesIO(data)


fs = BoardFs()


class Reset(BaseException):
    pass


reset_request = [None]


class machine:
    """What of `machine` the raw REPL is asked for (mpremote's reset, flash checks)."""

    @staticmethod
    def reset():
        reset_request[0] = "hard"
        raise Reset()

    @staticmethod
    def soft_reset():
        reset_request[0] = "soft"
        raise Reset()

    @staticmethod
    def unique_id():
        return b"\xa4\xcf\x12\x00\x00\x01"

    @staticmethod
    def freq(*a):
        return 240000000


def _uname():
    return os.namedtuple("uname_result", ("sysname", "nodename", "release", "version", "machine"))(
        "esp32", "esp32", "1.29.0", "v1.29.0 (armbridge emulator)", "Generic ESP32 module with ESP32")


def setup():
    """Mount the board's filesystem at / (after this module and its imports are loaded)."""
    os.uname = _uname
    sys.modules["machine"] = machine
    sys.modules["uos"] = os
    os.umount("/")
    os.mount(fs, "/")
    os.chdir("/")
    sys.path[:] = ["", "/lib"]


_globals = {"__name__": "__main__"}


def run(src):
    """One raw-REPL program (or a friendly-REPL line, prefixed "__single__")
    -> (stdout, stderr, reset request or None)."""
    out = io.StringIO()

    def _print(*args, sep=" ", end="\n", file=None):
        s = sep.join(str(a) for a in args) + end
        (file or out).write(s)

    _globals["print"] = _print
    err = io.StringIO()
    reset_request[0] = None
    mode = "exec"
    if src.startswith("__single__"):  # a line of the friendly REPL: its value is printed
        src, mode = src[10:], "single"
    try:
        exec(compile(src, "<stdin>", mode), _globals)
    except Reset:
        pass
    except BaseException as e:  # noqa: B902  (SystemExit, KeyboardInterrupt too, as the REPL does)
        sys.print_exception(e, err)
    tb = "".join(ln for ln in _lines(err.getvalue()) if "/bridge/" not in ln)
    return out.getvalue(), tb, reset_request[0]


def _lines(s):
    """s split after each newline (this module's frames are dropped from tracebacks)."""
    out = []
    i = 0
    while i < len(s):
        j = s.find("\n", i)
        j = len(s) if j < 0 else j + 1
        out.append(s[i:j])
        i = j
    return out


def _hex(s):
    return binascii.hexlify(s.encode()).decode() or "-"


def run_hex(hexsrc):
    """repl.mjs's X request: hex source -> "OUT_HEX ERR_HEX RESET CHANGES_HEX"."""
    src = binascii.unhexlify(hexsrc).decode() if hexsrc != "-" else ""
    out, err, reset = run(src)
    return " ".join((_hex(out), _hex(err), reset or "-", _hex(json.dumps(fs.take_changes()))))
