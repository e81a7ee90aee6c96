# flatcli: two commands on a fresh machine with only python3:
#   make reproduce   the paper's figures and numbers, and the Monte Carlo studies -> runs/paper/
#   make test        lint (ruff, mypy) and the test suite
# The virtual environment .venv is created and filled here, pinned by constraints.txt:
# `reproduce` installs what flatcli needs to run, `test` (and `bench`) add the tools.

PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
RUN_STAMP := $(VENV)/.installed-run
DEV_STAMP := $(VENV)/.installed-dev
# pip's own lines, one per package it fetches or installs (the rest is noise); its exit
# status is kept (pipefail)
SHELL := /bin/bash
.SHELLFLAGS := -o pipefail -ec
PIP_LINES := grep --line-buffered -E '^(Collecting|Installing collected|Successfully installed|ERROR|error)' || true

.PHONY: all install install-dev bytecode test lint reproduce bench bench-full clean

all: test

$(BIN)/python:
	@echo "flatcli: creating the virtual environment $(VENV) with $(PYTHON)"
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(RUN_STAMP): pyproject.toml constraints.txt | $(BIN)/python
	@echo "flatcli: installing flatcli and what it runs on (numpy, scipy, numba, pandas, pyarrow, matplotlib; about a minute the first time)"
	$(BIN)/python -m pip install -c constraints.txt -e . 2>&1 | { $(PIP_LINES); }
	@touch $@

$(DEV_STAMP): $(RUN_STAMP)
	@echo "flatcli: installing the tools of the tests (pytest, hypothesis, sympy, ruff, mypy, dask, python-control, nbclient)"
	$(BIN)/python -m pip install -c constraints.txt -e '.[dev]' 2>&1 | { $(PIP_LINES); }
	@touch $@

install: $(RUN_STAMP)

install-dev: $(DEV_STAMP)

# flatcli is installed editable, so pip compiles none of its modules; where
# PYTHONDONTWRITEBYTECODE is set (many containers, this project's CI) every process would
# compile them again (about 0.3 s of each start). compileall writes what changed, once.
bytecode: $(RUN_STAMP)
	@$(BIN)/python -m compileall -q flatcli benchmarks

lint: $(DEV_STAMP)
	$(BIN)/ruff check flatcli tests benchmarks
	$(BIN)/mypy

# The suite runs on every core the machine (or its container's CPU quota) gives, in
# pytest-xdist workers: most of a cold run is numba compiling kernels, one core each.
test: lint bytecode
	$(BIN)/pytest -q -n "$$($(BIN)/python -c 'from flatcli.machine import cores; print(cores())')"

reproduce: $(RUN_STAMP) bytecode
	$(BIN)/flatcli reproduce --out runs/paper

bench: $(DEV_STAMP) bytecode
	$(BIN)/python -m benchmarks.run --out runs/bench

bench-full: $(DEV_STAMP) bytecode
	$(BIN)/python -m benchmarks.run --out runs/bench --million

clean:
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache
