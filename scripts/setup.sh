#!/usr/bin/env bash
# Build the development environment: .venv (package + the extras in PIP_EXTRAS),
# node_modules (MicroPython WebAssembly interpreter), typings (ESP32 stubs)
# and, as root, the Debian AVR toolchain and OMPL 1.5 (libompl-dev: STRIDE's shim).
#
# Idempotent: each step records a hash of its inputs in a /.stamp-* file and
# is skipped while the hash matches and its output still exists, so a re-run
# takes well under a second.
set -euo pipefail
cd "$(dirname "$0")/.."

PYTHON=${PYTHON:-python3}
VENV=.venv
# Exact pins for these live in constraints.txt (one place for every pin).
PIP_EXTRAS="[test,train,masr,ompl,smm-peer,ray]"
STUBS=micropython-esp32-stubs
# libompl-dev: OMPL 1.5 headers and libompl.so for the STRIDE shim (planning/ext; the PyPI wheel binds no STRIDE).
# clang, libclang-rt-14-dev (the sanitizer and libFuzzer runtimes clang links), llvm (llvm-cov, llvm-profdata):
# libFuzzer with ASan/UBSan and source-based coverage (make fuzz, docs/fuzzing.md).
# chromium: the headless browser tests/test_view_web.py loads `armbridge view`'s web viewer in.
APT_PKGS=(gcc-avr avr-libc binutils-avr arduino-core-avr simavr libsimavr-dev avrdude libompl-dev clang libclang-rt-14-dev llvm chromium)

log() { printf 'setup: %s\n' "$*"; }

# Hash of the given files' contents: the key a step's stamp must match.
inputs_hash() { sha256sum "$@" | sha256sum | cut -d' ' -f1; }

# up_to_date STAMP HASH PATH: true when STAMP holds HASH and PATH exists.
up_to_date() { [[ -e $3 && -f $1 && $(<"$1") == "$2" ]]; }

step_venv() {
    if [[ -x $VENV/bin/python ]]; then return; fi
    "$PYTHON" -c 'import sys; sys.exit(sys.version_info < (3, 11))' || {
        echo "setup: $PYTHON is $("$PYTHON" --version 2>&1); Python >= 3.11 is required" >&2
        exit 1
    }
    log "creating $VENV"
    "$PYTHON" -m venv "$VENV"
}

step_pip() {
    local key
    key=$(inputs_hash pyproject.toml constraints.txt)
    if up_to_date .stamp-pip "$key" "$VENV/bin/armbridge"; then return; fi
    log "installing armbridge$PIP_EXTRAS (pins from constraints.txt)"
    # -qq: errors only (this machine's pip config adds index warnings per package).
    "$VENV/bin/python" -m pip install -qq --upgrade pip
    # -c keeps torch at its exact pin: any other torch spec pulls a CUDA build.
    "$VENV/bin/python" -m pip install -qq -c constraints.txt -e ".$PIP_EXTRAS"
    # The rerun CLI prints an analytics banner on first use otherwise.
    local out
    out=$("$VENV/bin/rerun" analytics disable 2>&1) || { echo "$out" >&2; exit 1; }
    echo "$key" >.stamp-pip
}

step_npm() {
    local key
    key=$(inputs_hash package.json package-lock.json)
    if up_to_date .stamp-npm "$key" node_modules/@micropython/micropython-webassembly-pyscript; then return; fi
    if ! command -v npm >/dev/null; then
        echo "setup: npm not found; install Node.js (apt-get install nodejs npm) and re-run" >&2
        exit 1
    fi
    log "installing npm packages (npm ci)"
    npm ci --no-audit --no-fund --loglevel=error >/dev/null
    echo "$key" >.stamp-npm
}

step_typings() {
    local key
    key=$(inputs_hash constraints.txt)
    if up_to_date .stamp-typings "$key" typings; then return; fi
    log "installing $STUBS into typings/"
    rm -rf typings
    "$VENV/bin/python" -m pip install -qq --target typings -c constraints.txt "$STUBS"
    echo "$key" >.stamp-typings
}

step_apt() {
    if dpkg -s "${APT_PKGS[@]}" >/dev/null 2>&1; then return; fi
    local cmd="apt-get install -y --no-install-recommends ${APT_PKGS[*]}"
    if [[ $(id -u) -ne 0 ]]; then
        echo "setup: AVR toolchain, clang/LLVM or libompl-dev missing (needed for the Arduino firmware, its simavr tests, the fuzzers and OMPL STRIDE); run:" >&2
        echo "  sudo apt-get update && sudo $cmd" >&2
        return
    fi
    log "installing AVR toolchain, clang/LLVM and libompl-dev from apt"
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq
    $cmd -qq >/dev/null
}

# The simavr harness of the Arduino boards' emulator (host/armbridge/emulator/simavr):
# built into the cache folder the emulator uses, where it would otherwise be built on
# first use. Needs the apt step's libsimavr-dev; skipped (with a note) without it.
step_harness() {
    if [[ ! -f /usr/include/simavr/sim_avr.h ]]; then
        log "simavr harness skipped: libsimavr-dev is missing"
        return
    fi
    local out
    out=$("$VENV/bin/python" -c 'from armbridge.emulator.simavr_runner import harness_binary; print(harness_binary())' 2>&1) || {
        echo "setup: building the simavr harness failed: $out" >&2
        exit 1
    }
}

# OMPL STRIDE's pybind11 shim (host/armbridge/planning/ext/stride.cpp), built into the same
# cache folder, where it would otherwise be built on first use (~12 s of g++). Needs the apt
# step's libompl-dev; skipped (with a note) without it.
step_stride() {
    if [[ ! -f /usr/include/ompl-1.5/ompl/geometric/planners/stride/STRIDE.h ]]; then
        log "OMPL STRIDE shim skipped: libompl-dev is missing"
        return
    fi
    local out
    out=$("$VENV/bin/python" -c 'from armbridge.planning.ext.build import stride_module; stride_module()' 2>&1) || {
        echo "setup: building the OMPL STRIDE shim failed: $out" >&2
        exit 1
    }
}

step_venv
step_pip
step_npm
step_typings
step_apt
step_harness
step_stride
log "environment ready"
