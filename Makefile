# jaxplan: `make run` and `make test` work as the first command on a fresh clone.
VENV    ?= .venv
PYTHON  ?= python3
PY      := $(VENV)/bin/python
STAMP   := $(VENV)/.installed
RUN_CONFIG ?= experiments/paper/eight_mixed_transitions.toml
PYTEST_WORKERS ?= 2

.PHONY: install test test-slow run paper sweep studies bench lint clean

# Idempotent: (re)install only when pyproject.toml changed or the venv is missing.
# The packages are installed by uv (pinned below), which downloads and installs in
# parallel: a fresh .venv in 8 s against pip's 35 s (empty caches, this machine); pip
# installs them where no uv wheel exists for the platform.  --compile-bytecode writes
# the packages' .pyc files at install (~9 s more, as pip does by default): where Python
# does not write them itself (PYTHONDONTWRITEBYTECODE, read-only installs) every
# process would compile jax, scipy, mujoco ... from source again, ~3.5 s per `jaxplan`
# command or test child (6.2 s -> 2.5 s to import them, this machine).
UV_VERSION := 0.9.30
$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	if $(PY) -m pip install --quiet uv==$(UV_VERSION); then \
	    $(PY) -m uv pip install --quiet --compile-bytecode --python $(PY) -e ".[dev]"; \
	else \
	    $(PY) -m pip install --quiet --upgrade pip && $(PY) -m pip install --quiet -e ".[dev]"; \
	fi
	touch $(STAMP)

install: $(STAMP)

test: $(STAMP)
	$(PY) -m pytest -q -n $(PYTEST_WORKERS) --dist loadfile --durations=10

test-slow: $(STAMP)
	$(PY) -m pytest -q -m slow

run: $(STAMP)
	$(VENV)/bin/jaxplan run $(RUN_CONFIG)

# the four paper scenarios, each into runs/<name>/ with its figures
paper: $(STAMP)
	for f in experiments/paper/*.toml; do $(VENV)/bin/jaxplan run $$f || exit 1; done

# the Q_obs x Q_lim sweep: sweeps/qobs_qlim/ (sweep.csv, heatmaps in figures/)
sweep: $(STAMP)
	$(VENV)/bin/jaxplan sweep experiments/sweeps/qobs_qlim.toml

# docs/RESULTS.md: the paper scenarios (both backends), collision-mode, fault, world, stall and baselines tables
# (resumable; about three hours on 2 cores, an estimate: see experiments/studies.py)
studies: $(STAMP)
	$(PY) experiments/studies.py paper --out sweeps/studies
	$(PY) experiments/studies.py collision --out sweeps/studies
	$(PY) experiments/studies.py faults --out sweeps/studies
	$(PY) experiments/studies.py worlds --out sweeps/studies
	$(PY) experiments/studies.py deadlock --resolutions auto off --off-seeds 3 --out sweeps/studies
	$(PY) experiments/studies.py baselines --out sweeps/studies

bench: $(STAMP)
	$(VENV)/bin/jaxplan bench all --json bench.json --markdown docs/BENCHMARKS.md --readme README.md

lint: $(STAMP)
	$(VENV)/bin/ruff check jaxplan tests

clean:
	rm -rf $(VENV) runs sweeps .pytest_cache .ruff_cache .hypothesis
