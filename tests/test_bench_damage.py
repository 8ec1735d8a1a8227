"""The damage model and the undetected-error count of bench/damage.py."""
import numpy as np
import pytest

from armbridge.bench import damage as d
from armbridge.link import protocol as P

LINE = b"12 W 52302 500 170 -1393 2000*0123ABCD"


def test_damage_rates_match_the_model():
    rng = np.random.default_rng(7)
    copies = 20000
    out, counts = d.damage([LINE], copies, rng)
    n = counts["bytes"]
    assert n == copies * len(LINE) and len(out) == copies
    want = {"drop": 0.01, "flip": 0.01 * 0.99, "dup": 0.01 * 0.99}  # flip and dup only on survivors
    for name, p in want.items():
        sigma = (p * (1 - p) / n) ** 0.5
        assert abs(counts[name] / n - p) < 5 * sigma, (name, counts[name] / n)
    assert sum(map(len, out)) == n - counts["drop"] + counts["dup"]
    changed = sum(o != LINE for o in out) / copies
    unchanged = (0.99 * (1 - 0.99 * 0.01) ** 2) ** len(LINE)
    assert abs(changed - (1 - unchanged)) < 5 * (unchanged * (1 - unchanged) / copies) ** 0.5


def test_each_fault_alone():
    rng = np.random.default_rng(1)
    flips, _ = d.damage([LINE], 50, rng, d.DamageModel(drop=0, flip=1, dup=0))
    for out in flips:
        assert len(out) == len(LINE)
        assert all(bin(a ^ b).count("1") == 1 for a, b in zip(out, LINE))
    dups, _ = d.damage([LINE], 5, rng, d.DamageModel(drop=0, flip=0, dup=1))
    assert dups == [bytes(b for b in LINE for _ in range(2))] * 5
    drops, _ = d.damage([LINE], 5, rng, d.DamageModel(drop=1, flip=1, dup=1))
    assert drops == [b""] * 5
    same, counts = d.damage([LINE], 5, rng, d.DamageModel(0, 0, 0))
    assert same == [LINE] * 5 and counts["drop"] == counts["flip"] == counts["dup"] == 0


def test_is_undetected_compares_what_would_execute():
    sent = d.encode_v1(12, "W", 52302, 500, 170, -1393, 0)
    other = d.encode_v1(12, "W", 52302, 500, 1700, -1393, 0)
    assert d.is_undetected(sent, other, 1)
    assert d.is_undetected(sent, b"12 W 5*1\n" + other, 1), "a piece after a damaged LF counts"
    assert not d.is_undetected(sent, sent, 1), "not damaged"
    assert not d.is_undetected(sent, sent[:-3] + b"\n", 1), "refused"
    assert not d.is_undetected(sent, d.encode_v1(12, "W", 52302, 0, 170, -1393, 0), 1), "RANGE: refused"
    assert not d.is_undetected(sent, d.encode_v1(12, "PONG"), 1), "VERB: refused"
    assert not d.is_undetected(sent, sent.replace(b"\n", b"\r\n"), 1), "same command"
    assert not d.is_undetected(sent, other, 2), "a v1 frame is no v2 line"
    sent2 = P.encode(12, "W", 52302, 500, 170, -1393, 0, epoch=99)
    other2 = P.encode(12, "W", 52302, 500, 1700, -1393, 0, epoch=99)
    assert d.is_undetected(sent2, other2, 2, epoch=99)
    assert not d.is_undetected(sent2, P.encode(12, "W", 52302, 500, 1700, -1393, 0, epoch=98), 2, epoch=99)


def test_v2_detects_every_damaged_line_of_a_run():
    result = d.undetected(20000, seed=3, version=2, copies=3)
    assert result.lines == 20000
    assert result.damaged > 0.5 * 3 * 20000
    assert result.undetected == 0 and result.examples == [] and result.rate == 0.0
    assert result.rate_upper_95 == pytest.approx(3.0 / result.damaged)


def test_batch_of_lines_of_different_lengths():
    rng = np.random.default_rng(2)
    lines = [b"1 PING*00000000", LINE, b"x"]
    out, counts = d.damage(lines, 4, rng, d.DamageModel(0, 0, 0))
    assert out == [line for line in lines for _ in range(4)]
    assert counts["bytes"] == 4 * sum(map(len, lines))
    out, _ = d.damage(lines, 2, rng, d.DamageModel(drop=0, flip=0, dup=1))
    assert out[2] == bytes(b for b in LINE for _ in range(2)) and out[3] == out[2] and out[-1] == b"xx"


def test_random_lines_are_valid_commands():
    rng = np.random.default_rng(4)
    for version in (1, 2):
        for sent, epoch in d.random_w_lines(200, rng, version):
            got = d.executes_as(sent, version, epoch)
            assert got is not None and got[1] == "W" and len(got[2]) == 5


def test_same_result_for_any_number_of_workers():
    one = d.undetected(450, seed=5, version=1, copies=4)
    two = d.undetected(450, seed=5, version=1, copies=4, workers=2)
    assert (one.lines, one.damaged, one.undetected) == (two.lines, two.damaged, two.undetected)
    assert one.lines == 450 and one.damaged > 0


def test_bad_version():
    with pytest.raises(ValueError):
        d.undetected(1, seed=0, version=3)


def test_v1_crc_is_ccitt_false():
    assert d.crc16(b"123456789") == 0x29B1
