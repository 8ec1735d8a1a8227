"""The host's flash journal (flash/manifest.Journal): a note about a pty holds only while
that pty lives (its number is reused by the next emulator); a real port's note stays."""
import json
import os

from armbridge.flash.manifest import Journal, half_flashed


def test_a_pty_note_holds_while_the_pty_lives_and_not_for_the_next_one(tmp_path, monkeypatch):
    monkeypatch.setenv("ARMBRIDGE_CACHE", str(tmp_path))
    master, slave = os.openpty()
    try:
        path = os.ttyname(slave)
        j = Journal(path)
        j.start("esp32", "arm3r 0.1.0", 5)
        j.progress(2)
        assert "stopped after 2 of 5 files" in half_flashed(path)
        # The same number on another pty (born later): the note is not about this board.
        note = json.loads(j.path.read_text())
        note["pty"] = note["pty"] - 1
        j.write(note)
        assert half_flashed(path) is None
    finally:
        os.close(master)
        os.close(slave)


def test_a_real_ports_note_survives_unplugging(tmp_path, monkeypatch):
    monkeypatch.setenv("ARMBRIDGE_CACHE", str(tmp_path))
    port = "/dev/serial/by-id/usb-armbridge-test-board-if00"   # not plugged in: no device behind it
    Journal(port).start("esp32", "arm3r 0.1.0", 5)
    assert "left half-flashed" in half_flashed(port)
    Journal(port).done()
    assert half_flashed(port) is None
