# The two commands a new user needs (see README):
#   make run    set up .venv and start the service on an embedded default store (./memory)
#   make test   set up .venv (with test extras) and run ruff + the test suite
VENV ?= .venv
PY := $(VENV)/bin/python
PIP := $(PY) -m pip
HOST ?= 127.0.0.1
PORT ?= 8000
DATA ?= ./memory

.PHONY: setup setup-test run test lint format bench

$(VENV)/.base: pyproject.toml
	python3 -m venv $(VENV)
	$(PIP) install -q --upgrade pip
	# torch first, pinned to the CPU wheel on disk, so no dependency pulls another build
	$(PIP) install -q torch==2.13.0
	$(PIP) install -q -e .
	touch $@

$(VENV)/.test: $(VENV)/.base
	$(PIP) install -q -e ".[test]"
	bash scripts/ensure-chromium.sh
	touch $@

setup: $(VENV)/.base
setup-test: $(VENV)/.test

run: setup
	$(VENV)/bin/tactus serve --host $(HOST) --port $(PORT) --data $(DATA)

lint: setup-test
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

test: setup-test lint
	$(VENV)/bin/pytest -q

format: setup-test
	$(VENV)/bin/ruff format .
	$(VENV)/bin/ruff check --fix .

bench: setup
	$(PY) benchmarks/memory.py
	$(PY) benchmarks/touch.py
	$(PY) benchmarks/service.py
