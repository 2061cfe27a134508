# jaxplan: `make run` and `make test` work as the first command on a fresh clone.
VENV    ?= .venv
PYTHON  ?= python3
PY      := $(VENV)/bin/python
STAMP   := $(VENV)/.installed
RUN_CONFIG ?= experiments/paper/eight_mixed_transitions.toml
PYTEST_WORKERS ?= 2

.PHONY: install test test-slow run bench lint figures clean

# Idempotent: (re)install only when pyproject.toml changed or the venv is missing.
$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[dev]"
	touch $(STAMP)

install: $(STAMP)

test: $(STAMP)
	$(PY) -m pytest -q -n $(PYTEST_WORKERS) --dist loadfile

test-slow: $(STAMP)
	$(PY) -m pytest -q -m slow

run: $(STAMP)
	$(VENV)/bin/jaxplan run $(RUN_CONFIG)

bench: $(STAMP)
	$(VENV)/bin/jaxplan bench all --json bench.json

lint: $(STAMP)
	$(VENV)/bin/ruff check jaxplan tests

clean:
	rm -rf $(VENV) runs sweeps .pytest_cache .ruff_cache .hypothesis
