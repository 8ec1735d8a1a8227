# Developer entry points. `make setup` is idempotent and fast when nothing
# changed (scripts/setup.sh keeps a stamp per step), so every target runs it.
SHELL := bash
VENV := .venv
PYTEST_ARGS ?=

.PHONY: setup test demo bench lint fuzz dist distclean

setup:
	@scripts/setup.sh

test: setup
	$(VENV)/bin/python -m pytest -q $(PYTEST_ARGS)

demo: setup
	$(VENV)/bin/armbridge demo

bench: setup
	$(VENV)/bin/armbridge bench link

lint: setup
	$(VENV)/bin/lint-imports --no-cache
	$(VENV)/bin/python -m mypy host/armbridge

# Coverage-guided fuzzing (docs/fuzzing.md), FUZZ_SECONDS per fuzzer (default 60) from
# the kept corpora: the pump board's C++ parsers under libFuzzer with ASan/UBSan and their
# llvm-cov report, then the Python codecs under atheris (host, MicroPython firmware and
# the C++ compared) and their coverage. A crash or a disagreement fails with its input.
FUZZ_SECONDS ?= 60
FUZZ_B := firmware/arduino_pump/build/libfuzzer
fuzz: setup
	$(MAKE) -C firmware/arduino_pump/fuzz -j2 PYTHON=$(CURDIR)/$(VENV)/bin/python FUZZ_SECONDS=$(FUZZ_SECONDS) shim run cov
	@for t in codec session; do mkdir -p $(FUZZ_B)/py/$$t && \
	  echo "fuzz python $$t: $(FUZZ_SECONDS) s" && \
	  $(VENV)/bin/python tests/fuzz_codecs.py fuzz $$t -max_total_time=$(FUZZ_SECONDS) -max_len=1024 \
	    -artifact_prefix=$(FUZZ_B)/py/crash-$$t- $(FUZZ_B)/py/$$t tests/fuzz_corpus/$$t \
	    firmware/arduino_pump/fuzz/corpus/$$t >$(FUZZ_B)/log/py-$$t.log 2>&1 \
	  || { tail -n 40 $(FUZZ_B)/log/py-$$t.log; exit 1; }; \
	  grep -E "^#[0-9]+[[:space:]]+DONE" $(FUZZ_B)/log/py-$$t.log; done
	$(VENV)/bin/python tests/fuzz_codecs.py cov

# The sdist and the wheel (with firmware, models, environments, vectors) in dist/.
dist: setup
	$(VENV)/bin/python -m build --outdir dist .

# Removes everything `make setup` builds (not the apt packages).
distclean:
	rm -rf $(VENV) node_modules typings dist .stamp-*
