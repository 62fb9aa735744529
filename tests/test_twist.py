"""pointrig.kinematics' twist of a bone about its own axis: the swing-twist split against
constructed rotations, and ``minimal_twist`` (the default ``[joints] bone_twist``) on a chain
with known rolls."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pointrig.kinematics import joint_trajectories, minimal_twist, swing_twist


def _perpendicular(a: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    v = rng.normal(size=3)
    v -= v.dot(a) * a
    return v / np.linalg.norm(v)


@pytest.mark.parametrize("seed", range(5))
def test_swing_twist_recovers_a_built_rotation(seed: int) -> None:
    rng = np.random.default_rng(seed)
    a = rng.normal(size=3)
    a /= np.linalg.norm(a)
    theta = rng.uniform(-3.0, 3.0)
    swing = Rotation.from_rotvec(rng.uniform(0.1, 2.5) * _perpendicular(a, rng)).as_matrix()
    R = swing @ Rotation.from_rotvec(theta * a).as_matrix()
    got_swing, got_theta = swing_twist(R, 3.0 * a)  # any length
    assert got_theta == pytest.approx(theta, abs=1e-9)
    np.testing.assert_allclose(got_swing, swing, atol=1e-9)
    # the swing's own axis is perpendicular to a; a flipped axis flips the angle only
    assert abs(Rotation.from_matrix(got_swing).as_rotvec().dot(a)) < 1e-9
    assert swing_twist(R, -a)[1] == pytest.approx(-theta, abs=1e-9)


def test_swing_twist_of_pure_rotations() -> None:
    a = np.array([0.0, 0.0, 1.0])
    sw, th = swing_twist(Rotation.from_rotvec([0, 0, 0.7]).as_matrix(), a)
    assert th == pytest.approx(0.7)
    np.testing.assert_allclose(sw, np.eye(3), atol=1e-12)
    sw, th = swing_twist(Rotation.from_rotvec([0.7, 0, 0]).as_matrix(), a)
    assert th == pytest.approx(0.0, abs=1e-12)
    np.testing.assert_allclose(sw, Rotation.from_rotvec([0.7, 0, 0]).as_matrix(), atol=1e-12)


def _chain(F: int, seed: int):
    """A three-bone chain (a torso block, an upper arm and a forearm along x) moving with
    random swings and random rolls of each limb about its own axis; returns rest points,
    labels, joints, parents and the fitted-like transforms (rolls included)."""
    rng = np.random.default_rng(seed)
    torso = rng.uniform([-0.2, -0.3, -0.1], [0.0, 0.3, 0.1], (300, 3))
    u = rng.uniform(0, 2 * np.pi, 400)
    upper = np.c_[rng.uniform(0.0, 0.3, 400), 0.04 * np.cos(u), 0.04 * np.sin(u)]
    fore = upper + [0.3, 0.0, 0.0]
    rest = np.vstack([torso, upper, fore])
    labels = np.repeat([0, 1, 2], [300, 400, 400])
    joints = np.array([[-0.1, 0.0, 0.0], [0.0, 0.0, 0.0], [0.3, 0.0, 0.0]])
    parent = np.array([-1, 0, 1])
    R = np.empty((F, 3, 3, 3))
    T = np.empty((F, 3, 3))
    x = np.array([1.0, 0.0, 0.0])
    for t in range(F):
        R[t, 0] = Rotation.from_rotvec(rng.normal(size=3) * 0.3).as_matrix()
        T[t, 0] = rng.normal(size=3) * 0.1
        for b in (1, 2):
            p = parent[b]
            swing = Rotation.from_rotvec(np.r_[0.0, rng.normal(size=2) * 0.6]).as_matrix()
            roll = Rotation.from_rotvec(rng.uniform(-2, 2) * x).as_matrix()
            R[t, b] = R[t, p] @ swing @ roll
            c = joints[b]  # head joint shared with the parent
            T[t, b] = R[t, p] @ c + T[t, p] - R[t, b] @ c
    return rest, labels, joints, parent, R, T


@pytest.mark.parametrize("seed", [0, 1])
def test_minimal_twist_keeps_the_joints_and_removes_the_roll(seed: int) -> None:
    """Oracle: the joint trajectories are unchanged (to rounding), each limb's relative
    rotation to its parent has no twist about its axis left, and its axis points where the
    fit put it; the root keeps its transform."""
    rest, labels, joints, parent, R, T = _chain(12, seed)
    R2, T2 = minimal_twist(R, T, joints, parent, rest, labels, min_elongation=2.0)
    np.testing.assert_allclose(joint_trajectories(joints, R2, T2, parent),
                               joint_trajectories(joints, R, T, parent), atol=1e-12)
    np.testing.assert_allclose(R2[:, 0], R[:, 0])
    np.testing.assert_allclose(T2[:, 0], T[:, 0])
    # the upper arm's axis runs to the elbow; the forearm (a leaf) to its points' centroid
    lead = rest[labels == 2].mean(0) - joints[2]
    for b, axis in ((1, joints[2] - joints[1]), (2, lead / np.linalg.norm(lead))):
        np.testing.assert_allclose(np.einsum("fij,j->fi", R2[:, b], axis),
                                   np.einsum("fij,j->fi", R[:, b], axis), atol=1e-12)
        for t in range(len(R)):
            rel = R2[t, parent[b]].T @ R2[t, b]
            assert abs(swing_twist(rel, axis)[1]) < 1e-9
            np.testing.assert_allclose(rel @ rel.T, np.eye(3), atol=1e-12)
    # the forearm (a leaf) also carries its own points' centroid to the same place
    c = rest[labels == 2].mean(0)
    np.testing.assert_allclose(np.einsum("fij,j->fi", R2[:, 2], c) + T2[:, 2],
                               np.einsum("fij,j->fi", R[:, 2], c) + T[:, 2], atol=1e-9)


def test_minimal_twist_leaves_compact_bones_alone() -> None:
    """A bone whose points are not elongated along its axis (spread ratio below the gate)
    keeps its fitted roll: its shape, not the view, decides its twist."""
    rest, labels, joints, parent, R, T = _chain(5, 2)
    R2, T2 = minimal_twist(R, T, joints, parent, rest, labels, min_elongation=50.0)
    np.testing.assert_array_equal(R2, R)
    np.testing.assert_array_equal(T2, T)


def test_minimal_twist_roll_gate() -> None:
    """``min_roll_deg``: limbs whose fitted roll against the parent stays below the gate at the
    90th percentile keep it; above it they lose it, as with no gate. The chain's rolls are
    uniform in +-2 rad, so their 90th percentile is about 103 deg (oracle: computed here)."""
    rest, labels, joints, parent, R, T = _chain(40, 4)
    x = np.array([1.0, 0.0, 0.0])
    p90 = max(np.percentile([abs(np.degrees(swing_twist(R[t, 0].T @ R[t, 1], x)[1]))
                             for t in range(40)], 90), 1.0)
    R_hi, T_hi = minimal_twist(R, T, joints, parent, rest, labels, min_roll_deg=179.9)
    np.testing.assert_array_equal(R_hi[:, 1], R[:, 1])
    R_lo, _ = minimal_twist(R, T, joints, parent, rest, labels, min_roll_deg=0.5 * p90)
    R_all, _ = minimal_twist(R, T, joints, parent, rest, labels)
    np.testing.assert_allclose(R_lo, R_all, atol=1e-12)
    assert np.abs(R_lo[:, 1] - R[:, 1]).max() > 0.1
