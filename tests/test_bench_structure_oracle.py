"""The exact motion of benchmarks/bench_structure_oracle.py against a closed form."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from bench_structure_oracle import exact_points  # noqa: E402


def test_exact_points_carry_each_rest_point_with_its_nearest_sample() -> None:
    """Samples of a rigidly moving body (5 cm grid); rest points = samples of the rest frame
    moved by at most 1 cm (less than half the spacing, so the nearest sample is the one
    moved). Each rest point must move with that sample and keep its offset, and frame
    ``rest_index`` must return the rest points."""
    rng = np.random.default_rng(2)
    g = np.arange(0.0, 0.5, 0.05)
    S0 = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    F, ri = 6, 2
    rots = Rotation.from_rotvec(rng.normal(scale=0.3, size=(F, 3))).as_matrix()
    trans = rng.normal(scale=0.2, size=(F, 3))
    surface = np.einsum("fij,sj->fsi", rots, S0) + trans[:, None]
    pick = rng.choice(len(S0), 300, replace=False)
    offset = rng.uniform(-0.01, 0.01, size=(300, 3))
    rest = surface[ri, pick] + offset
    Y = exact_points(rest, surface, ri)
    assert Y.shape == (F, 300, 3) and Y.flags.c_contiguous
    np.testing.assert_allclose(Y[ri], rest, atol=1e-12)
    # the tied sample is the picked one: its exact motion plus the kept offset
    np.testing.assert_allclose(Y, surface[:, pick] + offset[None], atol=1e-12)
