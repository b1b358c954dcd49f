# One virtual env for everything; each target is idempotent.
VENV ?= .venv
PY := $(VENV)/bin/python
PYTHON ?= python3

.PHONY: setup demo test test-fast bench clean

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

$(VENV)/.bench: $(VENV)/.installed
	$(PY) -m pip install -q -e '.[train,test,bench]'
	touch $@

# the development suite on whichever sets are given: make bench YUD=... MANIFEST=labels.csv RENDERS=folder
bench: $(VENV)/.bench
	$(PY) benchmarks/devsuite.py $(if $(YUD),--yud $(YUD)) $(if $(MANIFEST),--manifest $(MANIFEST)) \
		$(if $(RENDERS),--renders $(RENDERS)) --json bench.json

clean:
	rm -rf $(VENV)
