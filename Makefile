# Patternshop: `make demo` (set up + run the main job into out/), `make test` (set up + tests).
# Both need only python3 and are idempotent: the venv is (re)installed when pyproject.toml changes.
SHELL := /bin/bash
.SHELLFLAGS := -eu -o pipefail -c
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.patternshop-installed
# pip's local-index warnings about missing mirror folders are noise; real errors still fail the pipe.
PIP_QUIET := 2>&1 | { grep -v "is ignored: it is neither a file nor a directory" || true; }
PS := $(BIN)/patternshop
# torch threads of the demo's syntheses: on a 2-core machine busy with anything else, a 2-thread OpenMP team
# slows synthesis tenfold or more; on an idle machine `make demo DEMO_THREADS=2` may be faster.
DEMO_THREADS ?= 1

.PHONY: setup browser demo test bench examples clean

setup: $(STAMP)

$(STAMP): pyproject.toml
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	@echo "installing into $(VENV) (torch CPU build, then patternshop in editable mode)"
	$(BIN)/python -m pip install --disable-pip-version-check -q "torch==2.13.0" $(PIP_QUIET)
	$(BIN)/python -m pip install --disable-pip-version-check -q -e ".[dev]" $(PIP_QUIET)
	@touch $@

demo: setup
	@mkdir -p out
	OMP_NUM_THREADS=$(DEMO_THREADS) $(BIN)/python examples/demo.py --out out/demo --threads $(DEMO_THREADS)
	OMP_NUM_THREADS=$(DEMO_THREADS) $(PS) synthesize examples/logo.tif out/logo.txt --png out/logo.png --svg out/logo.svg --report out/logo.json --no-progress
	OMP_NUM_THREADS=$(DEMO_THREADS) $(PS) synthesize examples/gradient.tif out/gradient.txt --png out/gradient.png --svg out/gradient.svg --dot-sizes --report out/gradient.json --no-progress
	$(PS) preview examples/logo.tif out/logo_map.png --scale 2
	$(PS) palette out/palette.png
	@echo "demo outputs: out/demo/ (points -> map -> edit -> points: contact_sheet.png, summary.json, ...);"
	@echo "  out/: logo.{txt,png,svg}, gradient.{txt,png,svg} (with dot sizes), reports (*.json), palette.png"

test: setup browser
	$(BIN)/python -m pytest -q

# The studio's browser tests need Debian's chromium and chromium-driver: installed here when we are root with
# apt-get; otherwise those tests are skipped with a message (under CI=true they fail instead).
browser:
	@if command -v chromium >/dev/null && command -v chromedriver >/dev/null; then :; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	  echo "installing chromium and chromium-driver for the studio's browser tests"; \
	  { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends chromium chromium-driver >/dev/null; } \
	    || echo "could not install chromium: the studio's browser tests will be skipped (under CI=true they fail)"; \
	else echo "chromium is not installed (apt-get install chromium chromium-driver as root): the studio's browser tests will be skipped (under CI=true they fail)"; fi

bench: setup
	$(BIN)/python bench/run.py

examples: setup
	$(BIN)/python examples/make_examples.py

clean:
	rm -rf out .pytest_cache
