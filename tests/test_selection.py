"""Joint selection by the BIC on the raw frames (pointrig.selection), on articulated boxes whose
motion is known exactly: a joint inside a rigid part must go, a joint that turns must stay."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from pointrig.selection import select_joints


def _box_surface(lo: np.ndarray, hi: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """``(n, 3)`` points uniform on the surface of the box ``[lo, hi]`` (metres)."""
    size = hi - lo
    areas = np.array([size[1] * size[2], size[0] * size[2], size[0] * size[1]])
    axis = rng.choice(3, size=n, p=areas / areas.sum())
    p = lo + rng.random((n, 3)) * size
    side = rng.random(n) < 0.5
    p[np.arange(n), axis] = np.where(side, lo[axis], hi[axis])
    return p


def _scene(swing_deg: float, jitter_deg: float, rng: np.random.Generator, frames: int = 20):
    """Two boxes along x joined by a hinge at x = 0.4 m; the first box is given as two bones.

    Returns rest points ``(M, 3)``, labels ``(M,)`` (0, 1 = the two halves of the first box,
    2 = the second box), bone parents, ``R (F, 3, 3, 3)``, ``T (F, 3, 3)`` and raw frames
    sampled afresh from the true surfaces with 3 mm noise."""
    lo_a, hi_a = np.array([0.0, 0.0, 0.0]), np.array([0.4, 0.1, 0.1])
    lo_b, hi_b = np.array([0.4, 0.0, 0.0]), np.array([0.8, 0.1, 0.1])
    qa, qb = _box_surface(lo_a, hi_a, 800, rng), _box_surface(lo_b, hi_b, 800, rng)
    rest = np.vstack([qa, qb])
    labels = np.concatenate([(qa[:, 0] > 0.2).astype(int), np.full(len(qb), 2)])
    parent = np.array([-1, 0, 1])
    hinge = np.array([0.4, 0.05, 0.05])
    R = np.zeros((frames, 3, 3, 3))
    T = np.zeros((frames, 3, 3))
    raw = []
    for t in range(frames):
        s = t / (frames - 1)
        Ra = Rotation.from_rotvec([0.0, 0.3 * s, 0.1 * s]).as_matrix()
        Ta = np.array([0.2 * s, 0.0, 1.5])
        Rrel = Rotation.from_rotvec([0.0, 0.0, np.radians(swing_deg) * np.sin(np.pi * s)]).as_matrix()
        Rb = Ra @ Rrel
        Tb = Ra @ (hinge - Rrel @ hinge) + Ta
        # the spurious bone's fit carries a little noise of its own
        Rj = Rotation.from_rotvec(rng.normal(size=3) * np.radians(jitter_deg)).as_matrix()
        R[t] = [Ra, Rj @ Ra, Rb]
        T[t] = [Ta, Ta, Tb]
        sa, sb = _box_surface(lo_a, hi_a, 1500, rng), _box_surface(lo_b, hi_b, 1500, rng)
        x = np.vstack([sa @ Ra.T + Ta, sb @ Rb.T + Tb])
        raw.append(x + rng.normal(scale=0.003, size=x.shape))
    return rest, labels, parent, R, T, raw


def test_joint_inside_a_rigid_part_goes_and_a_turning_joint_stays():
    rng = np.random.default_rng(0)
    rest, labels, parent, R, T, raw = _scene(40.0, 0.5, rng)
    sel = select_joints(raw, rest, labels, parent, R, T)
    assert [r[:2] for r in sel.removed] == [(1, 0)]
    assert sel.keep.tolist() == [0, 2]
    assert sel.bone_parent.tolist() == [-1, 0]
    # the two halves of the first box are one bone, the second box its child
    assert set(sel.labels[labels < 2]) == {0} and set(sel.labels[labels == 2]) == {1}
    # the merged bone moves as the first box does (its halves' least-squares motion)
    np.testing.assert_allclose(sel.R[:, 1], R[:, 2])
    # (the jitter of one half, 0.5 deg per axis, is halved)
    assert np.abs(sel.R[:, 0] - R[:, 0]).max() < 0.03


def test_no_joint_stays_on_one_rigid_body():
    rng = np.random.default_rng(1)
    rest, labels, parent, R, T, raw = _scene(0.0, 0.5, rng)
    sel = select_joints(raw, rest, labels, parent, R, T)
    assert sel.keep.tolist() == [0]
    assert set(sel.labels.tolist()) == {0}


def test_penalty_zero_keeps_every_joint():
    rng = np.random.default_rng(2)
    rest, labels, parent, R, T, raw = _scene(0.0, 0.5, rng, frames=6)
    sel = select_joints(raw, rest, labels, parent, R, T, penalty_scale=0.0)
    assert sel.keep.tolist() == [0, 1, 2] and not sel.removed
    np.testing.assert_array_equal(sel.labels, labels)


def test_merged_weights_keep_their_sums():
    rng = np.random.default_rng(3)
    rest, labels, parent, R, T, raw = _scene(40.0, 0.5, rng, frames=8)
    sel = select_joints(raw, rest, labels, parent, R, T)
    W = rng.random((len(rest), 3))
    W /= W.sum(axis=1, keepdims=True)
    W2 = sel.merge_weights(W)
    assert W2.shape == (len(rest), len(sel.keep))
    np.testing.assert_allclose(W2.sum(axis=1), 1.0)
    # the removed bone's weight goes to the first box's bone, or (shared out) to the second
    # box's bone on the points that bone now holds
    to_second = sel.labels == 1 if sel.shared_out else np.zeros(len(rest), bool)
    np.testing.assert_allclose(W2[:, 0], W[:, 0] + np.where(to_second, 0.0, W[:, 1]))
    np.testing.assert_allclose(W2[:, 1], W[:, 2] + np.where(to_second, W[:, 1], 0.0))


def _chain(rng: np.random.Generator, swings_deg: tuple[float, float], frames: int = 16,
           band: bool = False):
    """Three boxes along x (0-0.4, 0.4-0.8, 0.8-1.2 m) joined by hinges at x = 0.4 and 0.8 m
    about z, swinging by ``swings_deg`` (the second relative to the first). With ``band``, the
    bones are cut as a registration that spreads the first hinge's bend cuts them: bone 0 up
    to x = 0.3, a band bone 0.3-0.5 that moves with half the hinge's rotation about the hinge,
    bone 2 beyond (the second and third boxes, one bone, with ``swings_deg[1] = 0``).

    Returns rest points, labels, parents, ``R (F, B, 3, 3)``, ``T (F, B, 3)``, the raw frames
    (3 mm noise) and the true rest joints of the bones."""
    los = [np.array([0.4 * k, 0.0, 0.0]) for k in range(3)]
    q = [_box_surface(lo, lo + [0.4, 0.1, 0.1], 900, rng) for lo in los]
    rest = np.vstack(q)
    hinges = [np.array([0.4, 0.05, 0.05]), np.array([0.8, 0.05, 0.05])]
    if band:
        x = rest[:, 0]
        labels = np.where(x < 0.3, 0, np.where(x < 0.5, 1, 2))
        joints = np.array([[0.0, 0.05, 0.05], [0.3, 0.05, 0.05], [0.5, 0.05, 0.05]])
    else:
        labels = np.repeat([0, 1, 2], 900)
        joints = np.array([[0.0, 0.05, 0.05], hinges[0], hinges[1]])
    R = np.zeros((frames, 3, 3, 3))
    T = np.zeros((frames, 3, 3))
    raw = []
    for t in range(frames):
        s = t / (frames - 1)
        R0 = Rotation.from_rotvec([0.0, 0.2 * s, 0.1 * s]).as_matrix()
        T0 = np.array([0.1 * s, 0.0, 1.5])
        rel = [Rotation.from_rotvec([0.0, 0.0, np.radians(a) * np.sin(np.pi * s * (1 + k))]
                                    ).as_matrix() for k, a in enumerate(swings_deg)]
        Rk, Tk = [R0], [T0]
        for h, r in zip(hinges, rel):  # each box hinged on the one before
            Rk.append(Rk[-1] @ r)
            Tk.append(Rk[-2] @ (h - r @ h) + Tk[-1])
        x = np.vstack([_box_surface(lo, lo + [0.4, 0.1, 0.1], 1500, rng) @ Rk[k].T + Tk[k]
                       for k, lo in enumerate(los)])
        raw.append(x + rng.normal(scale=0.003, size=x.shape))
        if band:
            half = Rotation.from_matrix(rel[0]).as_rotvec() / 2
            rh = Rotation.from_rotvec(half).as_matrix()
            R[t] = [R0, R0 @ rh, Rk[1]]
            T[t] = [T0, R0 @ (hinges[0] - rh @ hinges[0]) + T0, Tk[1]]
        else:
            R[t], T[t] = Rk, Tk
    return rest, labels, np.array([-1, 0, 1]), R, T, raw, joints


def test_a_band_bone_across_a_bend_is_shared_out_and_the_joint_lands_on_the_hinge():
    rng = np.random.default_rng(5)
    rest, labels, parent, R, T, raw, joints = _chain(rng, (50.0, 0.0), band=True)
    sel = select_joints(raw, rest, labels, parent, R, T)
    # the band goes, its points to the box each lies on; one joint stays, on the true hinge
    assert [r[:2] for r in sel.removed] == [(1, 0)] and sel.keep.tolist() == [0, 2]
    assert [s[:2] for s in sel.shared_out] == [(1, 2)]
    # on the faces the swing (about z) turns out of their plane, the band's points away from
    # the hinge go to the box they lie on, but for a point or two within the noise (points on
    # the z faces slide in their plane: either motion explains them)
    box = (np.arange(len(rest)) >= 900).astype(int)
    on_y = (labels == 1) & ((rest[:, 1] < 1e-9) | (rest[:, 1] > 0.1 - 1e-9)) \
        & (np.abs(rest[:, 0] - 0.4) > 0.02)
    assert on_y.sum() > 50 and np.mean(sel.labels[on_y] == box[on_y]) > 0.97
    jr = sel.rest_joints(joints)
    assert np.linalg.norm(jr[1] - [0.4, 0.05, 0.05]) < 0.015
    np.testing.assert_array_equal(jr[0], joints[0])


def test_the_choice_does_not_depend_on_the_thread_count():
    # the candidates' margins are computed side by side: one thread gives the same removals,
    # margins and shares bit for bit
    rng = np.random.default_rng(5)
    rest, labels, parent, R, T, raw, _ = _chain(rng, (50.0, 0.0), band=True)
    one = select_joints(raw, rest, labels, parent, R, T, workers=1)
    two = select_joints(raw, rest, labels, parent, R, T, workers=2)
    assert one.removed == two.removed and one.shared_out == two.shared_out
    np.testing.assert_array_equal(one.labels, two.labels)


def test_a_middle_bone_with_its_own_swing_keeps_both_joints():
    rng = np.random.default_rng(6)
    rest, labels, parent, R, T, raw, joints = _chain(rng, (40.0, 40.0))
    sel = select_joints(raw, rest, labels, parent, R, T)
    assert sel.keep.tolist() == [0, 1, 2] and not sel.removed and not sel.shared_out
    np.testing.assert_array_equal(sel.rest_joints(joints), joints)


def test_the_choice_does_not_depend_on_the_sampling_density():
    # every raw point four times over: a denser sensor sees the same surface, so the evidence,
    # counted at the rest points' resolution, and every removal margin are the same
    rng = np.random.default_rng(4)
    rest, labels, parent, R, T, raw = _scene(12.0, 1.0, rng, frames=10)
    sel = select_joints(raw, rest, labels, parent, R, T)
    dense = select_joints([np.repeat(x, 4, axis=0) for x in raw], rest, labels, parent, R, T)
    assert [r[:2] for r in dense.removed] == [r[:2] for r in sel.removed]
    np.testing.assert_allclose([r[2] for r in dense.removed], [r[2] for r in sel.removed],
                               rtol=1e-9)
    assert dense.keep.tolist() == sel.keep.tolist()
