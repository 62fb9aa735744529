"""pointrig.output.split_disconnected_bones: one bone per separate piece of a bone that
carries two subtrees, each piece's joint by Eq. 20 on its own motion, against a constructed
figure whose thighs turn about known hip centres."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pointrig.config import StructureConfig
from pointrig.errors import ConfigError
from pointrig.output import split_disconnected_bones

HIP_L = np.array([0.09, 0.05, 2.0])
HIP_R = np.array([-0.09, 0.05, 2.0])


def _grid(x0: float, x1: float, y0: float, y1: float) -> np.ndarray:
    """Points 1 cm apart on the rectangle ``[x0, x1] x [y0, y1]`` at depth 2 m."""
    xs, ys = np.meshgrid(np.arange(x0, x1 + 1e-9, 0.01), np.arange(y0, y1 + 1e-9, 0.01))
    return np.stack([xs.ravel(), ys.ravel(), np.full(xs.size, 2.0)], axis=1)


def _rot(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation matrix about unit ``axis`` by ``angle`` radians (Rodrigues)."""
    K = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]],
                  [-axis[1], axis[0], 0.0]])
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * K @ K


def _figure(bridge: bool = False, frames: int = 100):
    """Torso (bone 0, root, still), one bone of both thighs (bone 1: two blobs 10 cm apart),
    the shins (bones 2 and 3, children of bone 1). Each thigh and its shin turn about their own
    hip, alternately about x and z by up to 0.5 rad, the two legs out of phase."""
    torso = _grid(-0.15, 0.15, -0.5, 0.0)
    thigh_l, thigh_r = _grid(0.05, 0.13, 0.1, 0.3), _grid(-0.13, -0.05, 0.1, 0.3)
    shin_l, shin_r = _grid(0.05, 0.13, 0.32, 0.5), _grid(-0.13, -0.05, 0.32, 0.5)
    parts = [torso, thigh_l, thigh_r, shin_l, shin_r]
    labels = [0, 1, 1, 2, 3]
    if bridge:  # a strip joining the two thighs: one connected piece
        parts.append(_grid(-0.05, 0.05, 0.1, 0.13))
        labels.append(1)
    Q = np.concatenate(parts)
    lab = np.concatenate([np.full(len(p), b) for p, b in zip(parts, labels)])
    side = np.concatenate([np.full(len(p), s) for p, s in
                           zip(parts, [0, 1, 2, 1, 2] + ([0] if bridge else []))])
    Y = np.repeat(Q[None], frames, axis=0)
    x, z = np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])
    for t in range(frames):
        for s, hip, phase in ((1, HIP_L, 0.0), (2, HIP_R, 1.3)):
            ang = 0.5 * np.sin(0.37 * t + phase)
            R = _rot(x if t % 2 else z, ang)
            m = side == s
            Y[t, m] = (Q[m] - hip) @ R.T + hip
    joints = np.array([[0.0, -0.25, 2.0], [0.0, 0.1, 2.0], [0.09, 0.31, 2.0],
                       [-0.09, 0.31, 2.0]])
    parent = np.array([-1, 0, 1, 1])
    return Q, Y, lab, parent, joints, side


CFG = StructureConfig()  # the default, split_disconnected = 3 rest spacings


def test_the_two_thighs_become_two_bones_with_their_hips() -> None:
    Q, Y, lab, parent, joints, side = _figure()
    labels, par, J, source = split_disconnected_bones(Q, lab, parent, joints, Y, CFG)
    assert len(par) == 5 and list(source) == [0, 1, 2, 3, 1]
    # the pieces are exactly the two blobs, each hanging from the torso
    left, right = np.unique(labels[side == 1]), np.unique(labels[side == 2])
    thigh_l, thigh_r = set(left) - {2}, set(right) - {3}
    assert len(thigh_l) == 1 and len(thigh_r) == 1 and thigh_l != thigh_r
    a, b = thigh_l.pop(), thigh_r.pop()
    assert {a, b} == {1, 4} and par[a] == 0 and par[b] == 0
    # each shin hangs from its own thigh; the torso and the shins keep their points
    assert par[2] == a and par[3] == b
    np.testing.assert_array_equal(labels[lab != 1], lab[lab != 1])
    # Eq. 20 on each piece's own motion finds its hip (the truth) to within 1 cm
    assert np.linalg.norm(J[a] - HIP_L) < 0.01 and np.linalg.norm(J[b] - HIP_R) < 0.01
    np.testing.assert_array_equal(J[[0, 2, 3]], joints[[0, 2, 3]])


def test_without_the_registration_the_joint_is_the_pieces_nearest_tenth() -> None:
    """The prior alone: the centroid of the tenth of each blob's points nearest the old joint
    (computed here from the blob directly)."""
    Q, Y, lab, parent, joints, side = _figure()
    labels, par, J, _ = split_disconnected_bones(Q, lab, parent, joints, None, CFG)
    for s in (1, 2):
        blob = Q[(side == s) & (lab == 1)]
        d = np.linalg.norm(blob - joints[1], axis=1)
        want = blob[d <= np.quantile(d, 0.1)].mean(axis=0)
        piece = int(np.unique(labels[(side == s) & (lab == 1)])[0])
        np.testing.assert_allclose(J[piece], want, atol=1e-12)


def test_a_connected_bone_the_off_switch_and_a_full_cap_leave_the_skeleton_alone() -> None:
    Q, Y, lab, parent, joints, _ = _figure(bridge=True)
    labels, par, J, source = split_disconnected_bones(Q, lab, parent, joints, Y, CFG)
    assert len(par) == 4 and list(source) == [0, 1, 2, 3]
    np.testing.assert_array_equal(labels, lab)
    np.testing.assert_array_equal(J, joints)
    Q, Y, lab, parent, joints, _ = _figure()
    for cfg in (dataclasses.replace(CFG, split_disconnected=0.0),
                dataclasses.replace(CFG, max_joints=4)):
        labels, par, J, source = split_disconnected_bones(Q, lab, parent, joints, Y, cfg)
        assert len(par) == 4 and list(par) == list(parent)
        np.testing.assert_array_equal(labels, lab)
    # a cap with room for the new bone lets it through
    assert len(split_disconnected_bones(Q, lab, parent, joints, Y,
                                        dataclasses.replace(CFG, max_joints=5))[1]) == 5


def test_a_root_with_separate_pieces_is_left_whole() -> None:
    """The same two blobs as the root bone (the torso removed): not split."""
    Q, Y, lab, parent, joints, side = _figure()
    keep = lab != 0
    lab2 = lab[keep] - 1
    labels, par, _, source = split_disconnected_bones(
        Q[keep], lab2, np.array([-1, 0, 0]), joints[1:], Y[:, keep], CFG)
    assert len(par) == 3 and list(source) == [0, 1, 2]


def test_the_parameter_is_checked() -> None:
    with pytest.raises(ConfigError, match="split_disconnected"):
        dataclasses.replace(StructureConfig(), split_disconnected=-1.0)


def test_the_output_skeleton_gets_both_hips_and_keeps_its_skinning() -> None:
    """Through :func:`pointrig.pipeline.output_skeleton` (the pipeline's output stage): five
    joints, the two hips at the truth's, the new bone moving as the thighs' bone did, the
    skinning weights still summing to one with the thighs' weight moved to their new bone."""
    from pointrig.config import PipelineConfig
    from pointrig.pipeline import output_skeleton
    from pointrig.structure import fit_bones

    Q, Y, lab, parent, joints, side = _figure()
    R, T, _ = fit_bones(Q, Y, lab, 4)
    W = np.eye(4)[lab]
    frames = list(Y)
    sk = output_skeleton(Q, lab, parent, joints, R, T, W, PipelineConfig(), None,
                         observed=(frames, Y))
    assert sk.rest_positions.shape == (5, 3)
    for hip in (HIP_L, HIP_R):
        assert np.min(np.linalg.norm(sk.rest_positions - hip, axis=1)) < 0.01
    np.testing.assert_allclose(sk.weights.sum(axis=1), 1.0)
    thighs = [np.unique(sk.labels[(lab == 1) & (side == s)]) for s in (1, 2)]
    assert all(len(t) == 1 for t in thighs) and thighs[0][0] != thighs[1][0]
    off = dataclasses.replace(PipelineConfig(), structure=dataclasses.replace(
        CFG, split_disconnected=0.0))
    off = output_skeleton(Q, lab, parent, joints, R, T, W, off, None, observed=(frames, Y))
    assert off.rest_positions.shape == (4, 3)
