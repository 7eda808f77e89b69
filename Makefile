# Two commands a newcomer needs: `make run` and `make test`. Both set up .venv when needed.
VENV ?= .venv
BIN := $(VENV)/bin

.PHONY: setup run test test-fast bench clean

setup:
	@VENV=$(VENV) scripts/setup.sh

run: setup  ## full pipeline on the built-in simulated THOR sequence
	$(BIN)/slamlab $(ARGS)

test: setup  ## the whole test suite (real-data tests need SLAMLAB_DATA_DIR or ../shared/data)
	$(BIN)/python -m pytest $(PYTEST_ARGS)

bench: setup  ## speed and accuracy tables (see benchmarks/)
	for b in benchmarks/bench_*.py; do $(BIN)/python $$b || exit 1; done

clean:
	rm -rf outputs multirun reports/*.html .pytest_cache
