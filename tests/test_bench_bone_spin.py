"""The per-frame bone turn of benchmarks/bench_bone_spin.py against known rotation angles."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from bench_bone_spin import frame_turn  # noqa: E402


def test_frame_turn_is_the_percentile_of_the_known_steps() -> None:
    rng = np.random.default_rng(0)
    F = 30
    steps = rng.uniform(0.0, 170.0, (F - 1, 2))  # degrees between consecutive frames
    axes = rng.normal(size=(2, 3))
    start = Rotation.random(2, random_state=1)
    R = np.empty((F, 2, 3, 3))
    for b in range(2):
        rot = start[b]
        R[0, b] = rot.as_matrix()
        for t in range(F - 1):
            # turn about a fixed axis in the bone's frame (right-multiplied): the relative
            # rotation R_t^T R_(t+1) is exactly that turn
            rot = rot * Rotation.from_rotvec(np.radians(steps[t, b]) * axes[b]
                                             / np.linalg.norm(axes[b]))
            R[t + 1, b] = rot.as_matrix()
    for p in (50.0, 90.0, 100.0):
        np.testing.assert_allclose(frame_turn(R, p), np.percentile(steps, p, axis=0),
                                   atol=1e-6)


def test_frame_turn_of_a_still_bone_is_zero() -> None:
    R = np.broadcast_to(Rotation.random(3, random_state=2).as_matrix(), (5, 3, 3, 3))
    np.testing.assert_allclose(frame_turn(np.ascontiguousarray(R)), 0.0, atol=1e-5)
