# TPODS lab-bench toolkit. On a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: setup test demo bench robustness lint clean

setup: $(STAMP)

$(STAMP): pyproject.toml
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	@touch $(STAMP)

test: $(STAMP)
	MPLBACKEND=Agg $(BIN)/python -m pytest -q

demo: $(STAMP)
	MPLBACKEND=Agg $(BIN)/tpods demo

bench: $(STAMP)
	MPLBACKEND=Agg $(BIN)/python -m benchmarks.run --out runs/bench.json
	$(MAKE) robustness

# the CLI robustness properties with 25x the examples of `make test`, not derandomised
robustness: $(STAMP)
	MPLBACKEND=Agg TPODS_HYPOTHESIS_PROFILE=long $(BIN)/python -m pytest -q -p no:cacheprovider \
		tests/tpods/cli/test_properties.py

lint: $(STAMP)
	$(BIN)/ruff check .

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache
