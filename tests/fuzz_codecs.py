"""Coverage-guided differential fuzzing of the three line codecs (docs/fuzzing.md).

The host codec (host/armbridge/link/protocol.py), the MicroPython firmware's codec
and session rules (firmware/common/proto.py, session.py, run under CPython) and the
Arduino board's C++ (proto.cpp, session.cpp through fuzz/codec_shim.cpp, loaded with
ctypes when it is built: `make -C firmware/arduino_pump/fuzz shim`) get the same
inputs and must give the same answers. atheris (libFuzzer for Python) steers the
inputs by the Python code's coverage. Two targets, their input layouts shared with
the C++ libFuzzer targets of the same names (firmware/arduino_pump/fuzz/), so each
corpus seeds the other:

  codec    4-byte epoch (LE, 30 bits), flags (bit 0: a board line's bound 192, else
           96; bits 1..3: joints), then one line: decode agrees (seq, verb, arguments
           or the error code) on all three, then parse_command (values or code) on
           the decoded verb and arguments, and the LineReader of the firmware and of
           the C++ split the same bytes into the same lines, errors and e-stops.
           A board line (flag bit 0) that the host decodes, it also types
           (parse_board_line): nothing but ProtocolError may come out.
  session  8-byte operations (fuzz_session.cpp has the layout): HELLOs, read-only
           and other verbs, resets; the Python Session and the C++ one classify every
           line alike and hold the same session, epoch, hello_seq and expect; no seq
           executes twice in one epoch; a replay returns the first answer; the ER line
           the firmware writes for a refused seq is read back by the host.

  python tests/fuzz_codecs.py fuzz TARGET [libFuzzer flags] DIR...   atheris; the first DIR takes new inputs
  python tests/fuzz_codecs.py replay TARGET PATH...                   each input (file, or every file of a dir) once
  python tests/fuzz_codecs.py cov PATH...                             line and branch coverage (coverage.py) of
                                                                      the three modules over both targets' inputs
A disagreement raises AssertionError with both answers; atheris then writes the input
(crash-*) as libFuzzer does. The kept corpus is tests/fuzz_corpus/<target>/.
"""
import ctypes
import importlib
import json
import os
import pathlib
import shlex
import struct
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
FW_COMMON = ROOT / "firmware" / "common"
SHIM = pathlib.Path(os.environ.get("ARMBRIDGE_CODEC_SHIM",
                                   ROOT / "firmware" / "arduino_pump" / "build" / "libfuzzer" / "libcodec_shim.so"))
TARGETS = ("codec", "session")
MODULES = {"host": ROOT / "host" / "armbridge" / "link" / "protocol.py",
           "fw_proto": FW_COMMON / "proto.py", "fw_session": FW_COMMON / "session.py"}

host = fw = fws = D = None   # the modules, loaded by load()
cpp = None                   # the C++ shim, or None where it is not built


def load(instrument: bool = False) -> None:
    """Imports the three modules (under atheris's instrumentation when asked) and the
    shim. The firmware's flat names (proto, protodef, session) are left out of
    sys.modules and sys.path afterwards."""
    global host, fw, fws, D, cpp
    names = ("proto", "protodef", "session")
    saved = {n: sys.modules.pop(n) for n in names if n in sys.modules}
    sys.path.insert(0, str(FW_COMMON))
    try:
        if instrument:
            import atheris
            sys.modules.pop("armbridge.link.protocol", None)
            with atheris.instrument_imports(include=["armbridge.link.protocol", "proto", "session"]):
                host = importlib.import_module("armbridge.link.protocol")
                fw = importlib.import_module("proto")
                fws = importlib.import_module("session")
        else:
            host = importlib.import_module("armbridge.link.protocol")
            fw = importlib.import_module("proto")
            fws = importlib.import_module("session")
        D = importlib.import_module("protodef")
    finally:
        sys.path.remove(str(FW_COMMON))
        for n in names:
            sys.modules.pop(n, None)
        sys.modules.update(saved)
    cpp = _load_shim()


def _load_shim():
    if not SHIM.exists():
        return None
    lib = ctypes.CDLL(str(SHIM))
    u8p = ctypes.POINTER(ctypes.c_uint8)
    lib.shim_decode.argtypes = [ctypes.c_char_p, ctypes.c_size_t, ctypes.c_size_t, ctypes.c_uint32,
                                ctypes.c_char_p, ctypes.c_size_t]
    lib.shim_parse_command.argtypes = [ctypes.c_char_p, ctypes.c_size_t, ctypes.POINTER(ctypes.c_char_p), u8p,
                                       ctypes.c_uint8, ctypes.c_uint8, ctypes.POINTER(ctypes.c_int32)]
    lib.shim_stream.argtypes = [ctypes.c_char_p, ctypes.c_size_t, ctypes.c_char_p, u8p,
                                ctypes.POINTER(ctypes.c_uint16), u8p]
    lib.shim_session_init.argtypes = [ctypes.c_uint16, ctypes.c_uint32, ctypes.c_int32]
    lib.shim_session_classify.argtypes = [ctypes.c_uint16, ctypes.c_int, ctypes.c_int, ctypes.c_int32,
                                          ctypes.c_int32, ctypes.c_int32]
    lib.shim_session_accept.argtypes = [ctypes.c_uint16, ctypes.c_uint16, ctypes.c_uint32]
    lib.shim_session_record.argtypes = [ctypes.c_uint16, ctypes.c_uint8]
    lib.shim_session_replay_code.argtypes = [ctypes.c_uint16]
    lib.shim_session_state.argtypes = [ctypes.POINTER(ctypes.c_int64)]
    return lib


# ------------------------------------------------------------------ the codec
def host_decode(line: bytes, max_len: int, epoch: int):
    try:
        got = host.decode(line, max_len, epoch=epoch)
        return "ok", (got.seq, got.verb, list(got.args))
    except host.ProtocolError as err:
        return "error", err.code


def fw_decode(line: bytes, max_len: int, epoch: int):
    try:
        seq, verb, args = fw.decode(line, max_len, epoch)
        return "ok", (seq, verb, list(args))
    except fw.ProtocolError as err:
        return "error", err.code


def cpp_decode(line: bytes, max_len: int, epoch: int):
    out = ctypes.create_string_buffer(4096)
    code = cpp.shim_decode(line, len(line), max_len, epoch, out, len(out))
    if code:
        return "error", code, 0
    seq, verb, nargs, *args = out.value.decode("latin-1").split("\t")
    return "ok", (int(seq), verb, args), int(nargs)


def host_command(verb: str, args: list, n: int):
    try:
        return "ok", list(host.parse_command(verb, args, n))
    except host.ProtocolError as err:
        return "error", err.code


def fw_command(verb: str, args: list, n: int):
    try:
        return "ok", list(fw.parse_command(verb, list(args), n))
    except fw.ProtocolError as err:
        return "error", err.code


def cpp_command(verb: str, args: list, n: int):
    k = max(len(args), 16)
    raw = [a.encode("latin-1") for a in args]
    ptrs = (ctypes.c_char_p * k)(*raw)
    lens = (ctypes.c_uint8 * k)(*[len(a) for a in raw])
    values = (ctypes.c_int32 * k)()
    vb = verb.encode("latin-1")
    code = cpp.shim_parse_command(vb, len(vb), ptrs, lens, len(args), n, values)
    return ("error", code) if code else ("ok", list(values[:len(args)]))


def fw_stream(data: bytes) -> list:
    out = []
    for item in fw.LineReader(D.MAX_HOST_LINE).feed(data):
        out.append(("L", item[1]) if item[0] == "line" else ("E", item[1]) if item[0] == "error" else ("S", 0))
    return out


def cpp_stream(data: bytes) -> list:
    cap = len(data) + 1
    kinds = ctypes.create_string_buffer(cap)
    codes = (ctypes.c_uint8 * cap)()
    lens = (ctypes.c_uint16 * cap)()
    lines = (ctypes.c_uint8 * cap)()
    n = cpp.shim_stream(data, len(data), kinds, codes, lens, lines)
    raw, at, out = bytes(lines), 0, []
    for i in range(n):
        kind = kinds.raw[i:i + 1].decode()
        if kind == "L":
            out.append((kind, raw[at:at + lens[i]]))
            at += lens[i]
        else:
            out.append((kind, codes[i]))
    return out


def codec_one(data: bytes) -> None:
    if len(data) < 5 or len(data) > 4096:
        return
    epoch = struct.unpack_from("<I", data)[0] & 0x3FFFFFFF
    max_len = D.MAX_BOARD_LINE if data[4] & 1 else D.MAX_HOST_LINE
    n_joints = (data[4] >> 1) & 7
    line = bytes(data[5:])
    h, f = host_decode(line, max_len, epoch), fw_decode(line, max_len, epoch)
    assert h == f, ("decode: host", h, "firmware", f, line)
    if cpp is not None:
        kind, value, nargs = cpp_decode(line, max_len, epoch)
        # the C++ keeps the first 16 arguments (AB_MAX_ARGS) and counts the rest
        want = ("ok", (f[1][0], f[1][1], f[1][2][:16]), len(f[1][2])) if f[0] == "ok" else f + (0,)
        assert (kind, value, nargs) == want, ("decode: C++", (kind, value, nargs), "firmware", want, line)
    if h[0] == "ok" and max_len == D.MAX_BOARD_LINE:   # the host types a board line: only ProtocolError may come
        try:
            host.parse_board_line(host.Line(*h[1][:2], tuple(h[1][2])), n_joints or None)
        except host.ProtocolError:
            pass
    if f[0] == "ok":
        _, verb, args = f[1]
        h, f2 = host_command(verb, args, n_joints), fw_command(verb, args, n_joints)
        assert h == f2, ("parse_command: host", h, "firmware", f2, verb, args, n_joints)
        if cpp is not None:
            c = cpp_command(verb, args, n_joints)
            assert c == f2, ("parse_command: C++", c, "firmware", f2, verb, args, n_joints)
    if cpp is not None:
        a, b = fw_stream(line), cpp_stream(line)
        assert a == b, ("LineReader: firmware", a, "C++", b, line)


# ------------------------------------------------------------------ the session rules
def session_one(data: bytes) -> None:
    if len(data) > 8 * 512:
        return
    ro_verb, rw_verb = sorted(D.READ_ONLY)[0], "W"
    s = fws.Session()
    if cpp is not None:
        cpp.shim_session_init(0, 0, -1)
    executed: dict = {}   # seq -> answer code, this epoch
    state = (ctypes.c_int64 * 4)()
    for i in range(0, len(data) - 7, 8):
        op = data[i:i + 8]
        kind = op[0] & 3
        seq = op[1] | op[2] << 8
        if op[0] & 0x80 and s.open:
            seq = (s.expect + struct.unpack("b", op[1:2])[0]) & 0xFFFF
        if kind == 3:
            s = fws.Session(s.session, s.epoch, s.hello_seq)
            if cpp is not None:
                cpp.shim_session_init(s.session, s.epoch, s.hello_seq)
        elif kind == 0:
            proto = D.PROTOCOL_VERSION if op[0] & 0x40 else op[6]
            sid = op[3] | op[4] << 8
            e = s.epoch + struct.unpack("b", op[5:6])[0]
            if not 0 <= e <= D.EPOCH_MAX:
                continue
            a = s.classify(seq, "HELLO", (proto, sid, e))
            if cpp is not None:
                c = cpp.shim_session_classify(seq, 0, 1, proto, sid, e)
                assert a == c, ("HELLO: Python", a, "C++", c, op)
            if a in (fws.NEW, fws.RESYNC):
                assert e == s.epoch + 1, ("only the next epoch opens", op)
                s.accept(seq, sid, e)
                if cpp is not None:
                    cpp.shim_session_accept(seq, sid, e)
                executed = {}
        else:
            ro = kind == 1
            a = s.classify(seq, ro_verb if ro else rw_verb)
            if cpp is not None:
                c = cpp.shim_session_classify(seq, int(ro), 0, 0, 0, 0)
                assert a == c, ("classify: Python", a, "C++", c, seq, ro)
            if a == fws.EXEC:
                assert seq not in executed, ("a seq executed twice in one epoch", seq)
                code = op[7] % (max(D.ERROR_NAMES) + 1)   # AB_N_ERRORS, as fuzz_session.cpp
                s.record(seq, "ER" if code else "OK", [code])
                if cpp is not None:
                    cpp.shim_session_record(seq, code)
                executed[seq] = code
            elif a == fws.REPLAY:
                first = s.replay(seq)[1][0]
                assert executed.get(seq) == first, ("a replay is the first answer", seq, first)
                if cpp is not None:
                    assert cpp.shim_session_replay_code(seq) == first, ("C++ replay", seq)
            elif a in (fws.SEQERR, fws.NOSESSION):   # the board's answer, as the host reads it
                code = D.SEQ if a == fws.SEQERR else D.NOSESSION
                got = host.parse_board_line(host.decode(s.er(seq, code, s.expect if s.open else None)))
                assert (got.seq, got.code) == (seq, code), ("ER line", got)
        if cpp is not None:
            cpp.shim_session_state(state)
            want = (s.session, s.epoch, s.hello_seq, s.expect)
            assert tuple(state) == want, ("state: Python", want, "C++", tuple(state), op)


ONE = {"codec": codec_one, "session": session_one}


# ------------------------------------------------------------------ entry points
def _inputs(paths) -> list:
    files = []
    for p in map(pathlib.Path, paths):
        files += sorted(x for x in p.iterdir() if x.is_file()) if p.is_dir() else [p]
    return files


def replay(target: str, paths) -> int:
    files = _inputs(paths)
    for f in files:
        try:
            ONE[target](f.read_bytes())
        except AssertionError as err:
            raise AssertionError(f"{f}: {err}") from None
    return len(files)


def coverage_of(paths_by_target: dict) -> dict:
    """{module: {"lines": %, "branches": %}} over the inputs of each target."""
    import coverage

    cov = coverage.Coverage(branch=True, data_file=None, include=[str(p) for p in MODULES.values()])
    cov.start()
    load()
    for target, paths in paths_by_target.items():
        replay(target, paths)
    cov.stop()
    out = {}
    for name, path in MODULES.items():
        analysis = cov._analyze(str(path))
        n = analysis.numbers
        out[name] = {"lines": round(100.0 * n.n_executed / max(n.n_statements, 1), 1),
                     "branches": round(100.0 * n.n_executed_branches / max(n.n_branches, 1), 1),
                     "statements": n.n_statements, "missing": n.n_missing}
    return out


def main(argv: list) -> int:
    if len(argv) >= 3 and argv[1] == "fuzz" and argv[2] in TARGETS:
        import atheris

        load(instrument=True)
        print(f"fuzz_codecs {argv[2]}: C++ shim {'loaded' if cpp is not None else 'not built: Python only'}",
              flush=True)
        # argv[0] as a command line: libFuzzer's -merge (and -fork) runs it through sh for its children
        me = " ".join(shlex.quote(x) for x in (sys.executable, str(pathlib.Path(__file__).resolve()), "fuzz", argv[2]))
        atheris.Setup([me] + argv[3:], ONE[argv[2]])
        atheris.Fuzz()
        return 0
    if len(argv) >= 4 and argv[1] == "replay" and argv[2] in TARGETS:
        load()
        n = replay(argv[2], argv[3:])
        print(f"replay {argv[2]}: {n} inputs agree (C++ {'included' if cpp is not None else 'not built'})")
        return 0
    if len(argv) >= 2 and argv[1] == "cov":
        dirs = argv[2:] or [str(ROOT / "tests" / "fuzz_corpus")]
        got = coverage_of({t: [d for d in (pathlib.Path(x) / t for x in dirs) if d.is_dir()] for t in TARGETS})
        print(json.dumps(got))
        return 0
    print(__doc__, file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv))
