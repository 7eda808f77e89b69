# Two commands a newcomer needs: `make run` and `make test`. Both set up .venv when needed.
VENV ?= .venv
BIN := $(VENV)/bin

.PHONY: setup run lint test test-fast bench clean

setup:
	@VENV=$(VENV) scripts/setup.sh

run: setup  ## full pipeline on the built-in simulated THOR sequence
	$(BIN)/slamlab $(ARGS)

lint: setup  ## the layer contract: a lower layer never imports a higher one (pyproject [tool.importlinter])
	$(BIN)/lint-imports --no-logo

# `make test` spreads the tests over TEST_WORKERS processes (pytest-xdist), a test module to one process:
# a module's fixtures (a whole run, often) are made once, and the launcher sweeps (Ray's included) never
# start side by side
TEST_WORKERS ?= 2

test: lint  ## the layer contract and the whole test suite (real-data tests need SLAMLAB_DATA_DIR or ../shared/data); CI runs this
	$(BIN)/python -m pytest -n $(TEST_WORKERS) --dist loadscope $(PYTEST_ARGS)

test-fast: lint  ## the edit loop (< 1 min): no slow, real-data or browser tests
	$(BIN)/python -m pytest -m "not slow and not data and not browser" $(PYTEST_ARGS)

bench: setup  ## speed and accuracy tables (see benchmarks/)
	for b in benchmarks/bench_*.py; do $(BIN)/python $$b || exit 1; done

clean:
	rm -rf outputs multirun reports/*.html .pytest_cache .import_linter_cache
