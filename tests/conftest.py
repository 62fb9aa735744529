"""Shared pytest fixtures.

The whole suite (``make test``) runs every test. Long end-to-end tests carry
``@pytest.mark.slow``; while iterating, ``python -m pytest -m "not slow"`` leaves them out.
Benchmark modules are imported as ``benchmarks.NAME`` (pyproject's ``pythonpath`` puts the
repository root on the path).
"""

from __future__ import annotations

import numpy as np
import pytest


@pytest.fixture
def rng() -> np.random.Generator:
    """A seeded random generator."""
    return np.random.default_rng(12345)
