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
	$(BIN)/jaxplan eval all --quick --out results
	$(BIN)/jaxplan report results

test: $(BIN)/jaxplan
	$(BIN)/python -m pytest tests

bench: $(BIN)/jaxplan
	$(BIN)/python experiments/bench_geometry.py

.PHONY: demo test bench
