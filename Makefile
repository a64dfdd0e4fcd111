# arteq — common tasks. `make install` creates .venv and installs the project (editable).
PY ?= python3
# Installed before the project: pyproject allows any torch >= 2.4, and pip would otherwise pick the newest
# build for this platform (on Linux a multi-GB CUDA one). Here 2.13.0 is the on-disk CPU build; a GPU user
# can pass e.g. TORCH="torch==2.13.0 --index-url <their CUDA index>".
TORCH ?= torch==2.13.0
VENV ?= .venv
BIN := $(VENV)/bin

.PHONY: install test test-slow lint format train anny22 clean

$(BIN)/python:
	$(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip

install: $(BIN)/python
	$(BIN)/pip install -q $(TORCH)
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
