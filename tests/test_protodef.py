"""The one protocol table and its renderings: the committed generated files
are current, the MicroPython module holds the same data, and the C header
compiles (gcc, g++, avr-gcc) and, compiled and run, prints the same table."""
import importlib.util
import json
import shutil
import subprocess
import sys

import pytest
from require import missing

from armbridge.link import codegen
from armbridge.link import protodef as D

ROOT = codegen.ROOT
HEADER = ROOT / codegen.C_HEADER
FLAGS = ["-Wall", "-Wextra", "-Werror", "-pedantic"]

DUMP = r"""
#include <stdio.h>
#include "protodef.h"
int main(void) {
    int i, k;
    printf("{\"version\": %d, \"max_host_line\": %d, \"estop\": %d, \"epoch_max\": %ld, \"commands\": {",
           AB_PROTOCOL_VERSION, AB_MAX_HOST_LINE, AB_ESTOP_BYTE, (long)AB_EPOCH_MAX);
    for (i = 0; i < AB_N_COMMANDS; i++) {
        const ab_command *c = &AB_COMMANDS[i];
        printf("%s\"%s\": {\"ro\": %d, \"rule\": [%d, %d], \"args\": [", i ? ", " : "", c->verb,
               c->read_only, c->min_arg, c->max_arg);
        for (k = 0; k < c->n_args; k++)
            printf("%s[\"%s\", %d, %ld, %ld]", k ? ", " : "", c->args[k].name, c->args[k].kind,
                   (long)c->args[k].lo, (long)c->args[k].hi);
        printf("]}");
    }
    printf("}, \"errors\": [");
    for (i = 1; i < AB_N_ERRORS; i++) printf("%s\"%s\"", i > 1 ? ", " : "", AB_ERROR_NAMES[i]);
    printf("], \"stale\": %d, \"proto\": %d}\n", AB_ERR_STALE, AB_ERR_PROTO);
    return 0;
}
"""


def test_generated_files_are_current():
    for rel, text in codegen.rendered().items():
        assert (ROOT / rel).read_text() == text, f"{rel} is stale: run python -m armbridge.link.codegen"
    proc = subprocess.run([sys.executable, "-m", "armbridge.link.codegen", "--check"],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr


def test_check_fails_on_a_stale_file(tmp_path):
    codegen.main(["--root", str(tmp_path)])
    assert codegen.main(["--check", "--root", str(tmp_path)]) == 0
    path = tmp_path / codegen.C_HEADER
    path.write_text(path.read_text().replace("AB_RING 32", "AB_RING 31"))
    assert codegen.main(["--check", "--root", str(tmp_path)]) == 1


def test_micropython_module_holds_the_table():
    spec = importlib.util.spec_from_file_location("fw_protodef", ROOT / codegen.MICROPYTHON)
    fw = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(fw)
    for name in codegen.CONSTANTS + codegen.TABLES:
        assert getattr(fw, name) == getattr(D, name), name
    for code, name in D.ERROR_NAMES.items():
        assert getattr(fw, name) == code


def test_table_rules():
    """What the codecs rely on: q only last, joint written as 1..0, rules name arguments."""
    for verb, specs in D.COMMANDS.items():
        names = [n for n, _, _ in specs]
        assert "q" not in names[:-1], verb
        for name, lo, hi in specs:
            assert (lo, hi) == (1, 0) if name == "joint" else lo <= hi, (verb, name)
        for a, b in D.ORDERED.get(verb, ()):
            assert a in names and b in names
    assert set(D.READ_ONLY) <= set(D.COMMANDS)
    assert sorted(D.ERROR_NAMES) == list(range(1, 15))
    assert D.EPOCH_MAX == 2 ** 30 - 1 and D.TICKS_PERIOD == 2 ** 30
    assert D.MAX_EPOCH_COMMANDS <= D.SEQ_MOD // 2


def _compiler(name: str) -> str:
    path = shutil.which(name)
    if path is None:
        missing(f"{name} is not installed")
    return path


@pytest.mark.parametrize("lang", ["c", "c++"])
def test_header_compiles_with_gcc(lang, tmp_path):
    gcc = _compiler("gcc")
    proc = subprocess.run([gcc, "-x", lang, "-fsyntax-only", *FLAGS, str(HEADER)],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr


def test_header_table_matches_when_run(tmp_path):
    gcc = _compiler("gcc")
    src = tmp_path / "dump.c"
    src.write_text(DUMP)
    exe = tmp_path / "dump"
    proc = subprocess.run([gcc, *FLAGS, "-std=c99", "-I", str(HEADER.parent), "-o", str(exe), str(src)],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    got = json.loads(subprocess.run([str(exe)], capture_output=True, text=True, timeout=60, check=True).stdout)
    assert (got["version"], got["max_host_line"], got["estop"], got["epoch_max"]) == (
        D.PROTOCOL_VERSION, D.MAX_HOST_LINE, D.ESTOP_BYTE, D.EPOCH_MAX)
    assert got["errors"] == [D.ERROR_NAMES[c] for c in sorted(D.ERROR_NAMES)]
    assert (got["stale"], got["proto"]) == (D.STALE, D.PROTO)
    kinds = {"joint": 1, "q": 2}
    assert list(got["commands"]) == list(D.COMMANDS)
    for verb, specs in D.COMMANDS.items():
        row = got["commands"][verb]
        assert row["args"] == [[n, kinds.get(n, 0), lo, hi] for n, lo, hi in specs], verb
        assert row["ro"] == (verb in D.READ_ONLY)
        names = [n for n, _, _ in specs]
        rule = D.ORDERED.get(verb)
        assert row["rule"] == ([names.index(rule[0][0]), names.index(rule[0][1])] if rule else [-1, -1])


def test_header_compiles_with_avr_gcc(tmp_path):
    avr = _compiler("avr-gcc")
    src = tmp_path / "use.c"
    src.write_text('#include "protodef.h"\nint main(void) { return AB_COMMANDS[AB_VERB_W].n_args'
                   ' + (AB_EPOCH_MAX > 0x3FFFFFFEL) + (AB_SEQ_MOD == 65536L); }\n')
    proc = subprocess.run([avr, "-mmcu=atmega2560", "-Os", *FLAGS, "-I", str(HEADER.parent), "-c",
                           "-o", str(tmp_path / "use.o"), str(src)], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
