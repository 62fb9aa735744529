"""Input that is mostly a uniform scatter of outliers: recognised, cleaned against the dense
points, warned about and recorded in ``skeleton.json``; clean input is cleaned as before.

The oracle is the generated data: which points are surface and which are outliers is known.
"""

from __future__ import annotations

import json
import logging

import numpy as np

from pointrig.geometry import remove_sparse_points
from pointrig.pipeline import extract
from pointrig.preprocess import OUTLIER_SUSPECT, outlier_fraction, remove_sparse_frames
from pointrig.sequence import PointSequence
from pointrig.synth import NoiseConfig, synthesize


def _surface(rng: np.random.Generator, n_side: int = 60, spacing: float = 0.005) -> np.ndarray:
    """A gently curved sheet sampled at ``spacing`` metres, 2 m from the camera: ``(n^2, 3)``."""
    u, v = np.meshgrid(np.arange(n_side) * spacing, np.arange(n_side) * spacing)
    z = 2.0 + 0.3 * (u - u.mean()) ** 2
    pts = np.stack([u.ravel(), v.ravel(), z.ravel()], axis=1)
    return pts + rng.normal(scale=0.0005, size=pts.shape)


def _scatter(rng: np.random.Generator, around: np.ndarray, n: int) -> np.ndarray:
    """``n`` uniform outliers in the box of ``around`` enlarged by 0.3 m."""
    lo, hi = around.min(0) - 0.3, around.max(0) + 0.3
    return rng.uniform(lo, hi, size=(n, 3))


def test_outlier_fraction_measures_a_known_scatter():
    rng = np.random.default_rng(0)
    surf = _surface(rng)
    assert outlier_fraction(surf) < 0.05
    for share in (0.3, 0.5, 0.7):
        n_out = int(round(share / (1 - share) * len(surf)))
        mixed = np.vstack([surf, _scatter(rng, surf, n_out)])
        assert abs(outlier_fraction(mixed) - n_out / len(mixed)) < 0.06, share


def test_a_frame_of_mostly_outliers_is_cleaned_against_its_dense_points():
    rng = np.random.default_rng(1)
    surf = _surface(rng)
    out = _scatter(rng, surf, int(1.5 * len(surf)))  # 60 % of the points
    frame = np.vstack([surf, out])
    # the usual clean-up measures against a median that lies among the outliers
    usual = remove_sparse_points(frame, 10, 4.0)
    assert len(usual) == len(frame)
    report: dict = {}
    seq = PointSequence([frame, surf.copy()])
    cleaned, removed = remove_sparse_frames(seq, 10, 4.0, report=report)
    assert report["suspect"].tolist() == [True, False]
    kept = cleaned.frames[0]
    is_surface = np.isin(kept.view("f8,f8,f8"), surf.view("f8,f8,f8")).ravel()
    assert is_surface.sum() > 0.97 * len(surf)  # the subject stays
    assert (~is_surface).sum() < 0.1 * len(out)  # the scatter goes
    assert report["outliers_left"][0] < OUTLIER_SUSPECT
    # a clean frame is cleaned exactly as before
    np.testing.assert_array_equal(cleaned.frames[1], remove_sparse_points(surf, 10, 4.0))
    assert removed[1] == 1 - len(cleaned.frames[1]) / len(surf)


def test_fraction_left_equals_a_fresh_count_on_the_cleaned_frames():
    """The fraction of each cleaned frame's points that still look like outliers, which the
    clean-up reads from the neighbour distances it already has, equals
    :func:`outlier_fraction` counted afresh on the cleaned frame; the frames are cleaned as
    :func:`remove_sparse_points` (or its dense-reference form) cleans them."""
    rng = np.random.default_rng(3)
    surf = _surface(rng)
    frames = [surf, np.vstack([surf, _scatter(rng, surf, 200)]),
              np.vstack([surf, _scatter(rng, surf, 5000)]),  # mostly outliers: cleaned again
              surf[:8]]  # too few points to judge
    report: dict = {}
    cleaned, _ = remove_sparse_frames(PointSequence(frames), 10, 4.0, min_points=5,
                                      report=report)
    assert report["suspect"].tolist() == [False, False, True, False]
    for i, (f, c) in enumerate(zip(frames, cleaned.frames)):
        assert report["outliers_left"][i] == outlier_fraction(c, 10), i
        if i != 2:
            np.testing.assert_array_equal(c, remove_sparse_points(f, 10, 4.0))


def test_kept_points_distances_are_searched_again_only_where_they_change():
    """The clean-up's neighbour distances among the kept points, from those among all points,
    equal a fresh search of the kept points: also where removing the scatter changed them."""
    from pointrig.preprocess import _kept_distances, _kth_distances

    rng = np.random.default_rng(4)
    surf = _surface(rng)
    frame = np.vstack([surf, _scatter(rng, surf, 5000)])
    dk = _kth_distances(frame, 10)
    keep = dk <= 4.0 * np.median(dk[dk <= 3.0 * np.quantile(dk, 0.1)])  # the dense reference
    got = _kept_distances(frame, dk, keep, 10)
    want = _kth_distances(frame[keep], 10)
    np.testing.assert_array_equal(got, want)
    assert (want != dk[keep]).sum() >= 5  # the removal changed some kept points' distances


def test_extract_warns_and_records_mostly_outlier_input(tmp_path, caplog):
    clean = synthesize("arm", n_frames=4, seed=2, noise=NoiseConfig.clean())
    # as many uniform outliers as surface points in every frame
    noisy = synthesize("arm", n_frames=4, seed=2, noise=NoiseConfig.clean(outliers=1.0))
    seq = PointSequence(noisy.frames)
    with caplog.at_level(logging.WARNING, logger="pointrig.pipeline"):
        res = extract(seq, out_dir=tmp_path / "out", stop_after="structure", pictures=False)
    assert res.outliers["suspect_frames"] == [0, 1, 2, 3]
    assert res.outliers["left_max"] < OUTLIER_SUSPECT
    assert any("frames looked mostly like outliers" in r.getMessage() for r in caplog.records)
    doc = json.loads((tmp_path / "out" / "skeleton.json").read_text())
    assert doc["source"]["outliers"]["suspect_frames"] == [0, 1, 2, 3]
    assert doc["source"]["warnings"] == res.warnings and len(res.warnings) == 1
    # the same subject without the scatter: nothing flagged
    res = extract(PointSequence(clean.frames), out_dir=tmp_path / "clean",
                  stop_after="registration", pictures=False)
    assert res.outliers["suspect_frames"] == [] and res.warnings == []
