# One virtual env for everything; each target is idempotent.
VENV ?= .venv
PY := $(VENV)/bin/python
PYTHON ?= python3

.PHONY: setup demo test test-fast test-gpu docs bench clean

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	# the CPU wheel of torch first, so the range in pyproject.toml never pulls a CUDA build
	$(PY) -m pip install -q torch==2.13.0
	$(PY) -m pip install -q -e '.[train,test]'
	touch $@

setup: $(VENV)/.installed

demo: setup
	$(VENV)/bin/ngp demo

test: setup
	$(VENV)/bin/ruff check ngp_kornia tests benchmarks
	$(PY) -m pytest

# the same without the slow tests (training runs, multi-process runs, notebooks)
test-fast: setup
	$(VENV)/bin/ruff check ngp_kornia tests benchmarks
	$(PY) -m pytest -m "not slow"

# the tests that need a CUDA device (the batch path and one training step of each LightningModule on the GPU); they
# skip without one. Install a CUDA build of torch in the venv first: setup installs the CPU wheel.
test-gpu: setup
	$(PY) -m pytest -m gpu -p no:cacheprovider -rs

$(VENV)/.docs: $(VENV)/.installed
	$(PY) -m pip install -q -e '.[docs]'
	touch $@

# the API reference from the docstrings (pdoc, Google style) in docs/api: open docs/api/index.html. A pdoc warning
# (a module that does not import, an __all__ name that does not exist) or a malformed docstring section (ruff's
# pydocstyle rules, which make test checks too) fails it
docs: $(VENV)/.docs
	$(VENV)/bin/ruff check ngp_kornia docs
	$(PY) docs/build_api.py docs/api

$(VENV)/.bench: $(VENV)/.installed
	$(PY) -m pip install -q -e '.[train,test,bench]'
	touch $@

# the development suite on whichever sets are given: make bench YUD=... MANIFEST=labels.csv RENDERS=folder
bench: $(VENV)/.bench
	$(PY) benchmarks/devsuite.py $(if $(YUD),--yud $(YUD)) $(if $(MANIFEST),--manifest $(MANIFEST)) \
		$(if $(RENDERS),--renders $(RENDERS)) --json bench.json

clean:
	rm -rf $(VENV)
