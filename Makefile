# Quick start: `make demo`, then `make test`. Both create .venv themselves.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test bench example clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

demo: $(STAMP)
	MPLBACKEND=Agg $(BIN)/robomill demo -o out

test: $(STAMP)
	MPLBACKEND=Agg $(BIN)/python -m pytest -q -n 2

bench: $(STAMP)
	for b in benchmarks/bench_*.py; do MPLBACKEND=Agg $(BIN)/python $$b || exit 1; done

example: $(STAMP)
	$(BIN)/python examples/kr500_acetal/make_example.py

clean:
	rm -rf $(VENV) out .pytest_cache
