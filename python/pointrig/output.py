"""The output stage after step 3: the skeleton as :func:`pointrig.pipeline.extract` writes it.

Steps 1-3 (paper §4-§6) give bones, their motions and Eq. 20 joints. This stage turns them
into the output skeleton (:func:`output_skeleton`), in order:

1. **Joint selection** (:func:`pointrig.selection.select_joints`, ``[structure]
   joint_penalty``): the joints the raw frames support.
2. **Output tree** (:func:`output_tree`): the root joint at the root part's centre (§5.3) or
   the body's centre through the bone tree when the root is a leaf of a branched tree
   (:func:`tree_eccentricity`, :func:`tree_centre`, :func:`centre_root_joint`,
   :func:`reroot`), moved back along the camera ray to the body's axis depth
   (:func:`root_axis_joint`).
3. **Joint depth and bone rolls** (after step 3): the joints to their parts' axis depth
   (:func:`pointrig.view.view_depth_joints`) and the minimal twist of every bone
   (:func:`pointrig.kinematics.minimal_twist`).
4. :func:`build_skeleton`: joints in parent-before-child order.

Conventions: metres; ``x = R[t, b] @ q + T[t, b]`` (``T_frame_rest``); ``bone_parent`` ``-1``
at the root; joint ``b`` is the head of bone ``b``.
"""

from __future__ import annotations

import itertools
import logging
import time
from collections.abc import Sequence

import numpy as np

from .config import PipelineConfig, StructureConfig
from .errors import InputError
from .kinematics import (
    joint_trajectories,
    minimal_twist,
    tree_order,
)
from .skeleton import Skeleton
from .view import view_depth_correct, view_depth_joints

__all__ = [
    "build_skeleton",
    "centre_root_joint",
    "leaf_root",
    "output_skeleton",
    "output_tree",
    "reroot",
    "root_axis_joint",
    "tree_centre",
    "tree_eccentricity",
]

log = logging.getLogger(__name__)


def output_skeleton(rest_points: np.ndarray, labels: np.ndarray, bone_parent: np.ndarray,
                    joints_rest: np.ndarray, R: np.ndarray, T: np.ndarray,
                    weights: np.ndarray | None, config: PipelineConfig,
                    view_camera: np.ndarray | None,
                    observed: tuple[Sequence[np.ndarray], np.ndarray] | None = None,
                    timings: dict[str, float] | None = None) -> Skeleton:
    """The skeleton as :func:`extract` outputs it, from step 2's or step 3's bones.

    The one place of the output stage, so that a benchmark that reruns step 3 on cached
    inputs scores what the pipeline writes: after step 3 (``observed`` given) first the joints
    the raw frames support (:func:`pointrig.selection.select_joints`, ``[structure]
    joint_penalty``), then the output tree (a leaf root moves to the body's
    centre, :func:`pointrig.output.output_tree`), then, after step 3 (``observed`` given),
    the joints to their parts' axis depth along the camera ray (``[joints] joint_depth``,
    :func:`pointrig.view.view_depth_joints`) and the bones' rolls
    (``[joints] bone_twist``, :func:`pointrig.kinematics.minimal_twist`), then
    :func:`build_skeleton`.

    Parameters
    ----------
    rest_points
        ``(M, 3)`` rest points, metres.
    labels
        ``(M,)`` bone of each rest point.
    bone_parent
        ``(B,)`` parent bone, ``-1`` for the root.
    joints_rest
        ``(B, 3)`` rest-pose head joint of each bone, metres.
    R, T
        ``(F, B, 3, 3)`` and ``(F, B, 3)``: ``T_frame_rest`` of every bone per frame, metres.
    weights
        ``(M, B)`` skinning weights, or ``None``.
    config
        The pipeline's parameters (``structure`` and ``joints`` are read).
    view_camera
        ``(3,)`` camera position (metres) when the input is one view, else ``None`` (no depth
        pass).
    observed
        After step 3: ``(frames, registered)``, the ``F`` observed clouds ``(N_t, 3)`` and the
        final registration's ``(F, M, 3)`` points (metres) that the depth pass reads; ``None``
        for a step-2 skeleton (output tree only).
    timings
        If given, the depth pass's seconds are stored under ``"joint_depth"``.
    """
    from .selection import select_joints

    if observed is not None and config.structure.joint_penalty > 0:
        t0 = time.perf_counter()
        sel = select_joints(observed[0], rest_points, labels, bone_parent, R, T,
                            penalty_scale=config.structure.joint_penalty,
                            max_frames=config.structure.joint_frames,
                            workers=config.structure.workers)
        if sel.removed:
            log.info("removed %d of %d joints the raw frames do not support",
                     len(sel.removed), len(bone_parent))
        labels, bone_parent, R, T = sel.labels, sel.bone_parent, sel.R, sel.T
        joints_rest = sel.rest_joints(joints_rest)
        if weights is not None:
            weights = sel.merge_weights(weights)
        if timings is not None:
            timings["joint_selection"] = time.perf_counter() - t0
    parent, joints_rest = output_tree(rest_points, labels, bone_parent, joints_rest,
                                      config.structure, view_camera)
    if observed is not None and config.joints.joint_depth == "chord" \
            and view_camera is not None:
        t0 = time.perf_counter()
        joints_rest, _ = view_depth_joints(
            observed[0], observed[1], labels, parent, joints_rest, R, T, view_camera,
            n_frames=config.joints.depth_frames)
        if timings is not None:
            timings["joint_depth"] = time.perf_counter() - t0
    if observed is not None and config.joints.bone_twist == "minimal":
        R, T = minimal_twist(R, T, joints_rest, parent, rest_points, labels,
                             config.joints.twist_min_elongation,
                             config.joints.twist_min_roll_deg)
    return build_skeleton(rest_points, parent, joints_rest, R, T, weights, labels)


def build_skeleton(rest_points: np.ndarray, bone_parent: np.ndarray, joints_rest: np.ndarray,
                   R: np.ndarray, T: np.ndarray, weights: np.ndarray | None,
                   labels: np.ndarray | None) -> Skeleton:
    """Assemble a :class:`Skeleton` with joints in parent-before-child order.

    Joint ``b`` is the head of bone ``b`` (see :mod:`pointrig.kinematics`); skeleton bones
    are the segments parent joint -> child joint.
    """
    order = tree_order(bone_parent)
    inv = np.empty_like(order)
    inv[order] = np.arange(len(order))
    parents = np.array([inv[bone_parent[b]] if bone_parent[b] >= 0 else -1 for b in order])
    jr = joints_rest[order]
    Ro, To = R[:, order], T[:, order]
    jp = joint_trajectories(jr, Ro, To, parents)
    non_root = [j for j in range(len(order)) if parents[j] >= 0]
    return Skeleton(
        joint_names=[f"j{j}" for j in range(len(order))],
        parents=parents,
        rest_positions=jr,
        joint_positions=jp,
        bone_heads=np.array([parents[j] for j in non_root], dtype=np.int64),
        bone_tails=np.array(non_root, dtype=np.int64),
        bone_rotations=Ro,
        bone_translations=To,
        weights=None if weights is None else weights[:, order],
        rest_points=rest_points,
        labels=None if labels is None else inv[labels],
        bone_names=[f"b{j}" for j in non_root],
    )


def tree_eccentricity(rest_points: np.ndarray, labels: np.ndarray, bone_parent: np.ndarray,
                      joints_rest: np.ndarray, quantile: float = 0.98) -> np.ndarray:
    """Every rest point's farthest distance to the rest of the body *through the bone tree*.

    The distance from a point ``x`` of bone ``b`` to a point ``y`` of bone ``b'`` runs from
    ``x`` to the joint where the tree path leaves ``b``, along the path's joints, and from the
    joint where it enters ``b'`` to ``y`` (straight within one bone). A point's eccentricity is
    the largest such distance, each bone's far end taken as the ``quantile`` of its points'
    distances (robust to stray points).

    Parameters
    ----------
    rest_points
        ``(M, 3)`` rest points, metres.
    labels
        ``(M,)`` bone of each point.
    bone_parent
        ``(B,)`` parent bone, ``-1`` at the root.
    joints_rest
        ``(B, 3)`` head joint of every bone, metres (the root's is not used).
    quantile
        In ``(0, 1]``.

    Returns
    -------
    ecc
        ``(M,)`` metres; ``inf`` for a point whose label is not a bone.
    """
    from scipy.spatial.distance import cdist

    Q = np.asarray(rest_points, dtype=float)
    labels = np.asarray(labels, dtype=np.int64)
    parent = np.asarray(bone_parent, dtype=np.int64)
    B = len(parent)
    adj: list[list[tuple[int, int]]] = [[] for _ in range(B)]  # (neighbour, joint index)
    for k, p in enumerate(parent):
        if p >= 0:
            adj[k].append((int(p), k))
            adj[int(p)].append((k, k))
    pts = [Q[labels == b] for b in range(B)]
    far: dict[tuple[int, int], float] = {}  # (bone, entry joint) -> reach of its far end
    out = np.full(len(Q), np.inf)
    for b in range(B):
        P = pts[b]
        if len(P) == 0:
            continue
        ecc = np.quantile(cdist(P, P), quantile, axis=1)
        # walk the tree from b: for each bone reached, the first joint on the way out of b,
        # the path length along the joints since, and the joint where the walk entered it
        stack = [(nb, j, j, 0.0) for nb, j in adj[b]]
        seen = {b}
        while stack:
            c, first, last, length = stack.pop()
            seen.add(c)
            if len(pts[c]):
                if (c, last) not in far:
                    far[c, last] = float(np.quantile(
                        np.linalg.norm(pts[c] - joints_rest[last], axis=1), quantile))
                ecc = np.maximum(ecc, np.linalg.norm(P - joints_rest[first], axis=1)
                                 + length + far[c, last])
            for nb, j in adj[c]:
                if nb not in seen:
                    stack.append((nb, first, j,
                                  length + float(np.linalg.norm(joints_rest[j]
                                                                - joints_rest[last]))))
        out[labels == b] = ecc
    return out


def tree_centre(rest_points: np.ndarray, labels: np.ndarray, bone_parent: np.ndarray,
                joints_rest: np.ndarray, quantile: float = 0.98,
                tolerance: float = 0.0) -> tuple[np.ndarray, int]:
    """The body's centre through the bone tree and its bone.

    With ``tolerance = 0``: the rest point that minimises the farthest distance to the rest of
    the body through the bone tree (:func:`tree_eccentricity`). On a figure it lies between
    the limbs' attachments (a human's lower spine), whatever bone is largest. The minimum is
    flat across the body there, so which point wins can be decided by a stray lateral offset
    of a joint (on an idle figure whose hanging arms are part of the torso's bone, a hand at
    hip height). With ``tolerance > 0`` the centre
    is the centroid of the whole flat region, the points whose eccentricity is within
    ``tolerance`` times the rest points' bounding-box diagonal of the minimum, and its bone
    the one holding most of them.

    Parameters
    ----------
    rest_points, labels, bone_parent, joints_rest, quantile
        As for :func:`tree_eccentricity`.
    tolerance
        ``>= 0``, a fraction of the rest points' bounding-box diagonal.

    Returns
    -------
    point, bone
        ``(3,)`` the centre, metres (one of the rest points when ``tolerance = 0``), and its
        bone.
    """
    Q = np.asarray(rest_points, dtype=float)
    labels = np.asarray(labels, dtype=np.int64)
    ecc = tree_eccentricity(Q, labels, bone_parent, joints_rest, quantile)
    if not np.isfinite(ecc).any():
        raise InputError("tree_centre: no bone holds any rest point")
    i = int(np.argmin(ecc))
    if tolerance <= 0:
        return Q[i].copy(), int(labels[i])
    diag = float(np.linalg.norm(np.ptp(Q, axis=0)))
    flat = ecc <= ecc[i] + tolerance * diag
    return Q[flat].mean(axis=0), int(np.bincount(labels[flat]).argmax())


def centre_root_joint(rest_points: np.ndarray, centre: np.ndarray,
                      view_camera: np.ndarray | None = None, view_quantile: float = 0.95,
                      ball: float = 0.1) -> np.ndarray:
    """Rest position ``(3,)`` (metres) of a root joint at the body's centre: the centroid of
    the rest points within ``ball`` times the rest points' bounding-box diagonal of ``centre``
    (:func:`tree_centre`), moved back along the camera ray to the depth of the body's axis
    (:func:`pointrig.view.view_depth_correct`) when ``view_camera`` is given."""
    near = _ball_points(rest_points, centre, ball)
    return _axis_depth(near, near.mean(axis=0), view_camera, view_quantile)


def root_axis_joint(rest_points: np.ndarray, joint: np.ndarray,
                    view_camera: np.ndarray | None = None, view_quantile: float = 0.95,
                    ball: float = 0.1) -> np.ndarray:
    """Rest position ``(3,)`` (metres) of a root joint moved back along the camera ray from
    ``joint`` (the visible root part's centre, or its end) to the depth of the body's axis
    there: the single-view correction of :func:`pointrig.view.view_depth_correct` on the rest
    points within ``ball`` times the rest points' bounding-box diagonal of ``joint``, as
    :func:`centre_root_joint` does for the body's centre. Only the depth changes;
    ``joint`` is returned unchanged without ``view_camera``."""
    near = _ball_points(rest_points, joint, ball)
    return _axis_depth(near, np.asarray(joint, dtype=float), view_camera, view_quantile)


def _ball_points(rest_points: np.ndarray, centre: np.ndarray, ball: float) -> np.ndarray:
    """The rest points ``(n, 3)`` within ``ball`` x their bounding-box diagonal of ``centre``
    (``centre`` itself when none is)."""
    Q = np.asarray(rest_points, dtype=float)
    radius = ball * float(np.linalg.norm(np.ptp(Q, axis=0)))
    near = Q[np.linalg.norm(Q - centre, axis=1) <= radius]
    return near if len(near) else np.asarray(centre, dtype=float)[None]


def _axis_depth(near: np.ndarray, c: np.ndarray, view_camera: np.ndarray | None,
                view_quantile: float) -> np.ndarray:
    """``c (3,)`` moved back to the axis depth of the points ``near (n, 3)``, or a copy of it
    without a camera (metres; ``view_depth_correct`` itself returns a copy for a quantile of
    0)."""
    if view_camera is None:
        return np.array(c, dtype=float)
    return view_depth_correct(near, None, c, view_camera, view_quantile)


def output_tree(rest_points: np.ndarray, labels: np.ndarray, bone_parent: np.ndarray,
                joints_rest: np.ndarray, cfg: StructureConfig,
                view_camera: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The bone tree and head joints ``((B,), (B, 3))`` of the output skeleton.

    With ``cfg.leaf_root = "centre"`` a root that is a leaf of a branched tree
    (:func:`leaf_root`: the largest part is a limb end, such as a big head) is moved to the
    body's centre (:func:`tree_centre`, :func:`centre_root_joint`, :func:`reroot`): its head
    joint would otherwise sit at the far end of that limb (``root_end_alignment``), where no
    rig puts a joint. Chains (an arm, a snake) and roots with several children keep their
    tree, and with a camera their root joint moves back along the camera ray to the body's
    axis depth (:func:`root_axis_joint`, the correction every other joint gets; the re-rooted
    centre gets it too). The bones' motions do not change, only which joint heads which bone
    and where the root joint lies.
    """
    parent = np.asarray(bone_parent, dtype=np.int64)
    if cfg.leaf_root != "centre" or not leaf_root(parent):
        joints = np.array(joints_rest, dtype=float)
        root = int(np.flatnonzero(parent < 0)[0])
        joints[root] = root_axis_joint(rest_points, joints[root], view_camera,
                                       cfg.view_depth_quantile)
        return parent, joints
    centre, bone = tree_centre(rest_points, labels, parent, joints_rest,
                               tolerance=cfg.centre_tolerance)
    joint = centre_root_joint(rest_points, centre, view_camera, cfg.view_depth_quantile)
    log.info("root moved from bone %d (a leaf) to bone %d at the body's centre",
             int(np.flatnonzero(parent < 0)[0]), bone)
    return reroot(parent, joints_rest, bone, joint)


def leaf_root(bone_parent: np.ndarray) -> bool:
    """True if the root bone is a leaf of a branched tree: it has one child, and some bone has
    three or more tree neighbours (not a chain)."""
    parent = np.asarray(bone_parent, dtype=np.int64)
    root = int(np.flatnonzero(parent < 0)[0])
    degree = np.bincount(parent[parent >= 0], minlength=len(parent)) + (parent >= 0)
    return int(np.sum(parent == root)) == 1 and bool(np.any(degree >= 3))


def reroot(bone_parent: np.ndarray, joints_rest: np.ndarray, new_root: int,
           root_joint: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The same bone tree rooted at ``new_root``: parents ``(B,)`` and head joints ``(B, 3)``.

    Every joint stays where it is; only the bone it heads changes. On the path from the old
    root to ``new_root`` each edge turns round, so the joint between a bone and its old parent
    becomes the head of that parent. The old root's own head joint is dropped and
    ``root_joint (3,)`` (metres) becomes the head of ``new_root``.
    """
    parent = np.asarray(bone_parent, dtype=np.int64).copy()
    joints = np.asarray(joints_rest, dtype=float).copy()
    path = [int(new_root)]
    while parent[path[-1]] >= 0:
        path.append(int(parent[path[-1]]))
    old_joint = {k: joints[k].copy() for k in path}
    for child, par in itertools.pairwise(path):
        parent[par] = child
        joints[par] = old_joint[child]
    parent[new_root] = -1
    joints[new_root] = np.asarray(root_joint, dtype=float)
    return parent, joints
