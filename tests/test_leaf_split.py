"""The output stage's leaf split at a bend (``output.split_bent_leaves``).

A constructed leg: a thigh (the root bone) and one leaf bone holding the shin and an L-shaped
foot. The registered points are the exact motion of the three true parts plus noise, so the
true answer (a joint at the ankle, the foot's points in the new bone) is known.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pointrig.config import PipelineConfig, StructureConfig
from pointrig.output import _split_weights, leaf_bend, output_skeleton, split_bent_leaves

KNEE = np.array([0.0, 0.0, 0.0])
ANKLE = np.array([0.0, 0.0, -0.40])


def _rot_x(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _ribbon(a: np.ndarray, b: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` points on a 6 cm wide strip from ``a`` to ``b`` (a limb's visible front)."""
    t = rng.uniform(0.0, 1.0, n)
    side = rng.uniform(-0.03, 0.03, n)
    return a + t[:, None] * (b - a) + side[:, None] * np.array([1.0, 0.0, 0.0])


def _leg(foot_turn: float, straight: bool = False, noise: float = 0.003, seed: int = 0):
    """Rest points, labels (0 thigh, 1 shin and foot), tree, joints, registered points
    ``(F, M, 3)`` and the foot's mask. The shin swings about the knee; the foot turns by
    ``foot_turn`` (radians, amplitude) about the ankle against the shin. ``straight`` puts the
    'foot' on in line with the shin (a limb cut lengthwise)."""
    rng = np.random.default_rng(seed)
    thigh = _ribbon(np.array([0.0, 0.0, 0.40]), KNEE, 120, rng)
    shin = _ribbon(KNEE, ANKLE, 100, rng)
    tip = ANKLE + (np.array([0.0, 0.0, -0.15]) if straight else np.array([0.0, 0.18, 0.0]))
    foot = _ribbon(ANKLE, tip, 50, rng)
    Q = np.concatenate([thigh, shin, foot])
    labels = np.r_[np.zeros(120), np.ones(150)].astype(np.int64)
    is_foot = np.r_[np.zeros(220, bool), np.ones(50, bool)]
    parent = np.array([-1, 0])
    joints = np.array([[0.0, 0.0, 0.40], KNEE])
    F = 30
    Y = np.empty((F, len(Q), 3))
    for f in range(F):
        Rs = _rot_x(0.6 * np.sin(2 * np.pi * f / F))
        Rf = Rs @ _rot_x(foot_turn * np.sin(2 * np.pi * f / F + 1.0))
        Y[f, :120] = thigh
        Y[f, 120:220] = (shin - KNEE) @ Rs.T + KNEE
        ankle = (ANKLE - KNEE) @ Rs.T + KNEE
        Y[f, 220:] = (foot - ANKLE) @ Rf.T + ankle
    Y += rng.normal(0.0, noise, Y.shape)
    return Q, labels, parent, joints, Y, is_foot


def test_leaf_bend_finds_the_corner_of_an_l() -> None:
    Q, labels, _, joints, _, _ = _leg(0.0)
    angle, bend, proximal, distal, geo = leaf_bend(Q[labels == 1], joints[1])
    assert angle > 60.0
    assert np.linalg.norm(bend - ANKLE) < 0.05
    assert proximal == pytest.approx(0.40, abs=0.06)
    assert distal > 0.08
    assert geo.shape == (150,) and np.all(np.isfinite(geo))


def test_a_foot_that_turns_gets_a_joint_at_the_ankle() -> None:
    Q, labels, parent, joints, Y, is_foot = _leg(0.8)
    lab, par, jts, source = split_bent_leaves(Q, labels, parent, joints, Y, StructureConfig())
    assert len(par) == 3 and par[2] == 1 and source.tolist() == [0, 1, 1]
    assert np.linalg.norm(jts[2] - ANKLE) < 0.05
    np.testing.assert_array_equal(jts[:2], joints)
    # the new bone holds the foot: most foot points, few shin points
    assert np.mean(lab[is_foot] == 2) > 0.7
    assert np.mean(lab[~is_foot & (labels == 1)] == 2) < 0.15
    assert np.all(lab[labels == 0] == 0)


def test_a_foot_rigid_with_its_shin_is_left_whole() -> None:
    Q, labels, parent, joints, Y, _ = _leg(0.0)
    lab, par, jts, source = split_bent_leaves(Q, labels, parent, joints, Y, StructureConfig())
    assert len(par) == 2
    np.testing.assert_array_equal(lab, labels)


def test_a_straight_leaf_is_not_split_however_it_moves() -> None:
    Q, labels, parent, joints, Y, _ = _leg(0.8, straight=True)
    lab, par, _, _ = split_bent_leaves(Q, labels, parent, joints, Y, StructureConfig())
    assert len(par) == 2


def test_noise_free_rigid_input_is_left_whole() -> None:
    Q, labels, parent, joints, Y, _ = _leg(0.0, noise=0.0)
    _, par, _, _ = split_bent_leaves(Q, labels, parent, joints, Y, StructureConfig())
    assert len(par) == 2


def test_the_split_is_off_at_angle_zero() -> None:
    Q, labels, parent, joints, Y, _ = _leg(0.8)
    cfg = dataclasses.replace(StructureConfig(), leaf_split_angle_deg=0.0)
    lab, par, jts, source = split_bent_leaves(Q, labels, parent, joints, Y, cfg)
    np.testing.assert_array_equal(lab, labels)
    np.testing.assert_array_equal(par, parent)
    np.testing.assert_array_equal(source, [0, 1])


def test_split_weights_move_the_leaf_weight_to_the_new_bone() -> None:
    rng = np.random.default_rng(1)
    W = rng.dirichlet(np.ones(3), size=40)
    labels = np.argmax(W, axis=1)
    new_labels = labels.copy()
    moved = (labels == 1) & (np.arange(40) % 2 == 0)
    new_labels[moved] = 3
    out = _split_weights(W, new_labels, np.array([0, 1, 2, 1]))
    assert out.shape == (40, 4)
    np.testing.assert_allclose(out.sum(axis=1), 1.0)
    np.testing.assert_allclose(out[moved, 3], W[moved, 1])
    np.testing.assert_allclose(out[moved, 1], 0.0)
    np.testing.assert_allclose(out[~moved, :3], W[~moved])


def test_output_skeleton_poses_the_new_joint_with_its_leaf() -> None:
    """The ankle joint of the output skeleton follows the shin's motion in every frame."""
    Q, labels, parent, joints, Y, _ = _leg(0.8)
    F = len(Y)
    R = np.broadcast_to(np.eye(3), (F, 2, 3, 3)).copy()
    T = np.zeros((F, 2, 3))
    for f in range(F):
        R[f, 1] = _rot_x(0.6 * np.sin(2 * np.pi * f / F))
        T[f, 1] = KNEE - R[f, 1] @ KNEE
    cfg = PipelineConfig()
    sk = output_skeleton(Q, labels, parent, joints, R, T, np.eye(2)[labels], cfg, None,
                         observed=([y for y in Y], Y))
    assert sk.joint_positions.shape == (F, 3, 3)
    ankle = sk.joint_positions[:, 2]
    expect = np.einsum("fij,j->fi", R[:, 1], ANKLE) + T[:, 1]
    assert np.max(np.linalg.norm(ankle - expect, axis=1)) < 0.05


def test_a_cap_on_the_joints_holds() -> None:
    """``[structure] max_joints``: no split beyond the user's cap."""
    Q, labels, parent, joints, Y, _ = _leg(0.8)
    capped = dataclasses.replace(StructureConfig(), max_joints=2)
    _, par, _, _ = split_bent_leaves(Q, labels, parent, joints, Y, capped)
    assert len(par) == 2
    roomy = dataclasses.replace(StructureConfig(), max_joints=3)
    _, par, _, _ = split_bent_leaves(Q, labels, parent, joints, Y, roomy)
    assert len(par) == 3
