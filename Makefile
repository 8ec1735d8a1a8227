# Developer entry points. `make setup` is idempotent and fast when nothing
# changed (scripts/setup.sh keeps a stamp per step), so every target runs it.
SHELL := bash
VENV := .venv
PYTEST_ARGS ?=

.PHONY: setup test demo bench lint dist distclean

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

# The sdist and the wheel (with firmware, models, environments, vectors) in dist/.
dist: setup
	$(VENV)/bin/python -m build --outdir dist .

# Removes everything `make setup` builds (not the apt packages).
distclean:
	rm -rf $(VENV) node_modules typings dist .stamp-*
