"""The package's own surface, in the checkout's editable install: resources, --version,
help text, the train output guard, missing extras. (The wheel: tests/test_wheel.py.)"""
from __future__ import annotations

import json
from importlib.resources import files
from pathlib import Path

import pytest
from typer.testing import CliRunner

from armbridge import __version__, resources
from armbridge.cli import build_app
from armbridge.errors import ArmbridgeError
from armbridge.extras import require
from armbridge.link.protodef import PROTOCOL_VERSION
from armbridge.train.command import check_output


def test_resources_are_the_package_files() -> None:
    pkg = Path(str(files("armbridge")))
    for path, probe in ((resources.firmware_dir(), "esp32/main.py"), (resources.firmware_dir(), "common/protodef.py"),
                        (resources.models_dir(), "smm-arm3r/card.json"), (resources.envs_dir(), "E3.json")):
        assert path.is_relative_to(pkg) and (path / probe).is_file()
    assert resources.vectors_file().is_relative_to(pkg)
    assert isinstance(json.loads(resources.vectors_file().read_text()), (dict, list))
    assert resources.model_dir("smm-planar3r") == resources.models_dir() / "smm-planar3r"


def test_version_names_package_and_protocol() -> None:
    res = CliRunner().invoke(build_app(), ["--version"])
    assert res.exit_code == 0
    assert res.output.strip() == f"armbridge {__version__} (protocol {PROTOCOL_VERSION})"


@pytest.mark.parametrize("argv, shown", [
    (["smm", "--help"], "[default: the shipped smm-"),
    (["train", "smm-3r", "--help"], "[default: WORK_DIR/model]"),
    (["demo", "--help"], "[default: arm3r]"),
])
def test_help_keeps_defaults_and_shows_flags_as_flags(argv: list[str], shown: str) -> None:
    res = CliRunner().invoke(build_app(), argv, terminal_width=200)
    assert res.exit_code == 0, res.output
    assert shown in " ".join(res.output.split()), res.output
    assert "<bool>" not in res.output
    assert "--help  " in res.output or "--help " in res.output


def test_train_never_overwrites_a_shipped_model_without_force(tmp_path: Path) -> None:
    shipped = resources.model_dir("smm-planar3r")
    before = (shipped / "card.json").read_bytes()
    res = CliRunner().invoke(build_app(), ["train", "smm-3r", "--out", str(shipped), "--work-dir", str(tmp_path)])
    assert res.exit_code != 0 and isinstance(res.exception, ArmbridgeError)
    assert "a shipped model" in str(res.exception) and "--force" in str(res.exception)
    assert not any(tmp_path.iterdir()), "refused before building anything"
    assert (shipped / "card.json").read_bytes() == before
    with pytest.raises(ArmbridgeError, match="shipped"):
        check_output(shipped / "card.json", force=False, resume=True)  # --resume is no licence either
    check_output(shipped / "card.json", force=True, resume=False)  # asked for: allowed


def test_train_output_guard_for_own_models(tmp_path: Path) -> None:
    card = tmp_path / "model" / "card.json"
    check_output(card, force=False, resume=False)  # nothing there yet
    card.parent.mkdir()
    card.write_text("{}")
    with pytest.raises(ArmbridgeError, match=r"exists \(a model\); pass --force"):
        check_output(card, force=False, resume=False)
    check_output(card, force=False, resume=True)  # finishing its own run again


def test_a_missing_extra_is_named_in_one_line() -> None:
    with pytest.raises(ArmbridgeError) as exc:
        require("armbridge_no_such_module", "train", "--method nullspace")
    assert str(exc.value) == "--method nullspace needs the train extra: pip install 'armbridge[train]'"
    assert require("json", "train", "x").dumps([]) == "[]"
