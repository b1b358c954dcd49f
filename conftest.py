"""Shared pytest setup: doctests can use ``torch`` and ``np`` without importing them."""

import numpy as np
import pytest
import torch


@pytest.fixture(autouse=True)
def _doctest_names(doctest_namespace):
    doctest_namespace.update(torch=torch, np=np)
