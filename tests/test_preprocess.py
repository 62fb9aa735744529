"""The rest surface's clean-up: sparse points (flying pixels, outliers) go, the subject stays."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.spatial import cKDTree

from pointrig.config import RegistrationConfig
from pointrig.errors import ConfigError
from pointrig.preprocess import remove_sparse_points, remove_statistical_outliers, rest_surface
from pointrig.registration import register_sequence
from pointrig.sequence import PointSequence
from pointrig.synth import Camera, NoiseConfig, synthesize


def _plane_with_curtain(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A 60 x 60 grid at 5 mm (a surface seen by a depth camera) plus a curtain of flying
    pixels behind one edge (one per edge sample, up to 30 cm back) and uniform outliers;
    returns ``(points (N, 3), is_surface (N,))``."""
    rng = np.random.default_rng(seed)
    g = np.arange(60) * 0.005
    xx, yy = np.meshgrid(g, g)
    plane = np.column_stack([xx.ravel(), yy.ravel(), np.full(xx.size, 2.0)])
    plane[:, 2] += rng.normal(0, 0.001, len(plane))
    edge = plane[plane[:, 0] == g[-1]]
    curtain = edge + np.column_stack([np.zeros((len(edge), 2)),
                                      rng.uniform(0.0, 0.3, len(edge))])
    curtain = curtain[curtain[:, 2] > 2.05]  # within a few spacings they are surface-like
    outliers = rng.uniform([-0.3, -0.3, 1.7], [0.6, 0.6, 2.4], (40, 3))
    pts = np.vstack([plane, curtain, outliers])
    return pts, np.arange(len(pts)) < len(plane)


def test_sparse_points_go_where_the_statistical_removal_keeps_them() -> None:
    pts, surf = _plane_with_curtain()
    kept = remove_sparse_points(pts, 10, 4.0)
    tree = cKDTree(pts)
    idx = tree.query(kept)[1]
    assert np.all(tree.query(kept)[0] == 0.0)  # points are copied, not moved
    assert np.all(np.diff(idx) > 0)  # input order
    assert surf[idx].all()  # every curtain point and outlier is gone
    assert len(kept) >= 0.99 * surf.sum()  # and the surface stays
    # the statistical removal keeps some of them (the failure this guards against)
    sor = remove_statistical_outliers(pts, 20, 2.0)
    assert not surf[tree.query(sor)[1]].all()
    # 0 turns it off
    np.testing.assert_array_equal(remove_sparse_points(pts, 10, 0.0), pts)


def test_rest_surface_of_a_kinect_frame_lies_on_the_subject() -> None:
    """Default Kinect noise with flying pixels and 2 % outliers: the rest points against the
    renderer's true surface (oracle), with and without the sparse-point filter."""
    noise = dataclasses.replace(NoiseConfig(seed=2), outliers=0.02)
    syn = synthesize("human", n_frames=1, seed=1, camera=Camera.kinect(640), noise=noise)
    surface = syn.surface[0]
    size = float(np.linalg.norm(surface.max(0) - surface.min(0)))
    far = {}
    for ratio in (0.0, 4.0):
        rest = rest_surface(syn.frames[0], 2000, sparse_ratio=ratio)
        d = cKDTree(surface).query(rest)[0]
        far[ratio] = float(np.mean(d > 0.03 * size))
    assert far[0.0] > 0.03  # without it, farthest-point sampling picks the flying pixels
    assert far[4.0] < 0.005


def test_rest_sparse_parameters_are_validated() -> None:
    seq = PointSequence([np.random.default_rng(0).normal(size=(200, 3)) * 0.1 + [0, 0, 2]] * 2)
    for kw in ({"rest_sparse_ratio": 0.5}, {"rest_sparse_ratio": -1.0},
               {"rest_sparse_neighbors": 0}):
        with pytest.raises(ConfigError, match="rest_sparse"):
            register_sequence(seq, dataclasses.replace(RegistrationConfig(), **kw))
