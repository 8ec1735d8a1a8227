"""Undetected errors of the line protocol under the bench's damage model (issue 9 §1).

The damage model is the emulator UART's fault mix (emulator/uart.py), applied
to one line's bytes: each byte is dropped with probability `drop`; a byte that
survives has one random bit flipped with probability `flip` and is sent twice
with probability `dup` (the copy carries the flip). A damaged line is one whose
bytes changed; its pieces between LFs (a flip can make one) reach the decoder
as lines. An *undetected* error is a piece that decodes and passes
parse_command as a valid command other than the line that was sent: on a board
it would execute.

`undetected(n_lines, seed, version)` measures it for protocol v1 (CRC-16, kept
here only for this comparison) or v2 (CRC-32 seeded by the epoch) over random
valid `W` lines. Pure computation: the damage is drawn with numpy, a line's
copies at once; chunks of lines go to worker processes, each chunk seeded from
(seed, chunk index), so the result does not depend on the number of workers.
`armbridge bench link` reports it (docs/benchmarks.md).
"""
from __future__ import annotations

import binascii
import re
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from armbridge.link import protocol as P

JOINTS = 3
Q_RANGE = 3142  # joint values in mrad, within +-pi: a 3R arm's range
CHUNK = 200  # lines per task: the unit of seeding


@dataclass(frozen=True)
class DamageModel:
    drop: float = 0.01
    flip: float = 0.01
    dup: float = 0.01


def damage(lines: list[bytes], copies: int, rng: np.random.Generator,
           model: DamageModel = DamageModel()) -> tuple[list[bytes], dict[str, int]]:
    """`copies` independently damaged copies of each line (line by line, all
    copies of the first line first), and how many bytes were dropped, flipped
    and duplicated over all of them. One set of numpy draws for the whole batch:
    lines are padded to the longest, the padding is never sent."""
    width = max(map(len, lines))
    raw = np.zeros((len(lines), width), dtype=np.uint8)
    real = np.zeros((len(lines), width), dtype=bool)
    for i, line in enumerate(lines):
        raw[i, :len(line)] = np.frombuffer(line, dtype=np.uint8)
        real[i, :len(line)] = True
    raw, real = np.repeat(raw, copies, axis=0), np.repeat(real, copies, axis=0)
    dropped = (rng.random(raw.shape) < model.drop) & real
    kept = real & ~dropped
    flipped = (rng.random(raw.shape) < model.flip) & kept
    duplicated = (rng.random(raw.shape) < model.dup) & kept
    bits = rng.integers(0, 8, size=raw.shape, dtype=np.uint8)
    values = np.where(flipped, raw ^ (np.uint8(1) << bits), raw).astype(np.uint8)
    repeats = np.where(kept, np.where(duplicated, 2, 1), 0)
    flat = np.repeat(values.ravel(), repeats.ravel()).tobytes()
    ends = np.cumsum(repeats.sum(axis=1))
    starts = np.concatenate(([0], ends[:-1]))
    out = [flat[a:b] for a, b in zip(starts.tolist(), ends.tolist())]
    counts = {"bytes": int(real.sum()), "drop": int(dropped.sum()),
              "flip": int(flipped.sum()), "dup": int(duplicated.sum())}
    return out, counts


# ---------------------------------------------------------------- the two framings

_V1_FRAME = re.compile(rb"([\x20-\x7e]*)\*([0-9A-F]{4})")


def crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE, protocol v1's CRC (binascii.crc_hqx from 0xFFFF)."""
    return binascii.crc_hqx(data, 0xFFFF)


def encode_v1(seq: int, verb: str, *args: object) -> bytes:
    body = " ".join([str(seq), verb, *map(str, args)]).encode("ascii")
    return b"%s*%04X\n" % (body, crc16(body))


def decode_v1(line: bytes) -> P.Line:
    """v1's checks in v1's order: length, framing (4 hex digits), CRC-16, grammar."""
    if len(line) + (0 if line.endswith(b"\n") else 1) > P.MAX_HOST_LINE:
        raise P.ProtocolError(P.LONG)
    frame = _V1_FRAME.fullmatch(line.rstrip(b"\n").removesuffix(b"\r"))
    if frame is None:
        raise P.ProtocolError(P.PARSE)
    body, crc_field = frame.groups()
    if crc16(body) != int(crc_field, 16):
        raise P.ProtocolError(P.CRC)
    return P.parse_body(body)


def executes_as(piece: bytes, version: int, epoch: int) -> tuple | None:
    """What a board would execute for this received line: (seq, verb, values),
    or None when the line is refused."""
    try:
        line = decode_v1(piece) if version == 1 else P.decode(piece, P.MAX_HOST_LINE, epoch=epoch)
        return line.seq, line.verb, tuple(P.parse_command(line.verb, line.args, JOINTS))
    except P.ProtocolError:
        return None


def is_undetected(sent: bytes, received: bytes, version: int, epoch: int = 0) -> bool:
    """True when `received` differs from `sent` and a piece of it executes as a
    command other than the one `sent` carries."""
    if received == sent:
        return False
    return _wrong_piece(executes_as(sent, version, epoch), received, version, epoch) is not None


def _wrong_piece(original: tuple | None, received: bytes, version: int, epoch: int) -> bytes | None:
    for piece in received.split(b"\n"):
        if piece:
            got = executes_as(piece, version, epoch)
            if got is not None and got != original:
                return piece
    return None


# ---------------------------------------------------------------- the measurement

@dataclass
class Result:
    version: int
    lines: int = 0  # valid lines made
    damaged: int = 0  # damaged copies (bytes changed)
    undetected: int = 0
    examples: list[tuple[str, str]] = field(default_factory=list)  # (sent, received), a few

    @property
    def rate(self) -> float:
        return self.undetected / self.damaged if self.damaged else 0.0

    @property
    def rate_upper_95(self) -> float:
        """One-sided 95 % upper bound of the rate: the rule of three for zero
        events, else the normal approximation (enough for a report)."""
        if not self.damaged:
            return 1.0
        if not self.undetected:
            return 3.0 / self.damaged
        return self.rate + 1.645 * (self.rate * (1 - self.rate) / self.damaged) ** 0.5

    def add(self, other: Result) -> None:
        self.lines += other.lines
        self.damaged += other.damaged
        self.undetected += other.undetected
        self.examples = (self.examples + other.examples)[:10]


def random_w_lines(n: int, rng: np.random.Generator, version: int) -> list[tuple[bytes, int]]:
    """n valid W lines for a 3-joint board, each with the epoch it is framed
    with (v2: a random epoch; v1 has none)."""
    seq = rng.integers(0, P.SEQ_MOD, size=n).tolist()
    wid = rng.integers(0, P.SEQ_MOD, size=n).tolist()
    dur = rng.integers(1, 60001, size=n).tolist()
    q = rng.integers(-Q_RANGE, Q_RANGE + 1, size=(n, JOINTS)).tolist()
    epochs = rng.integers(1, P.EPOCH_MAX + 1, size=n).tolist() if version == 2 else [0] * n
    if version == 1:
        return [(encode_v1(s, "W", i, t, *j), 0) for s, i, t, j in zip(seq, wid, dur, q)]
    return [(P.encode(s, "W", i, t, *j, epoch=e), e) for s, i, t, j, e in zip(seq, wid, dur, q, epochs)]


def _chunk(task: tuple[int, int, int, int, int, DamageModel]) -> Result:
    seed, index, n_lines, copies, version, model = task
    rng = np.random.default_rng([seed, index])
    made = random_w_lines(n_lines, rng, version)
    bodies = [sent[:-1] for sent, _ in made]  # the LF is the line's boundary, not damaged
    received, _ = damage(bodies, copies, rng, model)
    result = Result(version, lines=n_lines)
    for k, (sent, epoch) in enumerate(made):
        body = bodies[k]
        original = executes_as(sent, version, epoch)
        for got in received[k * copies:(k + 1) * copies]:
            if got == body:
                continue
            result.damaged += 1
            piece = _wrong_piece(original, got, version, epoch)
            if piece is not None:
                result.undetected += 1
                if len(result.examples) < 10:
                    result.examples.append((body.decode("latin-1"), piece.decode("latin-1")))
    return result


def undetected(n_lines: int, seed: int, version: int, *, copies: int = 100, workers: int = 1,
               model: DamageModel = DamageModel()) -> Result:
    """Damages each of `n_lines` random valid W lines `copies` times and counts
    the damaged copies that would execute as another command. Same result for
    any `workers` (processes)."""
    if version not in (1, 2):
        raise ValueError(f"protocol version {version}: 1 or 2")
    tasks = [(seed, i, min(CHUNK, n_lines - start), copies, version, model)
             for i, start in enumerate(range(0, n_lines, CHUNK))]
    total = Result(version)
    if workers > 1 and len(tasks) > 1:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            for part in pool.map(_chunk, tasks):
                total.add(part)
    else:
        for task in tasks:
            total.add(_chunk(task))
    return total
