# Each target does its own setup on a fresh machine.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test slow bench lint clean cholmod

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(STAMP): $(BIN)/python pyproject.toml
	$(BIN)/python -m pip install --quiet -e '.[test]'
	@$(MAKE) --no-print-directory cholmod
	touch $(STAMP)

# CHOLMOD (SuiteSparse), a system library: 4-5x faster factorisations of the continuum's
# K than SuperLU (docs/inverse.md). Best effort: Debian's libcholmod3 through apt-get when
# it is missing and apt-get may run; otherwise SuperLU serves and nothing else changes.
cholmod:
	@if ldconfig -p 2>/dev/null | grep -q 'libcholmod\.so\.3'; then \
		echo "CHOLMOD: libcholmod.so.3 found"; \
	elif command -v apt-get >/dev/null 2>&1 && [ "$$(id -u)" = 0 ]; then \
		DEBIAN_FRONTEND=noninteractive apt-get install -y -q libcholmod3 >/dev/null 2>&1 \
			|| (apt-get update -q >/dev/null 2>&1 && DEBIAN_FRONTEND=noninteractive apt-get install -y -q libcholmod3 >/dev/null 2>&1) \
			&& echo "CHOLMOD: installed Debian's libcholmod3" \
			|| echo "CHOLMOD: apt-get could not install libcholmod3; SuperLU serves"; \
	else \
		echo "CHOLMOD: libcholmod.so.3 not found (Debian: apt-get install libcholmod3); SuperLU serves"; \
	fi

demo: $(STAMP)
	MPLBACKEND=Agg $(BIN)/dvs demo --out demo-output

test: $(STAMP)
	$(BIN)/ruff check symbolic solvers experiments tests
	$(BIN)/ruff format --check symbolic solvers experiments tests
	MPLBACKEND=Agg $(BIN)/python -m pytest

slow: $(STAMP)
	MPLBACKEND=Agg $(BIN)/python -m pytest -m slow

bench: $(STAMP)
	MPLBACKEND=Agg $(BIN)/python -m experiments.inverse.inversebench
	MPLBACKEND=Agg $(BIN)/python -m experiments.inverse.inversebench --diagnose
	$(BIN)/dvs bench board
	$(BIN)/dvs bench image

lint: $(STAMP)
	$(BIN)/ruff check symbolic solvers experiments tests
	$(BIN)/ruff format --check symbolic solvers experiments tests

clean:
	rm -rf $(VENV) demo-output .pytest_cache .ruff_cache
