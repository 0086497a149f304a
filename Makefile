# The two commands of the README: `make demo` and `make test`. Each sets up what it needs:
# Debian packages when run as root (scripts/system-deps.sh), then a .venv with baromap in it.

PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.baromap-installed
PYTEST_ARGS ?=

.PHONY: demo test lint setup system-deps firmware bench clean

demo: $(STAMP)
	$(BIN)/baromap demo

test: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/mypy
	@if command -v avr-gcc >/dev/null 2>&1; then $(MAKE) -C firmware; else echo "firmware: build skipped (avr-gcc not found; install gcc-avr avr-libc arduino-core-avr)"; fi
	$(BIN)/pytest $(PYTEST_ARGS)

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/mypy

setup: $(STAMP)

system-deps:
	@scripts/system-deps.sh

$(STAMP): pyproject.toml scripts/system-deps.sh
	@scripts/system-deps.sh
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q -e '.[test]'
	touch $@

bench: $(STAMP)
	for b in bench/*.py; do echo "== $$b"; $(BIN)/python $$b || exit 1; done

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .mypy_cache .ruff_cache
