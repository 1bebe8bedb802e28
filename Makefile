# Two commands (see README):  make demo   (install everything, run the main demo)
#                             make test   (lint + tests; what CI runs)
PYTHON ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
DEMO ?= trot

.PHONY: install install-gym demo test lint bench clean

$(BIN)/cafe-mpc: pyproject.toml requirements.lock
	@command -v $(PYTHON) >/dev/null 2>&1 || { echo "need $(PYTHON) (set PYTHON=...)"; exit 1; }
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -r requirements.lock
	$(BIN)/python -m pip install --quiet --no-deps -e .
	touch $(BIN)/cafe-mpc

install: $(BIN)/cafe-mpc

# the optional extra cafe-mpc[gym] (gym-quadruped as an external plant), pinned in requirements-gym.lock
$(VENV)/.gym-installed: $(BIN)/cafe-mpc requirements-gym.lock
	$(BIN)/python -m pip install --quiet -r requirements-gym.lock
	touch $(VENV)/.gym-installed

install-gym: $(VENV)/.gym-installed

demo: install
	$(BIN)/cafe-mpc run $(DEMO)

lint: install
	$(BIN)/ruff check src tests benchmarks examples
	$(BIN)/ruff format --check src tests benchmarks examples

test: install install-gym
	$(BIN)/ruff check src tests benchmarks examples
	$(BIN)/python -m pytest tests

bench: install
	$(BIN)/python benchmarks/bench_dynamics.py

clean:
	rm -rf $(VENV) runs .pytest_cache .ruff_cache
