"""benchmarks/bench_tracks.py's visibility: the samples a camera sees, against the closed form
of a sphere (a point of a convex surface is seen when the surface faces the camera there) and an
occluded sphere behind it."""

from __future__ import annotations

import numpy as np
from benchmarks.bench_tracks import seen_from


def _sphere(centre: np.ndarray, radius: float, n: int, seed: int) -> np.ndarray:
    d = np.random.default_rng(seed).normal(size=(n, 3))
    return centre + radius * d / np.linalg.norm(d, axis=1, keepdims=True)


def test_a_sphere_shows_the_cap_that_faces_the_camera() -> None:
    cam = np.zeros(3)
    c = np.array([0.1, -0.05, 2.0])
    p = _sphere(c, 0.2, 40000, 0)
    to_cam = (cam - p) / np.linalg.norm(cam - p, axis=1, keepdims=True)
    cos_inc = np.einsum("ij,ij->i", (p - c) / 0.2, to_cam)  # > 0: faces the camera
    seen = seen_from(p, cam)
    # the closed form, away from the rim (grazing views fall out of the depth tolerance, as
    # they leave a real depth image)
    assert seen[cos_inc > 0.5].mean() > 0.99
    assert not seen[cos_inc < -0.1].any()
    assert 0.8 < seen.sum() / (cos_inc > 0).sum() <= 1.0
    # nothing of the far half is seen, all of the near cap's centre is
    assert not seen[p[:, 2] > c[2] + 0.02].any()
    assert seen[np.linalg.norm(p - (c - [0, 0, 0.2]), axis=1) < 0.1].all()


def test_a_sphere_hidden_behind_another_is_not_seen() -> None:
    front = _sphere(np.array([0.0, 0.0, 2.0]), 0.2, 40000, 1)
    back = _sphere(np.array([0.0, 0.0, 3.0]), 0.1, 5000, 2)
    seen = seen_from(np.vstack([front, back]), np.zeros(3))
    assert not seen[len(front):].any()
    assert seen[:len(front)].mean() > 0.35
