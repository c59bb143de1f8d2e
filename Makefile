# Two set-up commands: `make demo` (main job) and `make test` (test suite).
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin

$(BIN)/jaxplan: pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -e ".[test]"
	touch $@

demo: $(BIN)/jaxplan
	$(BIN)/jaxplan drive --builtin --quick --planner all --out results/drive
	$(BIN)/jaxplan eval all --quick --out results
	$(BIN)/jaxplan report results

test: $(BIN)/jaxplan
	$(BIN)/python -m pytest -n 2 --dist loadfile --no-loadscope-reorder --durations=15 tests

bench: $(BIN)/jaxplan
	$(BIN)/pip install -q -e ".[test,bench]"
	for b in geometry bounds lattice speed parkout sim; do \
	  $(BIN)/python experiments/bench_$$b.py --out results/bench_$$b.json || exit 1; done

.PHONY: demo test bench
