# arteq — common tasks. `make install` creates .venv and installs the project (editable).
PY ?= python3
VENV ?= .venv
BIN := $(VENV)/bin

.PHONY: install test test-slow lint format train anny22 clean

$(BIN)/python:
	$(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip

install: $(BIN)/python
	$(BIN)/pip install -q -e ".[anny,dev]"

test:
	$(BIN)/python -m pytest -q

test-slow:
	$(BIN)/python -m pytest -q -m slow

lint:
	$(BIN)/ruff check src tests benchmarks
	$(BIN)/ruff format --check src tests benchmarks

format:
	$(BIN)/ruff check --fix src tests benchmarks
	$(BIN)/ruff format src tests benchmarks

train:
	$(BIN)/python -m arteq.train +experiment=stage2

anny22:
	$(BIN)/python -m arteq.body.anny22

clean:
	rm -rf .pytest_cache outputs multirun
