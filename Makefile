# Each target does its own setup on a fresh machine.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
TEST_WORKERS ?= 2

.PHONY: demo test slow bench lint clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(STAMP): $(BIN)/python pyproject.toml
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

demo: $(STAMP)
	MPLBACKEND=Agg $(BIN)/dvs demo --out demo-output

test: $(STAMP)
	$(BIN)/ruff check symbolic solvers experiments tests
	$(BIN)/ruff format --check symbolic solvers experiments tests
	MPLBACKEND=Agg $(BIN)/python -m pytest -n $(TEST_WORKERS) --dist loadfile

slow: $(STAMP)
	MPLBACKEND=Agg $(BIN)/python -m pytest -m slow

bench: $(STAMP)
	MPLBACKEND=Agg $(BIN)/python -m experiments.inverse.bench
	MPLBACKEND=Agg $(BIN)/python -m experiments.inverse.bench --diagnose
	$(BIN)/dvs bench board
	$(BIN)/dvs bench image

lint: $(STAMP)
	$(BIN)/ruff check symbolic solvers experiments tests
	$(BIN)/ruff format --check symbolic solvers experiments tests

clean:
	rm -rf $(VENV) demo-output .pytest_cache .ruff_cache
