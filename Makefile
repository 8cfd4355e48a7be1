# Each target creates .venv on first use and installs what it needs.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
# Warp compiles kernels once per source change; keep them in the checkout so tests and CI reuse them.
export WARP_CACHE_PATH := $(CURDIR)/.cache/warp
# JAX keeps MJX's compiled vehicle too, so each `vogjax simulate` process after the first skips it.
export JAX_COMPILATION_CACHE_DIR := $(CURDIR)/.cache/jax
export JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS := 0
export JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES := -1
# MkDocs Material's banner about its successor is not a build problem
export NO_MKDOCS_2_WARNING := 1

.PHONY: test docs demo bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[test,bench]"
	touch $@

test: $(STAMP)
	$(VENV)/bin/ruff check --quiet .
	$(VENV)/bin/ruff format --check --quiet .
	$(VENV)/bin/mkdocs build --strict
	$(PY) -m pytest -q -n 2 --dist loadfile

demo: $(STAMP)
	$(VENV)/bin/vogjax demo --out demo_out

bench: $(STAMP)
	$(PY) benchmarks/bench_voxelmap.py --out benchmarks/results
	$(PY) benchmarks/bench_globalmap.py --out benchmarks/results
	$(PY) benchmarks/bench_slam.py --out benchmarks/results
	$(PY) benchmarks/bench_sim.py --out benchmarks/results
	$(PY) benchmarks/bench_import.py --out benchmarks/results
	$(PY) benchmarks/bench_pipeline.py --out benchmarks/results
	$(PY) benchmarks/bench_crm.py --out benchmarks/results
	$(PY) benchmarks/bench_explore.py --out benchmarks/results
	$(PY) benchmarks/bench_paper.py --out benchmarks/results
	$(PY) benchmarks/bench_octomap.py --out benchmarks/results

clean:
	rm -rf $(VENV) .cache demo_out

docs: $(STAMP)
	$(VENV)/bin/mkdocs build --strict
