# Two commands do all set-up on a fresh machine:
#   make demo   # creates .venv, installs observer-gym (the core install: no PyTorch), runs `observer-gym demo`
#   make test   # creates .venv, adds the [rl] and dev extras (PyTorch, stable-baselines3, pytest, ...), runs the tests
# PyTorch (stable-baselines3 and the learned observers need it: the [rl] extra) is pinned
# first so pip does not pick another build.
PYTHON ?= python3
VENV ?= .venv
TORCH ?= torch==2.13.0
BIN := $(VENV)/bin

.PHONY: demo test bench lint typecheck

# The package and what it needs to run (the demo's install: the core, no PyTorch).
$(BIN)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e .
	touch $@

# Plus PyTorch (pinned, first), the [rl] extra and the tests' and linters' extras.
$(BIN)/.installed-dev: $(BIN)/.installed
	$(BIN)/python -m pip install --quiet "$(TORCH)"
	$(BIN)/python -m pip install --quiet -e ".[rl,dev]"
	touch $@

demo: $(BIN)/.installed
	$(BIN)/observer-gym demo

test: $(BIN)/.installed-dev
	$(BIN)/python -m pytest --durations=15

bench: $(BIN)/.installed
	$(BIN)/python benchmarks/bench_envs.py

lint: $(BIN)/.installed-dev
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

# mypy on the package as installed (observer_gym.envs is envs/, ...): .ci/typecheck.py
typecheck: $(BIN)/.installed-dev
	$(BIN)/python .ci/typecheck.py
