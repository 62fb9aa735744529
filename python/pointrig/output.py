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
3. **Splits** (after step 3): one bone per separate piece of a bone that carries two subtrees
   (:func:`split_disconnected_bones`, each piece's joint by Eq. 20) and a joint where a leaf
   bone bends (:func:`split_bent_leaves`, :func:`leaf_bend`); the new bones take their source
   bone's motion and skinning weights.
4. **Joint depth and bone rolls** (after step 3): the joints to their parts' axis depth
   (:func:`pointrig.view.view_depth_joints`) and the minimal twist of every bone
   (:func:`pointrig.kinematics.minimal_twist`).
5. :func:`build_skeleton`: joints in parent-before-child order.

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
from .geometry import knn_graph
from .kinematics import (
    joint_trajectories,
    minimal_twist,
    solve_joint_positions,
    tree_order,
)
from .skeleton import Skeleton
from .structure import fit_bones
from .view import view_depth_correct, view_depth_joints

__all__ = [
    "build_skeleton",
    "centre_root_joint",
    "leaf_bend",
    "leaf_root",
    "output_skeleton",
    "output_tree",
    "reroot",
    "root_axis_joint",
    "split_bent_leaves",
    "split_disconnected_bones",
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
    one bone per separate piece of a bone that carries two subtrees
    (:func:`pointrig.output.split_disconnected_bones`, ``[structure] split_disconnected``)
    and a joint where a leaf bone bends (:func:`pointrig.output.split_bent_leaves`,
    ``[structure] leaf_split_*``; the new bones take their source bone's motion), the joints
    to their parts' axis depth along the camera ray (``[joints] joint_depth``,
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
                            max_frames=config.structure.joint_frames)
        if sel.removed:
            log.info("removed %d of %d joints the raw frames do not support",
                     len(sel.removed), len(bone_parent))
        labels, bone_parent, R, T = sel.labels, sel.bone_parent, sel.R, sel.T
        joints_rest = np.asarray(joints_rest)[sel.keep]
        if weights is not None:
            weights = sel.merge_weights(weights)
        if timings is not None:
            timings["joint_selection"] = time.perf_counter() - t0
    parent, joints_rest = output_tree(rest_points, labels, bone_parent, joints_rest,
                                      config.structure, view_camera)
    if observed is not None:
        # new bones take their source bone's motion and weights: first the separate pieces
        # of a bone, then the bends of the leaves
        for split in (split_disconnected_bones, split_bent_leaves):
            labels, parent, joints_rest, source = split(rest_points, labels, parent,
                                                        joints_rest, observed[1],
                                                        config.structure)
            if len(source) > R.shape[1]:
                R, T = R[:, source], T[:, source]
                if weights is not None:
                    weights = _split_weights(weights, labels, source)
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


def _split_weights(weights: np.ndarray, labels: np.ndarray, source: np.ndarray) -> np.ndarray:
    """``(M, B')`` skinning weights after :func:`pointrig.output.split_bent_leaves` or
    :func:`pointrig.output.split_disconnected_bones`: each new bone ``b >= B`` takes its
    source bone's weight of the points now labelled ``b`` (the two move alike, so the skinned
    points do not change)."""
    W = np.asarray(weights, dtype=float)
    B = W.shape[1]
    out = np.zeros((W.shape[0], len(source)))
    out[:, :B] = W
    for b in range(B, len(source)):
        moved = labels == b
        out[moved, b] = W[moved, source[b]]
        out[moved, source[b]] = 0.0
    return out


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


def _segment_distances(X: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``(n,)`` distances of the points ``X (n, 3)`` to the segment ``a``-``b``."""
    ab = b - a
    t = np.clip((X - a) @ ab / max(float(ab @ ab), 1e-24), 0.0, 1.0)
    return np.linalg.norm(X - (a + t[:, None] * ab), axis=1)


def _geodesic_from(X: np.ndarray, source: np.ndarray, k: int = 8) -> np.ndarray:
    """``(n,)`` distances (metres) from the point of ``X (n, 3)`` nearest ``source`` over the
    ``k``-nearest-neighbour graph of ``X``; the Euclidean distance to ``source`` where the graph
    leaves more than a fifth of the points unreached (a piece seen in parts)."""
    from scipy.sparse.csgraph import dijkstra

    graph = knn_graph(X, k)
    s = int(np.argmin(np.linalg.norm(X - source, axis=1)))
    geo = dijkstra(graph, directed=False, indices=s)
    if np.isfinite(geo).mean() < 0.8:
        return np.linalg.norm(X - source, axis=1)
    return geo  # unreached points: inf


def leaf_bend(points: np.ndarray, head: np.ndarray, n_bins: int = 10
              ) -> tuple[float, np.ndarray, float, float, np.ndarray]:
    """The bend of a bone's rest points: a two-segment polyline head -> bend -> tip.

    The points are ordered by their geodesic distance from the head joint
    (:func:`_geodesic_from`) and cut into ``n_bins`` bins of equal count; the tip is the
    centroid of the farthest tenth, and the bend is the bin centroid (bins 2 to ``n_bins - 2``)
    whose polyline leaves the smallest median point distance.

    Parameters
    ----------
    points
        ``(n, 3)`` rest points of the bone, metres (``n >= 4``).
    head
        ``(3,)`` the bone's head joint, metres.
    n_bins
        Geodesic bins.

    Returns
    -------
    angle, bend, proximal, distal, geodesic
        The turn between the two segments (degrees, 0 = straight), the bend ``(3,)``
        (metres), the two segments' lengths (metres) and each point's geodesic distance
        ``(n,)`` from the head (metres).
    """
    X = np.asarray(points, dtype=float)
    head = np.asarray(head, dtype=float)
    geo = _geodesic_from(X, head)
    ok = np.isfinite(geo)
    tip = X[ok & (geo >= np.quantile(geo[ok], 0.9))].mean(0)
    edges = np.quantile(geo[ok], np.linspace(0.0, 1.0, n_bins + 1))
    best = (np.inf, head)
    for i in range(2, n_bins - 1):
        inside = ok & (geo >= edges[i]) & (geo <= edges[i + 1])
        if not inside.any():
            continue
        c = X[inside].mean(0)
        r = float(np.median(np.minimum(_segment_distances(X, head, c),
                                       _segment_distances(X, c, tip))))
        if r < best[0]:
            best = (r, c)
    bend = best[1]
    u, v = bend - head, tip - bend
    lu, lv = float(np.linalg.norm(u)), float(np.linalg.norm(v))
    if lu < 1e-12 or lv < 1e-12:
        return 0.0, bend, lu, lv, geo
    angle = float(np.degrees(np.arccos(np.clip(u @ v / (lu * lv), -1.0, 1.0))))
    return angle, bend, lu, lv, geo


def _rigid_residual(rest: np.ndarray, moved: np.ndarray, pieces: np.ndarray) -> float:
    """Sum over frames and points of the squared residual (m^2) of each piece's best rigid fit
    (:func:`fit_bones`) of ``rest (n, 3)`` to each frame of ``moved (F, n, 3)``; ``pieces
    (n,)`` numbers the pieces from 0."""
    pieces = np.ascontiguousarray(pieces, dtype=np.int64)
    R, T, _ = fit_bones(np.ascontiguousarray(rest), np.ascontiguousarray(moved), pieces,
                        int(pieces.max()) + 1)
    fit = np.einsum("fnij,nj->fni", R[:, pieces], rest) + T[:, pieces]
    return float(((fit - moved) ** 2).sum())


def _split_start(labels: np.ndarray, bone_parent: np.ndarray, joints_rest: np.ndarray
                 ) -> tuple[np.ndarray, list[int], list[np.ndarray], list[int]]:
    """Editable copies of a skeleton for the output stage's splits: labels ``(M,)`` int64,
    parents, head joints ``(3,)`` (metres) and each bone's source bone (itself)."""
    parent = [int(p) for p in bone_parent]
    return (np.asarray(labels, dtype=np.int64).copy(), parent,
            [np.asarray(j, dtype=float) for j in joints_rest], list(range(len(parent))))


def _split_result(labels: np.ndarray, parent: list[int], joints: list[np.ndarray],
                  source: list[int]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The split skeleton as arrays: labels ``(M,)``, parents ``(B',)``, joints ``(B', 3)``
    (metres) and sources ``(B',)``."""
    return (labels, np.array(parent, dtype=np.int64), np.array(joints),
            np.array(source, dtype=np.int64))


def split_bent_leaves(rest_points: np.ndarray, labels: np.ndarray, bone_parent: np.ndarray,
                      joints_rest: np.ndarray, registered: np.ndarray, cfg: StructureConfig
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A joint where a leaf bone's rest shape bends and its two pieces move apart.

    Step 2's clustering gives a small end part (a foot: 12-19 of 2000 rest points) no bone of
    its own, so it rides in one leaf bone with the end of the limb. A limb between two joints
    is straight; where a leaf's points bend (:func:`leaf_bend`, at least
    ``cfg.leaf_split_angle_deg``) and two rigid fits of the two pieces to the registered points
    leave at most ``cfg.leaf_split_max_ratio`` of one fit's squared residual, the points past
    the bend become a child bone whose head joint is the bend (docs/structure.md).
    Either test alone fires on heads, torso pieces and limbs cut lengthwise. A leaf that one
    rigid motion fits to 0.1 % of the subject size (RMS) is left whole. With
    ``cfg.max_joints > 0`` the output keeps at most that many bones: the splits with the
    smallest residual ratios go first.

    Parameters
    ----------
    rest_points
        ``(M, 3)`` rest points, metres.
    labels
        ``(M,)`` bone of each rest point.
    bone_parent
        ``(B,)`` parent bone, ``-1`` for the root.
    joints_rest
        ``(B, 3)`` head joints, metres.
    registered
        ``(F, M, 3)`` registered points, metres.
    cfg
        ``leaf_split_*`` are read; ``leaf_split_angle_deg = 0`` returns the input.

    Returns
    -------
    labels, parent, joints, source
        ``(M,)``, ``(B',)``, ``(B', 3)`` and ``(B',)``: the new bones come after the old ones,
        and ``source[b]`` is the bone whose motion and skinning weights bone ``b`` takes (``b``
        itself for the old bones, the split leaf for a new one).
    """
    labels, parent, joints, source = _split_start(labels, bone_parent, joints_rest)
    B = len(parent)
    if cfg.leaf_split_angle_deg <= 0:
        return _split_result(labels, parent, joints, source)
    Q = np.asarray(rest_points, dtype=float)
    Y = np.asarray(registered, dtype=float)
    size = float(np.linalg.norm(np.ptp(Q, axis=0)))
    n_children = np.bincount([p for p in parent if p >= 0], minlength=B)
    found: list[tuple[float, int, float, np.ndarray, np.ndarray]] = []
    for b in range(B):
        if n_children[b] or parent[b] < 0:
            continue
        idx = np.flatnonzero(labels == b)
        if len(idx) < max(cfg.leaf_split_min_points, 4):
            continue
        Xb = Q[idx]
        angle, bend, lu, lv, geo = leaf_bend(Xb, joints[b])
        if angle < cfg.leaf_split_angle_deg \
                or min(lu, lv) < cfg.leaf_split_min_fraction * (lu + lv) \
                or lv < cfg.leaf_split_min_length * size:
            continue
        distal = geo > geo[int(np.argmin(np.linalg.norm(Xb - bend, axis=1)))]
        if min(distal.sum(), (~distal).sum()) < 4:
            continue
        Yb = Y[:, idx]
        one = _rigid_residual(Xb, Yb, np.zeros(len(idx)))
        if np.sqrt(one / (len(Y) * len(idx))) < 1e-3 * size:
            continue  # one rigid motion explains the leaf (noise-free input): nothing bends
        two = _rigid_residual(Xb, Yb, distal)
        far = idx[distal]
        if two <= cfg.leaf_split_max_ratio * one:
            found.append((two / one, b, angle, far, np.asarray(bend, dtype=float)))
    # a user's cap on the joints (max_joints) holds: the clearest splits first
    room = cfg.max_joints - B if cfg.max_joints > 0 else len(found)
    for ratio, b, angle, far, bend in sorted(found, key=lambda c: (c[0], c[1]))[:max(room, 0)]:
        log.info("leaf bone %d split at its bend (%.0f deg, residual ratio %.2f)", b, angle,
                 ratio)
        labels[far] = len(parent)
        parent.append(b)
        joints.append(bend)
        source.append(b)
    return _split_result(labels, parent, joints, source)


def split_disconnected_bones(rest_points: np.ndarray, labels: np.ndarray,
                             bone_parent: np.ndarray, joints_rest: np.ndarray,
                             registered: np.ndarray | None, cfg: StructureConfig
                             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One bone per spatially separate piece of a bone that carries two or more subtrees.

    A rigid part is one connected piece of surface. Where step 2 gives one bone two pieces
    that do not touch, each carrying its own child bones (both thighs of a figure standing
    nearly still, whose small motions the clustering could not tell apart), the two are
    parts that happen to move alike, and a single joint between them and the parent stands
    for two. Here the bone's rest points are split into the connected components of the graph
    joining points closer than ``cfg.split_disconnected`` times the median rest spacing; the
    components holding at least ``max(10, 15 %)`` of the bone's points and the head joint of
    a child bone (each child goes to the component nearest its joint) each become a bone, the
    other points join the nearest of them. The new bones take the bone's motion and skinning
    weights (``source``) and hang from its parent. Each piece's head joint is step 2's joint
    rule (Eq. 20, :func:`pointrig.kinematics.solve_joint_positions` with ``cfg.eta``) on the
    Kabsch fits of the piece and of the parent to the registered points, its prior ``c~`` the
    centroid of the tenth of the piece's points nearest the bone's old head joint (that
    centroid itself without ``registered``). The root, bones with fewer than two children, and
    splits past ``cfg.max_joints`` (when > 0) are left whole.

    Parameters
    ----------
    rest_points
        ``(M, 3)`` rest points, metres.
    labels
        ``(M,)`` bone of each rest point.
    bone_parent
        ``(B,)`` parent bone, ``-1`` for the root.
    joints_rest
        ``(B, 3)`` head joints, metres.
    registered
        ``(F, M, 3)`` registered points, metres, or ``None``.
    cfg
        ``split_disconnected`` (rest spacings; 0 = off), ``eta`` and ``max_joints`` are read.

    Returns
    -------
    labels, parent, joints, source
        ``(M,)``, ``(B',)``, ``(B', 3)`` and ``(B',)`` as :func:`split_bent_leaves` returns
        them: new bones after the old ones, ``source[b]`` the bone whose motion bone ``b``
        takes.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    labels, parent, joints, source = _split_start(labels, bone_parent, joints_rest)
    B = len(parent)
    if cfg.split_disconnected <= 0:
        return _split_result(labels, parent, joints, source)
    Q = np.asarray(rest_points, dtype=float)
    spacing = float(np.median(cKDTree(Q).query(Q, 2)[0][:, 1]))
    for b in range(B):
        kids = [c for c in range(B) if parent[c] == b]
        idx = np.flatnonzero(labels == b)
        if parent[b] < 0 or len(kids) < 2 or len(idx) < 20:
            continue
        pairs = cKDTree(Q[idx]).query_pairs(cfg.split_disconnected * spacing,
                                            output_type="ndarray")
        graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])),
                           shape=(len(idx), len(idx)))
        n_comp, comp = connected_components(graph, directed=False)
        sizes = np.bincount(comp, minlength=n_comp)
        big = [c for c in range(n_comp) if sizes[c] >= max(10, 0.15 * len(idx))]
        if len(big) < 2:
            continue
        trees = {c: cKDTree(Q[idx[comp == c]]) for c in big}
        owner = {k: min(big, key=lambda c: trees[c].query(joints[k])[0]) for k in kids}
        pieces = sorted(set(owner.values()))
        if len(pieces) < 2 or 0 < cfg.max_joints < len(parent) + len(pieces) - 1:
            continue  # a user's cap on the joints (max_joints) holds
        near = np.argmin(np.stack([trees[c].query(Q[idx])[0] for c in pieces], axis=1), axis=1)
        # each piece's c~: the centroid of the tenth of its points nearest the old head joint
        head = joints[b]
        heads = []
        for p in range(len(pieces)):
            X = Q[idx[near == p]]
            d = np.linalg.norm(X - head, axis=1)
            heads.append(X[d <= np.quantile(d, 0.1)].mean(axis=0))
        if registered is not None:
            # Eq. 20 for every edge parent -> piece, on the Kabsch fits of the parent (local
            # bone 0) and of the pieces (1, 2, ...)
            local = np.full(len(Q), -1, dtype=np.int64)
            local[labels == parent[b]] = 0
            local[idx] = near + 1
            keep = local >= 0
            Rf, Tf, _ = fit_bones(Q[keep], np.ascontiguousarray(registered[:, keep]),
                                  local[keep], len(pieces) + 1)
            heads = list(solve_joint_positions(Rf, Tf, np.array([-1] + [0] * len(pieces)),
                                               np.vstack([head, heads]), cfg.eta)[1:])
        new = [b] + list(range(len(parent), len(parent) + len(pieces) - 1))
        joints[b] = heads[0]
        for h in heads[1:]:
            parent.append(parent[b])
            joints.append(h)
            source.append(b)
        labels[idx] = np.asarray(new)[near]
        for k in kids:
            parent[k] = new[pieces.index(owner[k])]
        log.info("bone %d split into %d separate pieces (%s points)", b, len(pieces),
                 [int(np.sum(near == p)) for p in range(len(pieces))])
    return _split_result(labels, parent, joints, source)


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
