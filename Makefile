# Two commands (see README):  make demo   (install everything, run the main demo)
#                             make test   (lint + tests; what CI runs)
PYTHON ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
DEMO ?= trot

.PHONY: install install-gym install-robot browser demo test lint bench clean

$(BIN)/cafe-mpc: pyproject.toml requirements.lock
	@command -v $(PYTHON) >/dev/null 2>&1 || { echo "need $(PYTHON) (set PYTHON=...)"; exit 1; }
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -r requirements.lock
	$(BIN)/python -m pip install --quiet --no-deps -e .
	$(BIN)/cafe-mpc compile   # the numba kernels compiled and cached now, so that the first run moves at once
	touch $(BIN)/cafe-mpc

install: $(BIN)/cafe-mpc

# the optional extra cafe-mpc[gym] (gym-quadruped as an external plant), pinned in requirements-gym.lock
$(VENV)/.gym-installed: $(BIN)/cafe-mpc requirements-gym.lock
	$(BIN)/python -m pip install --quiet -r requirements-gym.lock
	touch $(VENV)/.gym-installed

install-gym: $(VENV)/.gym-installed

# the optional extra cafe-mpc[robot] (Cyclone DDS for cafe-mpc deploy and sim-robot), pinned in
# requirements-robot.lock
$(VENV)/.robot-installed: $(BIN)/cafe-mpc requirements-robot.lock
	$(BIN)/python -m pip install --quiet -r requirements-robot.lock
	touch $(VENV)/.robot-installed

install-robot: $(VENV)/.robot-installed

demo: install
	$(BIN)/cafe-mpc run $(DEMO)

lint: install
	$(BIN)/ruff check src tests benchmarks examples
	$(BIN)/ruff format --check src tests benchmarks examples

# the report tests open pages in headless Chromium (tests/test_report.py; they skip without it): install
# Debian's chromium when no Chromium is on the PATH and apt-get can (as root, or through passwordless sudo);
# otherwise, or when the install fails (offline), say so and go on
BROWSERS := chromium chromium-browser google-chrome
browser:
	@if (for b in $(BROWSERS); do command -v $$b >/dev/null 2>&1 && exit 0; done; exit 1); then :; \
	elif ! command -v apt-get >/dev/null 2>&1; then \
	  echo "no Chromium and no apt-get: the report's browser tests will skip"; \
	else \
	  if [ "$$(id -u)" = 0 ]; then SUDO=; elif sudo -n true 2>/dev/null; then SUDO="sudo -n"; else SUDO=none; fi; \
	  if [ "$$SUDO" = none ]; then echo "no Chromium, and apt-get needs root: the report's browser tests will skip"; \
	  else echo "installing chromium for the report's browser tests (apt-get)"; \
	    { $$SUDO apt-get update -qq && $$SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium \
	      >/dev/null; } \
	      || echo "chromium could not be installed: the report's browser tests will skip"; fi; \
	fi

test: install install-gym install-robot browser
	$(BIN)/ruff check src tests benchmarks examples
	$(BIN)/python -m pytest tests

bench: install
	$(BIN)/python benchmarks/bench_dynamics.py

clean:
	rm -rf $(VENV) runs .pytest_cache .ruff_cache
