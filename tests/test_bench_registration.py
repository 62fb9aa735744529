"""benchmarks/bench_registration.py's metrics: the correspondence error ties the rest points to
the surface of the frame they came from."""

from __future__ import annotations

import numpy as np
from benchmarks.bench_registration import correspondence_error, nearest_observed, sequence_errors

from pointrig.registration import RegistrationResult


def _surface_motion(n_frames: int = 5, n: int = 400) -> np.ndarray:
    """``(F, n, 3)`` surface samples, metres: a unit-sphere shell turning about y by 10 deg a
    frame and drifting 2 cm a frame along x."""
    rng = np.random.default_rng(3)
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    out = []
    for t in range(n_frames):
        a = np.deg2rad(10.0 * t)
        rot = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
        out.append(v @ rot.T + [0.02 * t, 0.0, 0.0])
    return np.stack(out)


def test_exact_motion_from_any_rest_frame_has_no_error() -> None:
    """Rest points sampled 1 mm off frame ``r``'s surface and moved exactly with it: the error
    is zero when measured from frame ``r``, and large when measured from frame 0 (the points
    are then tied to the wrong samples)."""
    surface = _surface_motion()
    r = 3
    rest = surface[r] + 0.001 / np.sqrt(3)
    points = surface + (rest - surface[r])[None]
    err = correspondence_error(rest, points, surface, r)
    assert err.shape == (5, 400)
    np.testing.assert_allclose(err, 0.0, atol=1e-12)
    wrong = correspondence_error(rest, points, surface, 0)
    assert wrong.size == 0 or wrong.mean() > 0.01


def test_error_is_the_displacement_difference() -> None:
    """Points that lag the surface by 5 cm along z in frame 2 only: 5 cm there, 0 elsewhere
    (oracle: the lag itself)."""
    surface = _surface_motion()
    points = surface.copy()
    points[2, :, 2] -= 0.05
    err = correspondence_error(surface[1], points, surface, 1)
    np.testing.assert_allclose(err[2], 0.05, atol=1e-12)
    np.testing.assert_allclose(np.delete(err, 2, axis=0), 0.0, atol=1e-12)


def test_nearest_observed_against_brute_force() -> None:
    """Each registered point's distance to its own frame's nearest observed point, against all
    pairwise distances in numpy."""
    rng = np.random.default_rng(1)
    points = rng.normal(size=(3, 50, 3))
    frames = [rng.normal(size=(n, 3)) for n in (30, 60, 45)]
    got = nearest_observed(points, frames)
    want = np.stack([np.linalg.norm(p[:, None] - f[None], axis=2).min(1)
                     for p, f in zip(points, frames)])
    np.testing.assert_allclose(got, want, rtol=1e-12)


def test_sequence_errors_measure_from_the_chosen_rest_frame() -> None:
    """A registration from rest frame 3 that follows the surface exactly (rest points 1 mm off
    frame 3's samples): the sequence table's correspondence error is zero (oracle: the exact
    motion), which it is not when measured from frame 0; the registered points lie 1 mm from
    the observed ones (oracle: the offset)."""
    surface = _surface_motion()
    r = 3
    offset = 0.001 / np.sqrt(3)
    rest = surface[r] + offset
    points = surface + offset
    n = len(surface)
    res = RegistrationResult(rest_points=rest, points=points, sigma2=np.zeros(n),
                             iterations=np.zeros(n, dtype=np.int64), energy=np.zeros(n),
                             params={"rest_frame_index": r})
    no_mean, no_p90, ce = sequence_errors(res, list(surface), surface)
    assert ce < 1e-12
    np.testing.assert_allclose([no_mean, no_p90], 0.001, rtol=1e-9)
    res.params["rest_frame_index"] = 0
    # from frame 0 the rest points are tied to the wrong samples or to none (no mean)
    assert not sequence_errors(res, list(surface), surface)[2] < 0.01
