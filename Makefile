# Quick start: `make demo`, then `make test`. Both create .venv themselves, from the lock.
#
# Installs are locked: requirements.lock pins every package (with hashes) for Python 3.11 on any
# platform, so a fresh machine gets exactly what CI got; pyproject.toml keeps ranges for people
# who install robomill as a library. `make lock` refreshes the locks after a change of
# pyproject.toml's dependencies (uv, pinned below, in a throwaway .tools venv).
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
PIP := $(BIN)/python -m pip --disable-pip-version-check
STAMP := $(VENV)/.installed
BENCH_STAMP := $(VENV)/.installed-bench
LOCK := requirements.lock
BENCH_LOCK := requirements-bench.lock
UV_VERSION := 0.13.9
COMPILE = .tools/bin/uv pip compile --quiet pyproject.toml requirements-build.in --python-version 3.11 \
	--universal --generate-hashes

.PHONY: demo test bench example lock newcomer clean

$(STAMP): $(LOCK) pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PIP) install --quiet --require-hashes -r $(LOCK)
	$(PIP) install --quiet --no-deps --no-build-isolation -e .
	touch $(STAMP)

$(BENCH_STAMP): $(BENCH_LOCK) $(STAMP)
	$(PIP) install --quiet --require-hashes -r $(BENCH_LOCK)
	touch $(BENCH_STAMP)

demo: $(STAMP)
	MPLBACKEND=Agg $(BIN)/robomill demo -o out

# the two test workers already use both cores: learn's tables are filled in-process there
test: $(STAMP)
	MPLBACKEND=Agg ROBOMILL_WORKERS=1 $(BIN)/python -m pytest -q -n 2

bench: $(BENCH_STAMP)
	for b in benchmarks/bench_*.py; do MPLBACKEND=Agg $(BIN)/python $$b || exit 1; done

example: $(STAMP)
	$(BIN)/python examples/kr500_acetal/make_example.py

lock:
	$(PYTHON) -m venv .tools
	.tools/bin/python -m pip install --quiet --disable-pip-version-check uv==$(UV_VERSION)
	$(COMPILE) --extra test -o $(LOCK)
	$(COMPILE) --extra test --extra peers -o $(BENCH_LOCK)

# The newcomer's path on an empty checkout: a fresh clone beside this one (so ../shared resolves
# as in CI), no .venv, no numba cache, no out/, no pip cache; `make demo`, then `make test`.
newcomer:
	bash .ci/newcomer

clean:
	rm -rf $(VENV) .tools out .pytest_cache
