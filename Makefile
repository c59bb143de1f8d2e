# Two set-up commands: `make demo` (main job) and `make test` (test suite).
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin

$(BIN)/jaxplan: pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -e ".[test]"
	touch $@

# a handful of shared-format scenes where ../shared is there (the built-in ones always)
DEMO_SCENES := $(wordlist 1,4,$(sort $(wildcard ../shared/data/commonroad2018a/*.json)))

demo: $(BIN)/jaxplan
	$(BIN)/jaxplan drive --builtin --quick --planner lattice --out results/demo $(DEMO_SCENES)
	@sed -n '1,/^Wall time/p' results/demo/report.md

# every evaluation suite and its report (long: see docs/evaluation.md)
eval: $(BIN)/jaxplan
	$(BIN)/jaxplan eval all --out results/eval
	$(BIN)/jaxplan report results/eval

# lint, format and types of the package (the test suite builds the docs)
check: $(BIN)/jaxplan
	$(BIN)/pip install -q -e ".[test,lint]"
	$(BIN)/ruff check jaxplan
	$(BIN)/ruff format --check jaxplan
	$(BIN)/mypy

# The suite on two workers. A worker frees its compiled programs before it reaches the kernel's limit
# on memory maps (XLA aborted there, in a different test each time); should a worker still crash, it is
# replaced and its test runs once more (tests/conftest.py).
SUITE ?= tests
PYTEST_ARGS := -n 2 --max-worker-restart=2 --dist loadfile --no-loadscope-reorder --durations=15
test: $(BIN)/jaxplan
	$(BIN)/python -m pytest $(PYTEST_ARGS) $(SUITE)

bench: $(BIN)/jaxplan
	$(BIN)/pip install -q -e ".[test,bench]"
	for b in geometry bounds lattice speed parkout sim; do \
	  $(BIN)/python experiments/bench_$$b.py --out results/bench_$$b.json || exit 1; done

.PHONY: demo eval check test bench
