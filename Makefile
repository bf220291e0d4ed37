# Common commands; see README.md.
PY ?= python

.PHONY: install test test-all lint format typecheck check bench data

install:  ## install the project and its development tools
	$(PY) -m pip install -e ".[dev]"

test:  ## fast test suite (the README's test command)
	$(PY) -m pytest

test-all:  ## including slow tests (identification runs)
	$(PY) -m pytest -m "slow or not slow"

lint:
	ruff check src tests benchmarks
	ruff format --check src tests benchmarks

format:
	ruff format src tests benchmarks
	ruff check --fix src tests benchmarks

typecheck:
	mypy

check: lint typecheck test  ## what CI runs

bench:  ## simulator throughput (traj-steps/s) for B = 20, 540, 19440
	$(PY) benchmarks/throughput.py

data:  ## download the FRT-DS-ESSO recordings into $$MMG_DATA_DIR (or the user cache)
	$(PY) -m sweep.download
