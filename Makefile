# FPPM developer commands.  `make demo` and `make test` do all the set-up on a
# fresh machine: they create .venv with Python 3.13 (bpy 5.2 needs exactly
# 3.13) and install the pinned dependencies plus this package (editable).
#
#   make demo       render example_blends/cornell.blend to out/ with a summary (DEMO_FLAGS="--time-limit 30")
#   make test       run the test suite (two pytest-xdist workers, then the tests that time themselves alone)
#   make extension  download the wheels and build + validate the Blender extension zips in dist/
#   make bench      run the benchmark scripts in bench/
#   make bench-deps install the benchmark-only peers (pyluxcore: bench/peer_luxcore.py)
#   make clean      remove build outputs (not .venv)

SHELL := /bin/bash
.SHELLFLAGS := -eu -o pipefail -c
.DEFAULT_GOAL := help

VENV    := .venv
PY      := $(VENV)/bin/python
STAMP   := $(VENV)/.fppm-installed

# matplotlib, flip-evaluator: development only (tools/converge: `fppm converge`
# plots and PNG images; the HDR-FLIP metric of tools/metrics.py); the render
# path and the extension never import them.  dask[distributed]: `fppm render
# --workers/--cluster` only (tools/distributed.py), never in the extension.
# pytest-xdist: `make test` only (the suite in two workers on the CI machine's
# two cores; docs/architecture.md "The test suite's time, round 48").
# Pinned so that the wheels bundled in the extension (blender_manifest.toml)
# are the very versions the tests ran with.
BPY_VERSION      := 5.2.3
EMBREEX_VERSION  := 4.4.0.post1
OPENEXR_VERSION  := 3.5.3
NUMBA_VERSION    := 0.68.1
LLVMLITE_VERSION := 0.50.0
FLIP_VERSION     := 1.7
DASK_VERSION     := 2026.8.0
XDIST_VERSION    := 3.8.0
DEPS := bpy==$(BPY_VERSION) numpy embreex==$(EMBREEX_VERSION) OpenEXR==$(OPENEXR_VERSION) \
        numba==$(NUMBA_VERSION) llvmlite==$(LLVMLITE_VERSION) pytest pytest-xdist==$(XDIST_VERSION) hypothesis matplotlib \
        flip-evaluator==$(FLIP_VERSION) "dask[distributed]==$(DASK_VERSION)"

BLENDER_EXT = $(shell ls -d $(VENV)/lib/python3.13/site-packages/bpy/*/scripts/addons_core/bl_pkg/cli/blender_ext.py 2>/dev/null | head -n1)
WHEEL_PLATFORMS := manylinux_2_28_x86_64 win_amd64 macosx_14_0_arm64
WHEELS := embreex==$(EMBREEX_VERSION) OpenEXR==$(OPENEXR_VERSION) numba==$(NUMBA_VERSION) llvmlite==$(LLVMLITE_VERSION)

DEMO_SCENE  := example_blends/cornell.blend
DEMO_OUT    := out/cornell.exr
DEMO_FLAGS  ?= --time-limit 60
EXAMPLES_GENERATOR := $(firstword $(wildcard example_blends/make_*.py example_blends/generate*.py))

.PHONY: help venv demo test extension wheels bench bench-deps clean

help:
	@sed -n 's/^#   //p' Makefile

# --- .venv ------------------------------------------------------------------
# `python3.13` on PATH may be a pyenv shim that fails when 3.13 is not the
# selected version: every candidate is tried by running it.
$(PY):
	@py=""; \
	for c in python3.13 $$(pyenv root 2>/dev/null)/versions/3.13*/bin/python3.13 \
	         $${PYENV_ROOT:-$$HOME/.pyenv}/versions/3.13*/bin/python3.13 \
	         /usr/local/bin/python3.13 /usr/bin/python3.13; do \
	  if "$$c" -c 'import sys; assert sys.version_info[:2] == (3, 13)' >/dev/null 2>&1; then \
	    py="$$c"; break; fi; \
	done; \
	if [ -z "$$py" ]; then \
	  echo "error: Python 3.13 not found (bpy $(BPY_VERSION) needs exactly 3.13)." >&2; \
	  echo "Install it (e.g. 'pyenv install 3.13' or your package manager) and run make again." >&2; \
	  exit 1; \
	fi; \
	echo "Creating $(VENV) with $$py"; \
	"$$py" -m venv $(VENV)

$(STAMP): $(PY) pyproject.toml Makefile
	$(PY) -m pip install --quiet $(DEPS)
	$(PY) -m pip install --quiet --no-deps -e .
	rm -rf fppm.egg-info build
	@touch $(STAMP)

venv: $(STAMP)

# --- demo -------------------------------------------------------------------
$(DEMO_SCENE):
	@if [ -z "$(EXAMPLES_GENERATOR)" ]; then \
	  echo "error: $(DEMO_SCENE) is missing and no example_blends/make_*.py generator was found." >&2; exit 1; fi
	$(PY) $(EXAMPLES_GENERATOR)

demo: $(STAMP) $(DEMO_SCENE)
	@mkdir -p out
	$(VENV)/bin/fppm render $(DEMO_SCENE) -o $(DEMO_OUT) $(DEMO_FLAGS)

# --- tests ------------------------------------------------------------------
# Two phases: every test that does not time itself in two pytest-xdist workers
# (whole files to a worker, so a module's fixtures are made once), then the
# tests marked "serial" (they time themselves; tests/conftest.py) alone.
# Both phases run; the target fails if either did.
test: $(STAMP)
	@rc=0; \
	$(PY) -m pytest -q -n 2 --dist loadfile -m "not serial" --durations=15 tests/ || rc=$$?; \
	$(PY) -m pytest -q -m serial --durations=10 tests/ || rc=$$?; \
	exit $$rc

# --- extension --------------------------------------------------------------
wheels: $(STAMP)
	@mkdir -p wheels
	@for plat in $(WHEEL_PLATFORMS); do \
	  $(PY) -m pip download --quiet --only-binary=:all: --python-version 3.13 \
	    --platform $$plat --no-deps -d wheels $(WHEELS); \
	done
	@ls wheels

extension: wheels
	@test -n "$(BLENDER_EXT)" || { echo "error: blender_ext.py not found in the bpy wheel" >&2; exit 1; }
	@mkdir -p dist
	$(PY) $(BLENDER_EXT) build --source-dir . --output-dir dist --split-platforms
	@for z in dist/fppm-*.zip; do $(PY) $(BLENDER_EXT) validate "$$z"; done

# --- benchmarks -------------------------------------------------------------
bench: $(STAMP)
	@for b in bench/bench_*.py; do echo "== $$b"; $(PY) "$$b"; done

# LuxCoreRender's Python module, a peer compared at benchmark time only
# (bench/peer_luxcore.py, docs/peers.md): never in the extension or `make test`.
PYLUXCORE_VERSION := 2.11.2
bench-deps: $(STAMP)
	$(PY) -m pip install --quiet pyluxcore==$(PYLUXCORE_VERSION)

clean:
	rm -rf dist out build fppm.egg-info .pytest_cache
