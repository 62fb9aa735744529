"""The output skeleton's root at the body's centre when the largest part is a leaf
(pointrig.output.tree_centre / reroot / output_tree), against brute-force oracles."""

from __future__ import annotations

import dataclasses

import networkx as nx
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pointrig.config import StructureConfig
from pointrig.kinematics import joint_trajectories
from pointrig.output import leaf_root, output_tree, reroot, tree_centre


def _segment(a: np.ndarray, b: np.ndarray, n: int) -> np.ndarray:
    t = np.linspace(0.0, 1.0, n)[:, None]
    return a + t * (b - a)


def _stick_figure() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Points on a stick figure (metres): a big head (bone 0, the root, most points) on a spine
    (bone 1) that meets two legs (bones 2, 3) at the hip and two arms (4, 5) at the shoulder.
    Returns rest points (M, 3), labels (M,), parents (6,), head joints (6, 3)."""
    hip, shoulder, neck = np.array([0, 0, 0.0]), np.array([0, 0.5, 0.0]), np.array([0, 0.6, 0])
    top = np.array([0, 1.0, 0.0])
    feet = [np.array([-0.1, -0.9, 0.0]), np.array([0.1, -0.9, 0.0])]
    hands = [np.array([-0.6, 0.5, 0.0]), np.array([0.6, 0.5, 0.0])]
    parts = [_segment(neck, top, 400), _segment(hip, neck, 60),
             _segment(hip, feet[0], 90), _segment(hip, feet[1], 90),
             _segment(shoulder, hands[0], 60), _segment(shoulder, hands[1], 60)]
    Q = np.concatenate(parts)
    labels = np.concatenate([np.full(len(p), b) for b, p in enumerate(parts)])
    parent = np.array([-1, 0, 1, 1, 1, 1])
    joints = np.array([top, neck, hip, hip, shoulder, shoulder])
    return Q, labels, parent, joints


def _brute_force_eccentricity(Q, labels, parent, joints, quantile=1.0) -> np.ndarray:
    """(M,) eccentricity of every rest point through the tree: a graph with the rest points
    and the joints as nodes, each point joined to the joints of its bone (straight
    distances), each joint to the other joints of the bones it touches; Dijkstra."""
    G = nx.Graph()
    B, M = len(parent), len(Q)
    bone_joints = {b: {b} if parent[b] >= 0 else set() for b in range(B)}
    for k, p in enumerate(parent):
        if p >= 0:
            bone_joints[int(p)].add(k)
    for b, js in bone_joints.items():
        js = sorted(js)
        for i in js:
            for j in js:
                if i < j:
                    G.add_edge(("j", i), ("j", j),
                               weight=float(np.linalg.norm(joints[i] - joints[j])))
        for m in np.flatnonzero(labels == b):
            for j in js:
                G.add_edge(("p", int(m)), ("j", j), weight=float(np.linalg.norm(Q[m] - joints[j])))
    ecc = np.empty(M)
    for m in range(M):
        dist = nx.single_source_dijkstra_path_length(G, ("p", m))
        d = np.empty(M)
        for n in range(M):
            # within one bone the distance is straight, not through a joint
            d[n] = (np.linalg.norm(Q[m] - Q[n]) if labels[n] == labels[m]
                    else dist[("p", n)])
        ecc[m] = np.quantile(d, quantile)
    return ecc


def test_tree_centre_matches_a_brute_force_shortest_path_oracle() -> None:
    Q, labels, parent, joints = _noisy_stick_figure()
    centre, bone = tree_centre(Q, labels, parent, joints, quantile=1.0)
    ecc = _brute_force_eccentricity(Q, labels, parent, joints)
    best = int(np.argmin(ecc))
    np.testing.assert_allclose(centre, Q[best])
    assert bone == labels[best]


def test_tree_centre_of_a_big_headed_stick_figure_is_on_the_spine() -> None:
    """Closed form: from a spine point at height y (below the shoulder) the farthest points are
    a foot, ``y + |hip - foot|``, a hand, ``(0.5 - y) + 0.6``, and the top of the head,
    ``1.0 - y`` (always below the hand's); the centre balances the foot against the hands:
    ``y = (1.1 - 0.906) / 2 = 0.097`` m above the hip, not on the largest part (the head)."""
    Q, labels, parent, joints = _stick_figure()
    centre, bone = tree_centre(Q, labels, parent, joints, quantile=1.0)
    foot = float(np.hypot(0.1, 0.9))
    y = (1.1 - foot) / 2
    assert bone == 1
    spacing = 0.6 / 59  # the spine's sample spacing
    assert abs(centre[1] - y) <= spacing and abs(centre[0]) < 1e-12


def _noisy_stick_figure(n: int = 160) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(0)
    Q, labels, parent, joints = _stick_figure()
    keep = rng.choice(len(Q), n, replace=False)  # a small set for the oracle
    return Q[keep] + 0.01 * rng.normal(size=(n, 3)), labels[keep], parent, joints


@pytest.mark.parametrize("tolerance", [0.03, 0.05, 0.1])
def test_tree_centre_with_a_tolerance_is_the_flat_regions_centroid_by_the_oracle(
        tolerance: float) -> None:
    Q, labels, parent, joints = _noisy_stick_figure()
    centre, bone = tree_centre(Q, labels, parent, joints, quantile=1.0, tolerance=tolerance)
    ecc = _brute_force_eccentricity(Q, labels, parent, joints)
    flat = ecc <= ecc.min() + tolerance * np.linalg.norm(np.ptp(Q, axis=0))
    assert flat.sum() > 1  # a region, not the one point of tolerance 0
    np.testing.assert_allclose(centre, Q[flat].mean(axis=0), atol=1e-12)
    assert bone == np.bincount(labels[flat]).argmax()


def test_tree_centre_with_a_tolerance_keeps_a_mirror_symmetric_figure_on_its_plane() -> None:
    """A figure and its mirror image x -> -x (legs and arms swap bones): the least eccentric
    point is one of a mirrored pair off the plane; the flat region's centroid is on it."""
    Q, labels, parent, joints = _noisy_stick_figure()
    swap = np.array([0, 1, 3, 2, 5, 4])
    Q2 = np.concatenate([Q, Q * np.array([-1.0, 1.0, 1.0])])
    labels2 = np.concatenate([labels, swap[labels]])
    assert np.all(joints[:, 0] == 0)  # the joints lie on the plane
    point, _ = tree_centre(Q2, labels2, parent, joints, quantile=1.0)
    assert abs(point[0]) > 1e-3
    centre, _ = tree_centre(Q2, labels2, parent, joints, quantile=1.0, tolerance=0.01)
    assert abs(centre[0]) < 1e-12


def test_centre_tolerance_is_validated() -> None:
    from pointrig.errors import ConfigError

    for bad in (-0.1, 1.0, "0.02", True):
        with pytest.raises(ConfigError, match="centre_tolerance"):
            StructureConfig(centre_tolerance=bad)


def test_leaf_root_tells_a_leaf_of_a_branched_tree_from_a_chain() -> None:
    assert leaf_root(np.array([-1, 0, 1, 1, 1, 1]))  # big head on a body
    assert not leaf_root(np.array([-1, 0, 1, 2]))  # a chain (arm, snake): far end is right
    assert not leaf_root(np.array([1, -1, 1, 1]))  # a root with three children
    assert not leaf_root(np.array([-1, 0, 0]))  # two children


def test_reroot_keeps_every_joint_and_its_trajectory() -> None:
    rng = np.random.default_rng(1)
    parent = np.array([-1, 0, 1, 1, 2, 3, 3])
    B, F = len(parent), 5
    joints = rng.normal(size=(B, 3))
    R = Rotation.random(F * B, random_state=2).as_matrix().reshape(F, B, 3, 3)
    T = rng.normal(size=(F, B, 3))
    new_joint = rng.normal(size=3)
    p2, j2 = reroot(parent, joints, 5, new_joint)
    # a tree rooted at 5 with the same undirected edges
    assert p2[5] == -1 and int(np.sum(p2 < 0)) == 1
    edges = {frozenset((k, int(p))) for k, p in enumerate(parent) if p >= 0}
    edges2 = {frozenset((k, int(p))) for k, p in enumerate(p2) if p >= 0}
    assert edges == edges2
    # each edge keeps its joint position
    pos = {frozenset((k, int(p))): joints[k] for k, p in enumerate(parent) if p >= 0}
    for k, p in enumerate(p2):
        if p >= 0:
            np.testing.assert_array_equal(j2[k], pos[frozenset((k, int(p)))])
    np.testing.assert_array_equal(j2[5], new_joint)
    # the non-root joints move exactly as before (the same set of trajectories)
    before = joint_trajectories(joints, R, T, parent)
    after = joint_trajectories(j2, R, T, p2)
    old = {frozenset((k, int(p))): before[:, k] for k, p in enumerate(parent) if p >= 0}
    for k, p in enumerate(p2):
        if p >= 0:
            np.testing.assert_allclose(after[:, k], old[frozenset((k, int(p)))], atol=1e-12)
    np.testing.assert_allclose(after[:, 5], np.einsum("fij,j->fi", R[:, 5], new_joint) + T[:, 5])


def test_output_tree_moves_only_a_leaf_root() -> None:
    Q, labels, parent, joints = _stick_figure()
    cfg = StructureConfig()
    p2, j2 = output_tree(Q, labels, parent, joints, cfg)
    assert p2[1] == -1 and p2[0] == 1  # the spine is the root, the head its child
    np.testing.assert_array_equal(j2[0], joints[1])  # the head keeps the neck joint
    assert abs(j2[1][1] - 0.097) < 0.1 and abs(j2[1][0]) < 0.05  # near the hip, not the head top
    # "keep", a chain and a branching root are left alone
    keep = dataclasses.replace(cfg, leaf_root="keep")
    p3, j3 = output_tree(Q, labels, parent, joints, keep)
    np.testing.assert_array_equal(p3, parent)
    np.testing.assert_array_equal(j3, joints)
    chain = np.array([-1, 0, 1, 2, 3, 4])
    p4, _ = output_tree(Q, labels, chain, joints, cfg)
    np.testing.assert_array_equal(p4, chain)


def test_leaf_root_choice_is_validated() -> None:
    from pointrig.errors import ConfigError

    with pytest.raises(ConfigError, match="leaf_root"):
        StructureConfig(leaf_root="middle")


def _torso_with_legs(r: float = 0.15, depth: float = 2.5) -> tuple[np.ndarray, ...]:
    """What a depth camera at the origin looking along +z sees of a round torso (radius ``r``,
    axis vertical at ``x = 0, z = depth``, 0.6 m tall) with two legs hanging below: the near
    half of each cylinder, sampled uniformly across the image (metres). Returns rest points
    (M, 3), labels (M,), parents (3,) (the torso is the root, with two children) and head
    joints (3, 3): the torso's at the centroid of its visible points, the legs' at the hips."""
    rng = np.random.default_rng(4)

    def front(n: int, x0: float, radius: float, y0: float, y1: float) -> np.ndarray:
        x = rng.uniform(-radius, radius, n)
        y = rng.uniform(y0, y1, n)
        return np.stack([x0 + x, y, depth - np.sqrt(radius ** 2 - x ** 2)], axis=1)

    parts = [front(3000, 0.0, r, -0.3, 0.3), front(800, -0.08, 0.06, -1.2, -0.3),
             front(800, 0.08, 0.06, -1.2, -0.3)]
    Q = np.concatenate(parts)
    labels = np.concatenate([np.full(len(p), b) for b, p in enumerate(parts)])
    parent = np.array([-1, 0, 0])
    joints = np.array([parts[0].mean(axis=0), [-0.08, -0.3, depth], [0.08, -0.3, depth]])
    return Q, labels, parent, joints


def test_output_root_joint_moves_back_to_the_axis_depth() -> None:
    Q, labels, parent, joints = _torso_with_legs()
    cfg = StructureConfig()
    camera = np.zeros(3)
    # the visible centroid lies pi r / 4 = 11.8 cm in front of the axis (closed form)
    assert abs(joints[0][2] - (2.5 - np.pi * 0.15 / 4)) < 0.01
    p2, j2 = output_tree(Q, labels, parent, joints, cfg, camera)
    np.testing.assert_array_equal(p2, parent)
    np.testing.assert_array_equal(j2[1:], joints[1:])  # only the root joint moves
    assert abs(j2[0][2] - 2.5) < 0.02  # at the axis, within 2 cm
    # along the camera ray through the joint: the same direction from the camera, farther
    u0, u1 = joints[0] / np.linalg.norm(joints[0]), j2[0] / np.linalg.norm(j2[0])
    np.testing.assert_allclose(u1, u0, atol=1e-12)
    # no camera (input that is not one view) keeps the visible centroid
    _, j3 = output_tree(Q, labels, parent, joints, cfg, None)
    np.testing.assert_array_equal(j3, joints)
