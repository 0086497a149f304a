# The two commands of the README: `make demo` and `make test`. Each sets up what it needs:
# Debian packages when run as root (scripts/system-deps.sh), then a .venv with baromap in it.

PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.baromap-installed
TEST_STAMP := $(VENV)/.baromap-test-installed
PYTEST_ARGS ?=
# One pytest worker per core; tests sharing a module's fixture stay on one worker. The whole
# suite gets one more: about 45 % of a worker's time there is spent waiting on real processes,
# twins and timeouts, which the extra worker fills.
XDIST  := -n auto --dist loadgroup
XDIST_ALL := -n $(shell echo $$(( $$(nproc) + 1 ))) --dist loadgroup
TAP    := $(BIN)/baromapd-tap
TAP_CFLAGS := -std=gnu11 -O2 -Wall -Wextra -Werror

.PHONY: demo test check lint setup system-deps firmware bench clean tap viewer-client

demo: $(STAMP) $(TAP)
	$(BIN)/baromap demo

# mypy (one core, half a minute from a clean clone) runs beside the firmware build (the
# sanitized host tests are one compiler on the other core); its output follows the build's.
test: $(TEST_STAMP) $(TAP) viewer-client
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	@echo "$(BIN)/mypy (beside the firmware build)"; \
	log=$$(mktemp); $(BIN)/mypy >"$$log" 2>&1 & types=$$!; \
	$(MAKE) firmware; built=$$?; \
	wait $$types; typed=$$?; cat "$$log"; rm -f "$$log"; \
	test $$typed -eq 0 && test $$built -eq 0
	$(BIN)/pytest $(XDIST_ALL) $(PYTEST_ARGS)

# The inner loop: lint, types and the fast tests (no real processes, ptys, simulators or
# networks; nothing marked slow). `make test` runs everything.
check: $(TEST_STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/mypy
	$(BIN)/pytest $(XDIST) -q -m "not slow" $(PYTEST_ARGS)

lint: $(TEST_STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/mypy

setup: $(TEST_STAMP) $(TAP)

firmware:
	@if command -v avr-gcc >/dev/null 2>&1; then $(MAKE) -C firmware; else echo "firmware: build skipped (avr-gcc not found; install gcc-avr avr-libc arduino-core-avr)"; fi

system-deps:
	@scripts/system-deps.sh

# The demo needs baromap and what it runs on; the test tools come with `make test`. pip does
# not compile, compileall does it once on both cores: where PYTHONDONTWRITEBYTECODE is set (as
# on CI machines) nothing would ever be cached, and every process the demo and the tests start
# would compile matplotlib and scipy again (about 1.4 s of CPU each).
# Packages' own tests and the tools that run once (pip, mypy) are left out: half the bytes.
COMPILE_SKIP := /(tests|pip|mypy|mypyc|setuptools|pkg_resources|pygments)/
COMPILE := $(BIN)/python -m compileall -q -j 0 -x '$(COMPILE_SKIP)' $(VENV)/lib >/dev/null || echo "compileall: some files left to compile on import"

# The venv with baromap (and its test tools for `make test`: one pip run, one compile, which
# holds what the demo needs too).
define INSTALL
	@scripts/system-deps.sh
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --no-compile -e '$(1)'
	$(COMPILE)
endef

$(STAMP): pyproject.toml scripts/system-deps.sh
	$(call INSTALL,.)
	touch $@

$(TEST_STAMP): pyproject.toml scripts/system-deps.sh
	$(call INSTALL,.[test])
	touch $(STAMP) $@

# The laser's tap in C (daemon/tap.c; daemon/baromapd/tap.py says why there is a tap): built beside the
# venv's interpreter, where baromapd.tap looks for it (the README's install: `make tap
# BIN=/opt/baromap/bin`). Without a C compiler the daemon runs the Python tap and logs which.
tap: $(TAP)

$(TAP): daemon/tap.c
	@mkdir -p $(dir $@)
	@if command -v $(CC) >/dev/null 2>&1; then \
	  echo "$(CC) $(TAP_CFLAGS) -o $@ $<"; $(CC) $(TAP_CFLAGS) -o $@ $<; \
	else \
	  echo "tap: no C compiler ($(CC)): the daemon runs the Python tap (daemon/baromapd/tap.py)"; \
	fi

# The live view's third-party client (tests/e2e/test_liveview.py runs it beside the demo):
# @foxglove/ws-protocol and what it needs, as package-lock.json pins them.
VIEWER_JS := tests/liveview/js
VIEWER_STAMP := $(VIEWER_JS)/node_modules/.baromap-installed

viewer-client:
	@if command -v npm >/dev/null 2>&1; then $(MAKE) -s $(VIEWER_STAMP); \
	else echo "live view client: not installed (no node/npm; as root: apt-get install nodejs npm)"; fi

$(VIEWER_STAMP): $(VIEWER_JS)/package.json $(VIEWER_JS)/package-lock.json
	@if npm ci --prefix $(VIEWER_JS) --no-audit --no-fund --loglevel=error; then touch $@; \
	else echo "live view client: npm ci failed (no registry?); its end-to-end test is skipped"; fi

bench: $(STAMP) $(TAP)
	for b in bench/*.py; do echo "== $$b"; $(BIN)/python $$b || exit 1; done

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .mypy_cache .ruff_cache $(VIEWER_JS)/node_modules
