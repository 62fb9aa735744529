"""The depth-bias column of benchmarks/bench_step3.py against a closed form."""

from __future__ import annotations

import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from bench_step3 import depth_bias, human_sized, variant_configs  # noqa: E402

from pointrig.config import JointsConfig, StructureConfig  # noqa: E402
from pointrig.errors import ConfigError  # noqa: E402
from pointrig.evaluate import evaluate  # noqa: E402


def test_depth_bias_is_the_mean_offset_along_the_camera_ray() -> None:
    """Predictions = truth moved along each true joint's own ray by known amounts, plus a move
    across the ray that must not count; one far-off prediction stays unmatched."""
    rng = np.random.default_rng(0)
    F, J = 12, 3
    gt = np.stack([np.array([0.0, 0.0, 2.0]), np.array([0.3, -0.2, 2.1]),
                   np.array([-0.25, 0.3, 1.9])])[None] + 0.05 * rng.normal(size=(F, J, 3))
    u = gt / np.linalg.norm(gt, axis=2, keepdims=True)
    across = np.cross(u, np.array([0.0, 0.0, 1.0]))  # perpendicular to every ray
    depth = np.array([-0.03, 0.01])  # joints 0 and 1: 3 cm in front, 1 cm behind
    pred = np.concatenate([gt[:, :2] + depth[None, :, None] * u[:, :2] + 0.02 * across[:, :2],
                           gt[:, 2:] + np.array([2.0, 0.0, 0.0])], axis=1)
    rep = evaluate(pred, gt, np.array([-1, 0, 0]), threshold=0.2)
    assert [r.matched for r in rep.rows] == [0, 1, -1]
    syn = SimpleNamespace(gt_joints=gt)
    assert abs(depth_bias(pred, syn, rep) - depth.mean()) < 1e-12
    none = evaluate(pred[:, 2:] + 5.0, gt, np.array([-1, 0, 0]), threshold=0.2)
    assert np.isnan(depth_bias(pred[:, 2:] + 5.0, syn, none))


def test_pipeline_gap_is_the_largest_joint_distance() -> None:
    """The reproduction check: the largest per-joint, per-frame distance, inf on a shape
    mismatch (another skeleton), 0 for the same joints."""
    from bench_step3 import pipeline_gap

    rng = np.random.default_rng(1)
    P = rng.normal(size=(5, 4, 3))
    Q = P.copy()
    Q[3, 2] += np.array([0.0, 0.003, 0.004])  # 5 mm at one joint and frame
    assert pipeline_gap(P, P) == 0.0
    assert abs(pipeline_gap(Q, P) - 0.005) < 1e-12
    assert pipeline_gap(P[:, :3], P) == float("inf")


def test_lateral_recall_leaves_out_the_depth_along_the_ray() -> None:
    """Joint 0 moved 0.5 m along its own ray (unmatched by the evaluation, matched without the
    depth), joint 1 moved 0.05 m across it (matched both ways), joint 2 moved 0.5 m across it
    (unmatched both ways): recall 1/3, lateral recall 2/3; the truth itself: 1 and 1."""
    from bench_step3 import lateral_recall

    rng = np.random.default_rng(2)
    F = 10
    gt = np.stack([np.array([0.0, 0.0, 2.0]), np.array([0.3, -0.2, 2.1]),
                   np.array([-0.25, 0.3, 1.9])])[None] + 0.05 * rng.normal(size=(F, 3, 3))
    u = gt / np.linalg.norm(gt, axis=2, keepdims=True)
    across = np.cross(u, np.array([0.0, 0.0, 1.0]))
    across /= np.linalg.norm(across, axis=2, keepdims=True)
    pred = gt + np.stack([0.5 * u[:, 0], 0.05 * across[:, 1], 0.5 * across[:, 2]], axis=1)
    parents = np.array([-1, 0, 0])
    rep = evaluate(pred, gt, parents, threshold=0.2)
    syn = SimpleNamespace(gt_joints=gt)
    assert abs(rep.recall - 1 / 3) < 1e-12
    assert abs(lateral_recall(pred, syn, rep) - 2 / 3) < 1e-12
    exact = evaluate(gt, gt, parents, threshold=0.2)
    assert lateral_recall(gt, syn, exact) == 1.0


def test_variant_configs_split_joints_and_structure_keys() -> None:
    joints, structure = variant_configs([{}, {"joint_prior": 0.3},
                                         {"structure": {"leaf_split_angle_deg": 0}}])
    assert joints[0] == JointsConfig() and structure[0] == StructureConfig()
    assert joints[1].joint_prior == 0.3 and structure[1] == StructureConfig()
    assert joints[2] == JointsConfig() and structure[2].leaf_split_angle_deg == 0
    with pytest.raises(ConfigError):
        variant_configs([{"structure": {"no_such_key": 1}}])


def test_error_over_time_splits_the_normalised_error_by_stretches_of_frames() -> None:
    """A prediction = truth + a constant offset (taken out) + a 4 cm error in the last quarter
    of 20 frames at joint 1: the mean offset moves 1 cm, so frames 0-14 are 1 cm off it and
    frames 15-19 3 cm; tenths of two frames: 1 cm seven times, then 2 cm (frames 14-15), then
    3 cm twice. The mean of the tenths is the evaluation's normalised error; joint 0 has none;
    an unmatched joint is left out."""
    from bench_step3 import error_over_time

    rng = np.random.default_rng(3)
    F = 20
    gt = np.stack([np.array([0.0, 0.0, 2.0]), np.array([0.3, -0.2, 2.1]),
                   np.array([-0.25, 0.3, 1.9])])[None] + 0.05 * rng.normal(size=(F, 3, 3))
    pred = gt + np.array([0.01, -0.02, 0.03])  # constant offset: no normalised error
    pred[15:, 1] += np.array([0.04, 0.0, 0.0])
    pred[:, 2] += 3.0  # unmatched
    rep = evaluate(pred, gt, np.array([-1, 0, 0]), threshold=0.2)
    syn = SimpleNamespace(gt_joints=gt)
    out = error_over_time(pred, syn, rep, bins=10)
    names = [r.name for r in rep.rows]
    assert set(out) == {names[0], names[1]}
    assert np.allclose(out[names[0]], 0.0, atol=1e-12)
    assert np.allclose(out[names[1]], [0.01] * 7 + [0.02, 0.03, 0.03], atol=1e-12)
    assert abs(out[names[1]].mean() - rep.rows[1].normalized_error) < 1e-12


def test_human_sized_takes_the_human_and_the_girl_and_leaves_hand_and_greenman() -> None:
    """Sizes of the benchmark's subjects: the idle girl (1.62 m) and the procedural human
    (2.39 m) are in; the hand (0.24 m) and greenman (3.72 m) are out; bounds included."""
    assert human_sized(1.62) and human_sized(2.39)
    assert not human_sized(0.24) and not human_sized(3.72)
    assert human_sized(1.0) and human_sized(3.0) and not human_sized(3.01)
