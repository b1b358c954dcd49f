"""Shared pytest setup: doctests can use ``torch`` and ``np`` without importing them; the notebooks count as slow
tests (``pytest -m "not slow"`` skips them with the training and multi-process runs); a test run on the ``device``
fixture's CUDA device counts as a gpu test (``pytest -m gpu``, ``make test-gpu``)."""

import numpy as np
import pytest
import torch


@pytest.fixture(autouse=True)
def _doctest_names(doctest_namespace):
    doctest_namespace.update(torch=torch, np=np)


def pytest_collection_modifyitems(items):
    for item in items:
        if item.path.suffix == ".ipynb":
            item.add_marker(pytest.mark.slow)
        # a test run on the CUDA device of the ``device`` fixture is a gpu test too (make test-gpu runs them all)
        callspec = getattr(item, "callspec", None)
        if callspec is not None and callspec.params.get("device") == "cuda":
            item.add_marker(pytest.mark.gpu)
