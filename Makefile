# TPODS lab-bench toolkit. On a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: setup debian-tools test test-slow demo bench bench-long robustness lint clean golden fixtures docs

setup: $(STAMP) debian-tools

# the Debian tools the namespace tests use (tests/support/lab_net.py): nftables for packet
# loss. Installed when missing and running as root; a failure is reported, not fatal (the
# tests that need it then skip, saying so)
DEBIAN_TOOLS := nft:nftables ip:iproute2 openssl:openssl
debian-tools:
	@for pair in $(DEBIAN_TOOLS); do \
	  cmd=$${pair%%:*}; pkg=$${pair#*:}; \
	  command -v $$cmd > /dev/null 2>&1 && continue; \
	  if [ "$$(id -u)" != 0 ] || ! command -v apt-get > /dev/null 2>&1; then \
	    echo "setup: $$cmd not found; install the Debian package $$pkg as root (apt-get install $$pkg) or the tests that need it skip"; \
	    continue; fi; \
	  echo "setup: installing $$pkg (for $$cmd)"; \
	  DEBIAN_FRONTEND=noninteractive apt-get install -y -q $$pkg > /dev/null 2>&1 \
	    || (apt-get update -q > /dev/null 2>&1 && DEBIAN_FRONTEND=noninteractive apt-get install -y -q $$pkg > /dev/null 2>&1) \
	    || echo "setup: could not install $$pkg (apt-get failed); the tests that need $$cmd skip"; \
	done

# the project's bytecode, compiled ahead of every target that starts Python processes. A
# machine may set PYTHONDONTWRITEBYTECODE (this one does): Python then never caches what it
# compiles, and every `tpods` process compiled the ~250 project modules it imports again
# (0.15-0.4 s of CPU each: a demo flight's estimator subscribed after 0.8-0.9 s instead of
# 0.5-0.6 s, and the suite starts a few hundred such processes). Only changed files are
# compiled again (0.2 s when nothing changed); errors are left to the tests to report
BYTECODE := $(BIN)/python -m compileall -q -j 0 common tpods bench calibration mocap_bridge \
	estimator benchmarks tests > /dev/null || true

$(STAMP): pyproject.toml
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test,docs]'
	@touch $(STAMP)

# in parallel over the machine's cores (pytest-xdist): a worker per core takes any test, and
# one more worker at low priority takes only the tests that do not watch the clock
# (tests/support/lanes.py; on 2 cores 299 s against 362 s with 2 workers, where a third
# equal worker starved the demo's emulated valves); the longest files start first
# (tests/conftest.py) and an idle worker takes tests from another's queue (worksteal); the
# 15 slowest tests are listed at the end. One OpenBLAS thread per process: the workers
# already use every core, and OpenBLAS's own pool spins at start-up (import numpy: 0.24 s
# CPU, 0.09 s with one thread) in each of the suite's few hundred `tpods` subprocesses
test: $(STAMP) debian-tools
	@$(BYTECODE)
	MPLBACKEND=Agg OPENBLAS_NUM_THREADS=1 $(BIN)/python -m pytest -q -n auto --dist worksteal --durations=15

# the many-seed studies marked slow (skipped by make test: tests/conftest.py), minutes each
test-slow: $(STAMP) debian-tools
	@$(BYTECODE)
	MPLBACKEND=Agg OPENBLAS_NUM_THREADS=1 $(BIN)/python -m pytest -q -n auto -m slow --durations=15

demo: $(STAMP)
	@$(BYTECODE)
	MPLBACKEND=Agg OPENBLAS_NUM_THREADS=1 $(BIN)/tpods demo

# the performance suite, under 10 minutes; exits 1 on a NO (a miss on a quiet host), not on
# "noisy host" (docs/bench.md)
bench: $(STAMP)
	@$(BYTECODE)
	MPLBACKEND=Agg $(BIN)/python -m benchmarks.run --out runs/bench.json

# the cases that take minutes each (benchmarks/run.py LONG_CASES), then the robustness properties
bench-long: $(STAMP)
	@$(BYTECODE)
	MPLBACKEND=Agg $(BIN)/python -m benchmarks.run --long --out runs/bench-long.json
	$(MAKE) robustness

# the CLI robustness properties with 25x the examples of `make test`, not derandomised
robustness: $(STAMP)
	MPLBACKEND=Agg TPODS_HYPOTHESIS_PROFILE=long $(BIN)/python -m pytest -q -p no:cacheprovider \
		tests/tpods/cli/test_properties.py tests/tpods/cli/test_properties_plausible.py \
		tests/tpods/cli/test_properties_surfaces.py

# the documentation site from docs/ into site/ (mkdocs.yml; the CLI reference is generated
# from the parsers by docs_tools/hooks.py); --strict: a broken link or a page left out of
# the nav fails the build
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --site-dir site

lint: $(STAMP)
	$(BIN)/ruff check .

# rewrite the golden outputs beside runs/fixtures/* from today's code, printing what moved
# (review with `git diff runs/fixtures` before committing)
golden: $(STAMP)
	MPLBACKEND=Agg $(BIN)/python -m pytest -q -s -p no:cacheprovider tests/regression --update-goldens

# record the serial fixture (runs/fixtures/bench-session) again against the emulators,
# and live-run, bifilar-swing, structure-run against the simulated module and simulator
fixtures: $(STAMP)
	$(BIN)/python -m tests.support.make_fixtures bench
	$(BIN)/python -m tests.support.fixtures_recorded all

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache site
