"""The REPL console of an emulated MicroPython board, as mpremote meets it on a real one.

The board's pty carries the link (the firmware's line protocol) until the host
sends Ctrl-C; then the firmware stops (outputs off: `board.py`) and the pty is
this console, in MicroPython's own modes and bytes (py/pyexec.c):

  friendly  `>>> ` prompt, one-line statements echoed and run (expression
            values printed); Ctrl-A raw mode, Ctrl-B banner, Ctrl-C a fresh
            line, Ctrl-D soft reboot: `MPY: soft reboot`, then main.py runs
            (the firmware boots: BOOT)
  raw       `raw REPL; CTRL-B to exit\\r\\n>`; bytes collect until Ctrl-D, then
            `OK`, the program's output, `\\x04`, its traceback, `\\x04`, `>`.
            Ctrl-D on an empty program: `OK\\r\\nMPY: soft reboot\\r\\n`, a fresh
            interpreter and the raw banner again (main.py does not run from the
            raw REPL, as on the chip: mpremote relies on it); Ctrl-B back to
            friendly; Ctrl-C clears the program
  paste     raw paste (`\\x05A\\x01` in raw mode): `R\\x01` + the window (u16 LE,
            WINDOW bytes), `\\x01` each time a window has been taken in, Ctrl-D
            ends it with `\\x04`, then output, `\\x04`, traceback, `\\x04`, `>`

Programs run in the real MicroPython interpreter (`mpbridge/repl.mjs`: the
WebAssembly port from npm, with the board's filesystem mounted at / as a VFS,
`replfs.py`) in one Node process per console, started on first use and fed
the filesystem (`boardfs.BoardFs`); every change a program makes comes back
and is applied to the BoardFs. `machine.reset()` resets the board (the
firmware in the filesystem boots); a soft reboot starts a fresh interpreter.
Output is cooked as on the chip (`\\n` -> `\\r\\n`).
"""
from __future__ import annotations

import json
from typing import Callable

from armbridge.emulator.boardfs import BoardFs
from armbridge.emulator.micropython import BridgeError, NodeProcess, bridge_script, find_micropython, find_node

WINDOW = 256          # MICROPY_REPL_STDIN_BUFFER_MAX, the ESP32 port's raw-paste window
HEAP_BYTES = 1024 * 1024
VERSION = "1.29.0"
BANNER = (f"MicroPython v{VERSION} on 2026-12-01; Generic ESP32 module with ESP32 (armbridge emulator)\r\n"
          'Type "help()" for more information.\r\n')
RAW_BANNER = b"raw REPL; CTRL-B to exit\r\n"
CTRL_A, CTRL_B, CTRL_C, CTRL_D, CTRL_E = 1, 2, 3, 4, 5


def cooked(text: str) -> bytes:
    return text.replace("\r\n", "\n").replace("\n", "\r\n").encode("utf-8", "replace")


class MicroPythonExec:
    """One `node repl.mjs` child: runs raw-REPL programs on a copy of the BoardFs."""

    def __init__(self, fs: BoardFs, heap_bytes: int = HEAP_BYTES, timeout: float = 20.0) -> None:
        script = bridge_script().with_name("repl.mjs")
        self.proc = NodeProcess([find_node(), str(script), str(find_micropython()), str(int(heap_bytes))], timeout)
        self.version = self.proc.ready()
        for d in sorted(fs.dirs):
            self._ok(f"D {d}")
        for name, data in fs.files.items():
            self._ok(f"F {name} {data.hex() or '-'}")

    def _ok(self, line: str) -> None:
        answer = self.proc.call(line)
        if answer != "OK":
            raise BridgeError(f"the REPL's MicroPython answered {answer[:120]!r}")

    def run(self, src: bytes) -> tuple[str, str, str | None, list]:
        """-> (stdout, traceback, reset request "hard"/"soft"/None, filesystem changes)."""
        answer = self.proc.call("X " + (src.hex() or "-"))
        f = answer.split(" ")
        if f[0] != "R" or len(f) != 5:
            why = bytes.fromhex(f[1]).decode("utf-8", "replace") if f[0] == "E" and len(f) > 1 else answer[:120]
            raise BridgeError(f"the REPL's MicroPython failed: {why}")

        def text(h: str) -> str:
            return "" if h == "-" else bytes.fromhex(h).decode("utf-8", "replace")

        return text(f[1]), text(f[2]), None if f[3] == "-" else f[3], json.loads(text(f[4]) or "[]")

    def close(self) -> None:
        self.proc.close()


class Repl:
    """The console state machine; see the module docstring.

    write(bytes): output for the host. on_reset(kind): "hard" (machine.reset())
    or "soft" (Ctrl-D in the friendly REPL): the board reboots and main.py runs.
    """

    def __init__(self, fs: BoardFs, write: Callable[[bytes], None], on_reset: Callable[[str], None]) -> None:
        self.fs = fs
        self.write = write
        self.on_reset = on_reset
        self.mode = "friendly"
        self._buf = bytearray()
        self._window_left = WINDOW
        self._exec: MicroPythonExec | None = None

    # ------------------------------------------------------------ entering
    def enter(self, interrupted: bool) -> None:
        """The console takes over: after a Ctrl-C stopped the firmware, or a boot without main.py."""
        self.mode = "friendly"
        self._buf.clear()
        if interrupted:
            self.write(cooked('Traceback (most recent call last):\n  File "main.py", in <module>\nKeyboardInterrupt: \n'))
        self.write(cooked(BANNER) + b">>> ")

    def close(self) -> None:
        if self._exec is not None:
            self._exec.close()
            self._exec = None

    def _executor(self) -> MicroPythonExec:
        if self._exec is None:
            self._exec = MicroPythonExec(self.fs)
        return self._exec

    def _run(self, src: bytes) -> tuple[str, str, str | None]:
        try:
            out, err, reset, changes = self._executor().run(src)
        except BridgeError as exc:  # the interpreter died or hung: a fresh one next time
            self.close()
            return "", f"Traceback (most recent call last):\nRuntimeError: {exc}\n", None
        self.fs.apply(changes)
        return out, err, reset

    # ------------------------------------------------------------ bytes in
    def feed(self, data: bytes) -> None:
        for b in data:
            if self.mode == "friendly":
                self._friendly(b)
            elif self.mode == "raw":
                self._raw(b)
            elif self.mode == "paste":
                self._paste(b)
            else:  # "gone": the board is rebooting; bytes are lost as on the chip
                return

    def _soft_reboot(self) -> None:
        self.close()  # a fresh interpreter: globals and imported modules are gone
        self.write(b"MPY: soft reboot\r\n")

    def _friendly(self, b: int) -> None:
        if b == CTRL_A:
            self.mode = "raw"
            self._buf.clear()
            self.write(b"\r\n" + RAW_BANNER + b">")
        elif b == CTRL_B:
            self._buf.clear()
            self.write(b"\r\n" + cooked(BANNER) + b">>> ")
        elif b == CTRL_C:
            self._buf.clear()
            self.write(b"\r\n>>> ")
        elif b == CTRL_D:
            if self._buf:
                return
            self.write(b"\r\n")
            self._soft_reboot()
            self.mode = "gone"
            self.on_reset("soft")
        elif b in (8, 127):
            if self._buf:
                self._buf.pop()
                self.write(b"\x08 \x08")
        elif b == 13:
            src = bytes(self._buf)
            self._buf.clear()
            self.write(b"\r\n")
            if src.strip():
                out, err, reset = self._run(b"__single__" + src)
                self.write(cooked(out + err))
                if reset:
                    self._reset(reset)
                    return
            self.write(b">>> ")
        elif b >= 32 or b == 9:
            self._buf.append(b)
            self.write(bytes([b]))

    def _raw(self, b: int) -> None:
        if b == CTRL_A:
            if bytes(self._buf) == b"\x05A":
                self._buf.clear()
                self.mode = "paste"
                self._window_left = WINDOW
                self.write(b"R\x01" + WINDOW.to_bytes(2, "little"))
                return
            if len(self._buf) == 2 and self._buf[0] == CTRL_E:  # a raw-paste variant we do not speak
                self._buf.clear()
                self.write(b"R\x00")
                return
            self._buf.clear()
            self.write(RAW_BANNER + b">")
        elif b == CTRL_B:
            self._buf.clear()
            self.mode = "friendly"
            self.write(b"\r\n" + cooked(BANNER) + b">>> ")
        elif b == CTRL_C:
            self._buf.clear()
        elif b == CTRL_D:
            src = bytes(self._buf)
            self._buf.clear()
            self.write(b"OK")
            if not src:
                self.write(b"\r\n")
                self._soft_reboot()
                self.write(RAW_BANNER + b">")
                return
            self._execute(src)
        else:
            self._buf.append(b)

    def _paste(self, b: int) -> None:
        if b in (CTRL_C, CTRL_D):
            src = bytes(self._buf)
            self._buf.clear()
            self.mode = "raw"
            self.write(b"\x04")
            if b == CTRL_C:
                self.write(b"\x04" + cooked("Traceback (most recent call last):\nKeyboardInterrupt: \n") + b"\x04>")
                return
            self._execute(src)
            return
        self._buf.append(b)
        self._window_left -= 1
        if self._window_left == 0:
            self._window_left = WINDOW
            self.write(b"\x01")

    def _execute(self, src: bytes) -> None:
        out, err, reset = self._run(src)
        self.write(cooked(out))
        if reset:  # machine.reset() never returns on the chip: no end markers
            self._reset(reset)
            return
        self.write(b"\x04" + cooked(err) + b"\x04>")

    def _reset(self, kind: str) -> None:
        if kind == "soft" and self.mode in ("raw", "paste"):  # machine.soft_reset() from the raw REPL
            self.mode = "raw"
            self._soft_reboot()
            self.write(RAW_BANNER + b">")
            return
        self.close()
        self.mode = "gone"
        self.on_reset(kind)


class Console:
    """Where an emulated board's pty bytes go: `mode` "link" (the firmware's
    UART, board.py's PacedUart, byte-exact as ever) or "repl" (the `Repl`).

    A Ctrl-C from the host (as sent: before link faults, which model the link
    UART, not the console) stops the firmware (`interrupt()`) and hands the pty
    to the REPL; a reset hands it back to the link. The console's bytes run on
    their own fault-free lanes, paced at the board's baud like the UART.
    """

    def __init__(self, fs: BoardFs, bytes_per_s: float, interrupt: Callable[[], None],
                 on_reset: Callable[[str], None]) -> None:
        from armbridge.emulator.uart import Lane

        self.mode = "link"
        self.rx = Lane("console-rx", bytes_per_s, None, 0)
        self.tx = Lane("console-tx", bytes_per_s, None, 0)
        self.interrupt = interrupt
        self.repl = Repl(fs, self._write, on_reset)
        self._now = 0.0

    def _write(self, data: bytes) -> None:
        self.tx.push(data, self._now)

    def from_host(self, data: bytes, t: float) -> bytes:
        """Bytes from the host at time t -> the part that goes to the link."""
        self._now = t
        if self.mode == "link":
            i = data.find(b"\x03")
            if i < 0:
                return data
            link, data = data[:i], data[i + 1:]
            self.mode = "repl"
            self.interrupt()
            self.repl.enter(interrupted=True)
        else:
            link = b""
        if data:
            self.rx.push(data, t)
        return link

    def poll(self, t: float) -> bytes:
        """Run the REPL on the bytes due by t; -> the console's bytes for the host."""
        self._now = t
        if self.mode == "repl":
            data = self.rx.pop(t)
            if data:
                self.repl.feed(data)
        return self.tx.pop(t)

    def to_link(self) -> None:
        """A reset: the firmware (re)boots and has the pty again."""
        self.mode = "link"
        self.rx.clear()
        self.repl.close()

    def to_repl(self, banner: bytes = b"") -> None:
        """A boot that left no firmware running (no main.py, or it raised): the REPL."""
        self.mode = "repl"
        if banner:
            self._write(banner)
        self.repl.enter(interrupted=False)

    def close(self) -> None:
        self.repl.close()
