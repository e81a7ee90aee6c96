# flatcli: two commands on a fresh machine with only python3:
#   make reproduce   the paper's figures and numbers, and the Monte Carlo study -> runs/paper/
#   make test        lint (ruff, mypy) and the test suite
# The virtual environment .venv is created and filled here, pinned by constraints.txt.

PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed-stamp

.PHONY: all install test lint reproduce bench bench-full clean

all: test

$(STAMP): pyproject.toml constraints.txt
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -c constraints.txt -e '.[dev]'
	touch $(STAMP)

install: $(STAMP)

lint: $(STAMP)
	$(BIN)/ruff check flatcli tests benchmarks
	$(BIN)/mypy

test: lint
	$(BIN)/pytest -q

reproduce: $(STAMP)
	$(BIN)/flatcli reproduce --out runs/paper

bench: $(STAMP)
	$(BIN)/python -m benchmarks.run --out runs/bench

bench-full: $(STAMP)
	$(BIN)/python -m benchmarks.run --out runs/bench --million

clean:
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache
