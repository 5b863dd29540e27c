# Two commands for a newcomer: `make demo` and `make test`. Each sets up .venv when missing.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# One BLAS thread per process: on these small networks (400-300, batch 256) multithreaded BLAS
# measured 10-20x slower, and a tournament already runs one worker per core.
export OPENBLAS_NUM_THREADS ?= 1
export OMP_NUM_THREADS ?= 1
export MKL_NUM_THREADS ?= 1

.PHONY: demo test lint bench setup clean

setup: $(STAMP)

# CPU torch first: an unpinned torch would pull a multi-GB CUDA build.
$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q torch==2.13.0
	$(BIN)/python -m pip install -q -e '.[dev,ray,slurm,sb3]'
	# numba's cache, filled once here: else every worker of the first run compiles (~50 s each)
	$(BIN)/formula-tourney compile
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/formula-tourney demo

# One pytest worker per core, a test file to a worker (files share fixtures such as a Slurm
# cluster); many tests wait on subprocesses, daemons and worker pools, so two overlap well.
test: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/python -m pytest -q -n auto --dist loadfile

# Style and the repository's own rule: no citation of issues, sessions or files outside it.
lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/python -m pytest -q -p no:cacheprovider tests/test_repository.py

bench: $(STAMP)
	for b in benchmarks/*.py; do echo "== $$b"; $(BIN)/python $$b || exit 1; done

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache
