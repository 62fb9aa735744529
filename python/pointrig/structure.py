"""Step 2: skeletal structure extraction (paper §5, Eqs. 14, 15 and 20).

From the registered sequence (rest points ``Q (M, 3)`` and their positions ``Y (F, M, 3)`` in
every frame) build a bone tree without being told the number of bones:

1. **Motion-based clustering** (§5.2). k-means on rest positions concatenated with scaled
   displacement trajectories gives ``k`` initial clusters; then ``cluster_rounds`` rounds of
   (i) one rigid transform per cluster and frame by weighted absolute orientation (Kabsch,
   Eq. 14), (ii) relabel each point by the candidate bone with the smallest residual summed over
   frames, (iii) majority vote of the labels in a rest-pose ball around each point. The fits and
   residuals run in the Rust core (``_core.cluster_fit``, ``_core.cluster_residuals``);
   the clustering itself is :mod:`pointrig.clustering`.
2. **Refinement** (§5.4), made precise (docs/structure.md): bones whose relative rotation never
   exceeds ``merge_angle_deg`` (``merge_percentile``-th percentile over every two frames) and whose
   relative motion moves the smaller bone by less than ``merge_displacement`` of the subject's
   size (``merge_rule="both"``: no visible articulation either way) are merged, tiny
   clusters are absorbed, spurious leaves at branching joints are pruned, and bones whose joints
   (Eq. 20) collapse onto one point are removed ("merge joints that are very close").
3. **Bone graph** (§5.3): bones that touch in the rest pose are linked, weighted by their joint
   dislocation (how far the two bones carry their best shared joint near the contact apart;
   ``edge_weight="eq15"``: the paper's transform-swap weight of Eq. 15,
   ``_core.swap_residuals``); the minimum spanning tree (networkx) is the skeleton, rooted at
   the bone with the most points (``root_choice="centroid"``: the paper's bone whose centre is
   nearest the rest-pose centroid). A touching graph
   that is disconnected (occlusion) is bridged by motion (joint dislocation) plus distance.
   Loops cannot occur: the result is a spanning tree by construction.
4. **Initial joints**: Eq. 20 in closed form (:func:`pointrig.kinematics.solve_joint_positions`)
   with the centroid of the boundary points between a bone and its parent as data term.

The output stage after step 3 (output tree, re-rooting, bone splits) is
:mod:`pointrig.output`.

Conventions (TEAM.md): metres; ``x = R[t, b] @ q + T[t, b]`` (``T_frame_rest``); ``bone_parent``
``-1`` at the root; joint ``b`` is the head of bone ``b``.
"""

from __future__ import annotations

import json
import logging
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from . import _core
from .clustering import (
    _cluster_rounds,
    _compact,
    _kmeans,
    _neighbor_labels,
    kmeans_features,
)
from .config import StructureConfig, pool_size
from .errors import FormatError, InputError
from .io.atomic import write_npz
from .kinematics import joint_trajectories, solve_joint_positions
from .skeleton import Skeleton
from .view import (
    SINGLE_VIEW_MAX_TWO_LAYER,
    in_view,
    two_layer_fraction,
    view_depth_correct,
)

__all__ = [
    "StructureResult",
    "eq15_weights",
    "extract_structure",
    "fit_bones",
    "relative_rotation_angles",
    "relative_rotation_range",
    "removal_cost",
    "skeleton_distance",
    "structure_from_labels",
    "to_skeleton",
    "write_structure_outputs",
]

log = logging.getLogger(__name__)

_BAND_SAMPLE = 128  # points per bone used by the blend-band test (speed only)


# --------------------------------------------------------------------------------------------
# result
# --------------------------------------------------------------------------------------------


@dataclass
class StructureResult:
    """Output of step 2.

    Attributes
    ----------
    labels
        ``(M,)`` int64, bone of each rest point, in ``[0, B)``.
    bone_parent
        ``(B,)`` int64, parent bone, ``-1`` at the root.
    R, T
        ``(F, B, 3, 3)`` rotations and ``(F, B, 3)`` translations (metres), ``T_frame_rest``
        of each bone (Eq. 14 fit of its points).
    joints_rest
        ``(B, 3)`` rest-pose head joint of every bone (root: its centre; others: the Eq. 20
        joint shared with the parent), metres.
    c_tilde
        ``(B, 3)`` boundary centroids between each bone and its parent (root: its centre), m.
    root
        Index of the root bone.
    rest_points
        ``(M, 3)`` the rest points the labels refer to, metres.
    diagnostics
        JSON-able dict: initial k, clusters after clustering, merges done, pruned bones,
        bridges, per-bone RMS residual (m), timings (s).
    view_camera
        ``(3,)`` camera position (metres) used by the single-view depth correction of ``c~``
        (:mod:`pointrig.view`), or ``None`` when the correction is off; step 3 applies the same
        correction to its joint prior.
    view_quantile
        The quantile ``q`` of that correction (0 when off).
    """

    labels: np.ndarray
    bone_parent: np.ndarray
    R: np.ndarray
    T: np.ndarray
    joints_rest: np.ndarray
    c_tilde: np.ndarray
    root: int
    rest_points: np.ndarray
    diagnostics: dict[str, Any] = field(default_factory=dict)
    view_camera: np.ndarray | None = None
    view_quantile: float = 0.0

    @property
    def n_bones(self) -> int:
        """Number of bones ``B``."""
        return int(self.bone_parent.shape[0])

    def save(self, path: str | Path) -> None:
        """Write the result to an ``.npz`` file (atomically)."""
        write_npz(
            path,
            labels=self.labels, bone_parent=self.bone_parent, R=self.R, T=self.T,
            joints_rest=self.joints_rest, c_tilde=self.c_tilde, root=np.int64(self.root),
            rest_points=self.rest_points,
            diagnostics=np.array(json.dumps(self.diagnostics, allow_nan=True)),
            view_camera=(np.full(3, np.nan) if self.view_camera is None
                         else np.asarray(self.view_camera, dtype=float)),
            view_quantile=np.float64(self.view_quantile),
        )

    @classmethod
    def load(cls, path: str | Path) -> StructureResult:
        """Read a result written by :meth:`save`.

        Raises
        ------
        InputError
            If the file is missing.
        FormatError
            If it is not a structure result.
        """
        p = Path(path)
        if not p.exists():
            raise InputError("file not found", p)
        try:
            with np.load(p, allow_pickle=False) as z:
                return cls(
                    labels=z["labels"].astype(np.int64), bone_parent=z["bone_parent"].astype(np.int64),
                    R=z["R"], T=z["T"], joints_rest=z["joints_rest"], c_tilde=z["c_tilde"],
                    root=int(z["root"]), rest_points=z["rest_points"],
                    diagnostics=json.loads(str(z["diagnostics"])),
                    **_load_view(z),
                )
        except (KeyError, ValueError, OSError) as exc:
            raise FormatError(f"{p}: not a pointrig structure result ({exc})") from None


# --------------------------------------------------------------------------------------------
# small public helpers (also used by tests)
# --------------------------------------------------------------------------------------------


def fit_bones(
    rest_points: np.ndarray, points: np.ndarray, labels: np.ndarray, n_bones: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per bone and frame Kabsch fit (Eq. 14) from the rest points of the bone.

    Returns ``R (F, B, 3, 3)``, ``T (F, B, 3)`` and the point count per bone ``(B,)``.
    """
    return _core.cluster_fit(rest_points, points, np.ascontiguousarray(labels, np.int64), n_bones)


def eq15_weights(
    rest_points: np.ndarray, points: np.ndarray, labels: np.ndarray, R: np.ndarray,
    T: np.ndarray, pairs: np.ndarray,
) -> np.ndarray:
    """Edge weights ``e_ij`` of Eq. 15 for bone pairs ``(P, 2)``; returns ``(P,)`` in m^2."""
    pairs = np.ascontiguousarray(np.asarray(pairs, np.int64).reshape(-1, 2))
    if len(pairs) == 0:
        return np.zeros(0)
    halves = _core.swap_residuals(rest_points, points, np.ascontiguousarray(labels, np.int64),
                                  R, T, pairs)
    return halves.sum(axis=1)


def relative_rotation_angles(R: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """Angle (radians) of the relative rotation ``R_i^tT R_j^t`` per pair and frame, ``(P, F)``.

    The rest pose is the reference: every bone's rotation is the identity there, so this is the
    rotation of bone ``j`` against bone ``i`` away from the rest pose.
    """
    pairs = np.asarray(pairs, np.int64).reshape(-1, 2)
    tr = np.einsum("fpij,fpij->pf", R[:, pairs[:, 0]], R[:, pairs[:, 1]])
    return _trace_angle(tr)


def _trace_angle(tr: np.ndarray) -> np.ndarray:
    """Rotation angle (radians) from the trace of a rotation matrix (any shape)."""
    return np.arccos(np.clip(0.5 * (tr - 1.0), -1.0, 1.0))


def relative_rotation_range(R: np.ndarray, pairs: np.ndarray, max_frames: int = 128
                            ) -> np.ndarray:
    """Angle (radians) between the relative rotations of every two frames, ``(P, G*G)``.

    For each pair ``(i, j)`` and frames ``s, t`` the angle of ``rel_s^T rel_t`` with
    ``rel_t = R_i^tT R_j^t``: how far bone ``j`` turns against bone ``i`` between any two frames,
    so any percentile of it measures the *range* of the relative motion and does not depend on
    which frame is the rest pose (replacing every ``R^t`` by ``R^t A_b`` for fixed per-bone
    ``A_b`` leaves it unchanged). ``G = min(F, max_frames)`` evenly spaced frames (memory
    ``P G^2``).
    """
    pairs = np.asarray(pairs, np.int64).reshape(-1, 2)
    F = R.shape[0]
    sel = np.unique(np.linspace(0, F - 1, min(F, max_frames)).round().astype(np.int64))
    Rs = R[sel]
    rel = np.einsum("fpji,fpjk->pfik", Rs[:, pairs[:, 0]], Rs[:, pairs[:, 1]])
    tr = np.einsum("pfij,pgij->pfg", rel, rel)
    return _trace_angle(tr).reshape(len(pairs), -1)


# --------------------------------------------------------------------------------------------
# internals
# --------------------------------------------------------------------------------------------


def _load_view(z: Any) -> dict[str, Any]:
    """``view_camera`` / ``view_quantile`` of a saved result (a camera of NaN: off)."""
    if "view_camera" not in z or not np.all(np.isfinite(z["view_camera"])):
        return {"view_camera": None, "view_quantile": 0.0}
    return {"view_camera": np.asarray(z["view_camera"], dtype=float),
            "view_quantile": float(z["view_quantile"])}


class _Ctx:
    """Per-call constants: data, neighbourhoods, scale."""

    def __init__(self, Q: np.ndarray, Y: np.ndarray, cfg: StructureConfig):
        from scipy.spatial import cKDTree

        self.Q, self.Y, self.cfg = Q, Y, cfg
        self.M, self.F = Q.shape[0], Y.shape[0]
        self.tree = cKDTree(Q)
        kn = min(cfg.vote_neighbors + 1, self.M)
        dist, idx = self.tree.query(Q, k=kn)
        dist, idx = dist[:, 1:], idx[:, 1:]  # drop self
        radius = cfg.vote_radius_ratio * float(np.median(dist[:, -1])) if dist.size else 0.0
        self.nbr = np.where(dist <= radius, idx, -1)  # (M, k) neighbours inside the ball
        # stricter neighbourhood for the bone-graph edges (§5.3): a few point spacings
        spacing = float(np.median(dist[:, 0])) if dist.size else 0.0
        self.nbr_graph = np.where(dist <= cfg.graph_radius_ratio * spacing, idx, -1)
        if cfg.neighbor_stretch > 0 and self.F > 1 and idx.size:
            stretch = _max_frame_distance(Y, idx)
            self.nbr = np.where(stretch <= cfg.neighbor_stretch * radius, self.nbr, -1)
            self.nbr_graph = np.where(stretch <= cfg.neighbor_stretch * dist, self.nbr_graph, -1)
        self.radius = radius
        self.centroid = Q.mean(axis=0)
        self.rms_radius = float(np.sqrt(((Q - self.centroid) ** 2).sum(1).mean()))
        self.size = float(np.linalg.norm(Q.max(0) - Q.min(0)))  # bounding-box diagonal, m

    def fit(self, labels: np.ndarray, B: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return fit_bones(self.Q, self.Y, labels, B)


def _max_frame_distance(Y: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Largest distance over frames between each point and each of its neighbours.

    Parameters
    ----------
    Y
        ``(F, M, 3)`` registered points, metres.
    idx
        ``(M, k)`` neighbour indices into the ``M`` points.

    Returns
    -------
    np.ndarray
        ``(M, k)`` ``max_t |y_m^t - y_idx[m, i]^t|``, metres (one frame at a time: memory
        ``M k``).
    """
    out = np.zeros(idx.shape)
    for y in Y:
        np.maximum(out, np.linalg.norm(y[idx] - y[:, None, :], axis=2), out=out)
    return out


def _touch_pairs(ctx: _Ctx, labels: np.ndarray, min_pairs: int,
                 strict: bool = False) -> dict[tuple[int, int], int]:
    """Bone pairs that touch in the rest pose -> number of straddling neighbour pairs
    (``strict``: only neighbours within ``graph_radius_ratio`` point spacings)."""
    nbr = ctx.nbr_graph if strict else ctx.nbr
    rows = np.repeat(np.arange(ctx.M), nbr.shape[1])
    cols = nbr.ravel()
    ok = cols >= 0
    a, b = labels[rows[ok]], labels[cols[ok]]
    diff = a != b
    lo, hi = np.minimum(a[diff], b[diff]), np.maximum(a[diff], b[diff])
    if lo.size == 0:
        return {}
    keys, cnt = np.unique(np.stack([lo, hi], 1), axis=0, return_counts=True)
    return {(int(i), int(j)): int(c) for (i, j), c in zip(keys, cnt) if c >= min_pairs}


def rotation_noise_var(Q: np.ndarray, labels: np.ndarray, own_res: np.ndarray, B: int,
                       n_frames: int, corr_exponent: float = 0.0) -> np.ndarray:
    """Expected squared angle (rad^2) of the Kabsch rotation noise of each bone, ``(B,)``.

    For ``n`` points with isotropic residual variance ``s^2`` per coordinate, the linearised
    rotation error of Eq. 14 has covariance ``s^2 J^-1`` with ``J = sum |q~|^2 I - q~ q~^T`` (the
    inertia tensor of the centred rest points), so ``E[theta^2] = s^2 tr(J^-1)``. ``s^2`` is the
    bone's own residual per coordinate and frame (6 degrees of freedom removed per frame).
    Large, well-spread bones get ~0; tiny or degenerate (collinear) patches get a large value.
    Registration residuals are spatially correlated (a patch slides as a whole), so only
    ``n^(1 - corr_exponent)`` of the ``n`` points count as independent: the variance is
    multiplied by ``n^corr_exponent`` (0 = independent points, 1 = one rigid drift per bone).
    """
    out = np.full(B, np.inf)
    for b in range(B):
        sel = labels == b
        n = int(sel.sum())
        if n < 3:
            continue
        qc = Q[sel] - Q[sel].mean(0)
        J = (qc ** 2).sum() * np.eye(3) - qc.T @ qc
        ev = np.linalg.eigvalsh(J)
        if ev[0] <= 1e-12 * max(ev[-1], 1e-300):
            continue
        s2 = own_res[sel].sum() / max(n_frames * (3 * n - 6), 1)
        out[b] = s2 * float((1.0 / ev).sum()) * float(n) ** corr_exponent
    return out


def _merge_stat(R: np.ndarray, pairs: list[tuple[int, int]], pct: float,
                noise_var: np.ndarray | None = None, margin: float = 1.0) -> np.ndarray:
    """Relative-rotation statistic (degrees) per pair: the ``pct``-th percentile over every two
    frames of the angle between their relative rotations ``R_i^tT R_j^t``
    (:func:`relative_rotation_range`, whatever frame is the rest pose), minus (in quadrature)
    the same percentile expected from the Kabsch noise of the two bones alone (``margin``
    times it)."""
    if not pairs:
        return np.zeros(0)
    P = np.array(pairs)
    ang = relative_rotation_range(R, P)
    stat = np.percentile(ang, pct, axis=1)
    if noise_var is not None and margin > 0:
        from scipy.special import gammaincinv  # scipy.stats costs 0.3 s to import

        # a relative rotation made of noise only is ~ isotropic Gaussian in 3 axes:
        # its angle is chi(3)-distributed with E[theta^2] = var_i + var_j; chi(3)'s quantile
        # is sqrt(2 P^-1(3/2, p)), P the regularised lower incomplete gamma function
        var = noise_var[P[:, 0]] + noise_var[P[:, 1]]
        q = np.sqrt(2.0 * gammaincinv(1.5, pct / 100.0)) / np.sqrt(3.0)
        noise = margin * q * np.sqrt(var)
        stat = np.sqrt(np.maximum(stat ** 2 - noise ** 2, 0.0))
    return np.degrees(stat)


def _merge_scores(ctx: _Ctx, labels: np.ndarray, R: np.ndarray, T: np.ndarray,
                  pairs: list[tuple[int, int]]) -> tuple[np.ndarray, np.ndarray]:
    """Merge score per bone pair (``< 1`` = one bone) and the angle statistic (degrees).

    ``merge_rule`` "angle": the noise-discounted relative-rotation statistic
    (:func:`_merge_stat`) over ``merge_angle_deg``. "both": the larger of that and the
    displacement score, the same angle (radians) times the reach of the smaller bone (RMS
    distance of its rest points from the pair's contact point), i.e. how far the relative
    rotation moves that bone's points, over ``merge_displacement * size`` (size = rest-pose
    bounding-box diagonal): a pair merges only when both are small.
    """
    cfg = ctx.cfg
    B = int(labels.max()) + 1
    own = _core.cluster_residuals(ctx.Q, ctx.Y, R, T, np.ascontiguousarray(labels[:, None]))[:, 0]
    nv = rotation_noise_var(ctx.Q, labels, own, B, ctx.F, cfg.noise_corr_exponent)
    stat = _merge_stat(R, pairs, cfg.merge_percentile, nv, cfg.noise_margin)
    s_angle = stat / cfg.merge_angle_deg
    if cfg.merge_rule == "angle":
        return s_angle, stat
    # a pair the angle test already keeps apart cannot merge: skip its contact search
    reach = np.zeros(len(pairs))
    for n in np.flatnonzero(s_angle < 1.0):
        i, j = pairs[n]
        _d, c = _closest_pair(ctx, labels, i, j)
        reach[n] = min(float(np.sqrt(((ctx.Q[labels == b] - c) ** 2).sum(1).mean()))
                       for b in (i, j))
    s_disp = np.radians(stat) * reach / (cfg.merge_displacement * ctx.size)
    return np.maximum(s_angle, s_disp), stat


def _merge_batch(ctx: _Ctx, labels: np.ndarray, extra_pairs: list[tuple[int, int]],
                 diag: dict[str, Any]) -> tuple[np.ndarray, bool]:
    """One batch of §5.4 merges; returns (labels, changed).

    If some clusters hold fewer than ``min_cluster_fraction * M`` points, each is absorbed into
    its touching neighbour with the smallest Eq. 15 weight. Otherwise the touching (or
    ``extra_pairs``) bone pairs whose relative-rotation statistic (:func:`_merge_stat`) is below
    ``merge_angle_deg`` are merged, smallest first, at most one merge per bone per batch, so
    that the caller can re-run the clustering rounds (boundaries move) before the next batch.
    """
    cfg = ctx.cfg
    labels, B = _compact(labels)
    if B < 2:
        return labels, False
    R, T, counts = ctx.fit(labels, B)
    pairs = sorted(set(_touch_pairs(ctx, labels, cfg.touch_min_pairs))
                   | {(min(a, b), max(a, b)) for a, b in extra_pairs})
    target = np.arange(B)
    small = np.flatnonzero(counts < cfg.min_cluster_fraction * ctx.M)
    if small.size:
        for s in small[np.argsort(counts[small])]:
            s = int(s)
            nbrs = [j if i == s else i for i, j in pairs if s in (i, j)]
            nbrs = [j for j in nbrs if j not in small] or [j for j in range(B)
                                                         if j != s and j not in small]
            if not nbrs:
                continue
            w = eq15_weights(ctx.Q, ctx.Y, labels, R, T, np.array([(s, j) for j in nbrs]))
            target[s] = int(nbrs[int(np.argmin(w))])
            diag.setdefault("absorbed", []).append(int(counts[s]))
    elif pairs:
        score, stat = _merge_scores(ctx, labels, R, T, pairs)
        used: set[int] = set()
        for idx in np.argsort(score, kind="stable"):
            if score[idx] >= 1.0:
                break
            i, j = pairs[idx]
            if i in used or j in used:
                continue
            used |= {i, j}
            target[j] = i
            diag.setdefault("merges_deg", []).append(round(float(stat[idx]), 3))
    if np.array_equal(target, np.arange(B)):
        return labels, False
    return target[labels], True


def _closest_pair(ctx: _Ctx, labels: np.ndarray, i: int, j: int) -> tuple[float, np.ndarray]:
    from scipy.spatial import cKDTree

    Pi, Pj = ctx.Q[labels == i], ctx.Q[labels == j]
    d, idx = cKDTree(Pj).query(Pi, k=1)
    a = int(np.argmin(d))
    return float(d[a]), 0.5 * (Pi[a] + Pj[idx[a]])


def _dislocation(R: np.ndarray, T: np.ndarray, i: int, j: int, c0: np.ndarray,
                 prior: float) -> float:
    """Joint dislocation of a candidate bridge, metres.

    Solves Eq. 20 for the pair with a weak pull to the gap midpoint ``c0``:
    ``min_c sum_t |A_t c + b_t|^2 + prior * (sum_t |A_t|_F^2 / 3) |c - c0|^2`` with
    ``A_t = R_i^t - R_j^t``, ``b_t = T_i^t - T_j^t``, and returns the RMS over frames of the
    residual dislocation ``|A_t c + b_t|`` at that joint: ~0 for two bones that really share a
    joint (wherever it lies in the occluded gap), large for bones moving independently.
    """
    A = R[:, i] - R[:, j]
    b = T[:, i] - T[:, j]
    F = R.shape[0]
    lam = prior * F * float((A ** 2).sum(axis=(1, 2)).mean()) / 3.0 + 1e-12
    lhs = np.einsum("fji,fjk->ik", A, A) + lam * np.eye(3)
    rhs = lam * c0 - np.einsum("fji,fj->i", A, b)
    try:
        c = np.linalg.solve(lhs, rhs)
    except np.linalg.LinAlgError:
        c = c0
    d = np.einsum("fab,b->fa", A, c) + b
    return float(np.sqrt((d ** 2).sum(1).mean()))


def _edge_dislocations(ctx: _Ctx, labels: np.ndarray, R: np.ndarray, T: np.ndarray,
                      pairs: list[tuple[int, int]]) -> np.ndarray:
    """Bone-graph weights ``edge_weight="dislocation"`` of touching bone pairs, ``(P,)`` metres.

    Each pair's :func:`_dislocation` (RMS over frames of how far the two bones carry their best
    shared joint apart), with the joint pulled towards the centroid ``c0`` of the pair's contact
    band (points of either bone with a rest-pose neighbour in the other; the closest pair's
    midpoint if the band is empty) with relative weight ``edge_joint_prior``. Bones that rotate
    about a common point near where they touch score ~0; a limb lying against a part it does
    not hang from scores its swing at the contact.
    """
    nl = _neighbor_labels(ctx, labels)
    out = np.empty(len(pairs))
    for n, (i, j) in enumerate(pairs):
        band = _contact_band(labels, nl, i, j)
        c0 = ctx.Q[band].mean(0) if band.any() else _closest_pair(ctx, labels, i, j)[1]
        out[n] = _dislocation(R, T, i, j, c0, ctx.cfg.edge_joint_prior)
    return out


def _contact_band(labels: np.ndarray, nl: np.ndarray, i: int, j: int) -> np.ndarray:
    """``(M,)`` mask of the points of bones ``i`` and ``j`` with a ball neighbour in the other
    (``nl`` from :func:`_neighbor_labels`)."""
    return ((labels == i) & (nl == j).any(1)) | ((labels == j) & (nl == i).any(1))


def _build_tree(ctx: _Ctx, labels: np.ndarray, B: int, R: np.ndarray, T: np.ndarray,
                diag: dict[str, Any]) -> tuple[np.ndarray, int, set[tuple[int, int]]]:
    """MST of the touching graph (weights: :func:`_edge_dislocations`, or Eq. 15 with
    ``edge_weight="eq15"``), bridged by motion + distance; rooted at
    the bone whose centre is nearest the rest-pose centroid (§5.3), or at the bone with the
    most points (``root_choice="largest"``). Returns (parent, root, bridges)."""
    import networkx as nx

    cfg = ctx.cfg
    touch = sorted(_touch_pairs(ctx, labels, cfg.touch_min_pairs, strict=True))
    G = nx.Graph()
    G.add_nodes_from(range(B))
    if touch:
        if cfg.edge_weight == "dislocation":
            w = _edge_dislocations(ctx, labels, R, T, touch)
        else:
            w = eq15_weights(ctx.Q, ctx.Y, labels, R, T, np.array(touch))
        for (i, j), wij in zip(touch, w):
            G.add_edge(i, j, weight=float(wij))
    forest = nx.minimum_spanning_tree(G, weight="weight", algorithm="kruskal")
    comps = [sorted(c) for c in nx.connected_components(forest)]
    bridges: set[tuple[int, int]] = set()
    if len(comps) > 1:
        comp_of = np.empty(B, np.int64)
        for ci, c in enumerate(comps):
            comp_of[c] = ci
        H = nx.Graph()
        H.add_nodes_from(range(len(comps)))
        for i in range(B):
            for j in range(i + 1, B):
                ci, cj = int(comp_of[i]), int(comp_of[j])
                if ci == cj:
                    continue
                gap, mid = _closest_pair(ctx, labels, i, j)
                cost = _dislocation(R, T, i, j, mid, cfg.bridge_joint_prior) + cfg.bridge_gap_weight * gap
                key = (min(ci, cj), max(ci, cj))
                if not H.has_edge(*key) or cost < H.edges[key]["weight"]:
                    H.add_edge(*key, weight=cost, bones=(i, j))
        for a, b, data in nx.minimum_spanning_edges(H, weight="weight", algorithm="kruskal"):
            i, j = data["bones"]
            forest.add_edge(i, j, weight=data["weight"])
            bridges.add((min(i, j), max(i, j)))
        diag["bridges"] = diag.get("bridges", 0) + len(bridges)
    if cfg.root_choice == "largest":
        root = int(np.argmax(np.bincount(labels, minlength=B)))
    else:
        centres = np.array([ctx.Q[labels == b].mean(0) for b in range(B)])
        root = int(np.argmin(((centres - ctx.centroid) ** 2).sum(1)))
    parent = np.full(B, -1, np.int64)
    for u, v in nx.bfs_edges(forest, root):
        parent[v] = u
    assert nx.is_tree(forest)  # a spanning tree has no loops (§5.4 criterion 2)
    return parent, root, bridges


def _boundary_centroids(ctx: _Ctx, labels: np.ndarray, parent: np.ndarray,
                        view_camera: np.ndarray | None = None) -> np.ndarray:
    """``c~`` (Eq. 20): centroid of the points of bone and parent that neighbour each other
    (moved back along the ray from ``view_camera`` by :func:`pointrig.view.view_depth_correct`
    when given); for bridged bones (no shared boundary) the midpoint of the closest pair; root:
    its centre."""
    B = len(parent)
    out = np.empty((B, 3))
    nl = _neighbor_labels(ctx, labels)
    for k in range(B):
        p = int(parent[k])
        if p < 0:
            out[k] = ctx.Q[labels == k].mean(0)
            continue
        sel = _contact_band(labels, nl, k, p)
        if sel.any():
            out[k] = ctx.Q[sel].mean(0)
            if view_camera is not None:
                out[k] = view_depth_correct(ctx.Q[sel], None, out[k], view_camera,
                                            ctx.cfg.view_depth_quantile)
        else:
            out[k] = _closest_pair(ctx, labels, k, p)[1]
    return out


def _blend_fit(q: np.ndarray, y: np.ndarray, R: np.ndarray, T: np.ndarray, a: int, b: int
               ) -> tuple[float, np.ndarray]:
    """Per-point LBS blend of bones ``a`` and ``b``: ``y ~ (1-w) x_a + w x_b`` with one
    ``w in [0, 1]`` per point for all frames (closed form). Returns (residual m^2, w (n,))."""
    xa = q[None] @ R[:, a].transpose(0, 2, 1) + T[:, a, None]
    xb = q[None] @ R[:, b].transpose(0, 2, 1) + T[:, b, None]
    d, r = xb - xa, y - xa
    den = (d * d).sum((0, 2))
    w = np.clip((r * d).sum((0, 2)) / np.maximum(den, 1e-300), 0.0, 1.0)
    res = float(((r - w[None, :, None] * d) ** 2).sum())
    return res, w


def _blend_all_pairs(q: np.ndarray, y: np.ndarray, R: np.ndarray, T: np.ndarray,
                     nb: list[int]) -> list[tuple[int, int, float, np.ndarray]]:
    """:func:`_blend_fit` for every pair of the bones ``nb`` at once.

    Each bone's motion of the points ``q (n, 3)`` is computed once, then every pair's closed
    form follows from per-point Gram terms ``<x_k, x_l>``, ``<y, x_k>``, ``<y, y>`` summed over
    frames. Returns ``(ia, ib, residual m^2, w (n,))`` for ``ia < ib`` (indices into ``nb``).
    """
    n = q.shape[0]
    X = q[None, None] @ R[:, nb].swapaxes(-1, -2) + T[:, nb, None]  # (F, K', n, 3)
    X2 = np.ascontiguousarray(X.transpose(2, 1, 0, 3)).reshape(n, len(nb), -1)
    y2 = np.ascontiguousarray(y.transpose(1, 0, 2)).reshape(n, -1, 1)
    G = (X2 @ X2.transpose(0, 2, 1)).transpose(1, 2, 0)  # (K', K', n)
    yx = (X2 @ y2)[..., 0].T  # (K', n)
    yy = (y2[..., 0] ** 2).sum(1)  # (n,)
    out = []
    for ia in range(len(nb)):
        for ib in range(ia + 1, len(nb)):
            den = G[ib, ib] - 2.0 * G[ia, ib] + G[ia, ia]  # |x_b - x_a|^2
            num = yx[ib] - yx[ia] - G[ia, ib] + G[ia, ia]  # <y - x_a, x_b - x_a>
            w = np.clip(num / np.maximum(den, 1e-300), 0.0, 1.0)
            rr = yy - 2.0 * yx[ia] + G[ia, ia]  # |y - x_a|^2
            res = float(np.maximum(rr - 2.0 * w * num + w * w * den, 0.0).sum())
            out.append((ia, ib, res, w))
    return out


def removal_cost(Q: np.ndarray, Y: np.ndarray, R: np.ndarray, T: np.ndarray,
                 labels: np.ndarray, b: int, others: list[int]) -> tuple[float, np.ndarray]:
    """How visibly bone ``b`` moves against the bones ``others``, metres.

    Each point of ``b`` is given to whichever of ``others`` fits it best (Eq. 14 residual
    summed over frames, their transforms held fixed). Returns the RMS over those points and
    the frames of the extra misfit against ``b``'s own fit,
    ``sqrt(max(mean_m min_k r_mk - mean_m r_mb, 0) / F)``, and the chosen bone per point
    ``(n_b,)``.

    Parameters
    ----------
    Q, Y
        ``(M, 3)`` rest points and ``(F, M, 3)`` registered points, metres.
    R, T
        ``(F, B, 3, 3)`` and ``(F, B, 3)`` per-bone transforms (``T_frame_rest``).
    labels
        ``(M,)`` bone per point.
    b, others
        The bone and its candidate replacements (non-empty).
    """
    if len(others) == 0:
        raise ValueError("removal_cost needs at least one other bone")
    sel = np.flatnonzero(labels == b)
    cand = np.empty((len(sel), len(others) + 1), np.int64)
    cand[:, 0] = b
    cand[:, 1:] = others
    res = _core.cluster_residuals(Q[sel], np.ascontiguousarray(Y[:, sel]), R, T, cand)
    own = float(res[:, 0].mean()) if len(sel) else 0.0
    best = float(res[:, 1:].min(1).mean()) if len(sel) else 0.0
    cost = float(np.sqrt(max(best - own, 0.0) / max(Y.shape[0], 1)))
    return cost, np.asarray(others, np.int64)[res[:, 1:].argmin(1)]


def _prune(ctx: _Ctx, labels: np.ndarray, parent: np.ndarray, joints: np.ndarray,
           R: np.ndarray, T: np.ndarray, counts: np.ndarray, diag: dict[str, Any]
           ) -> np.ndarray | None:
    """One pruning step of §5.4 on the tree; returns new labels or ``None`` if nothing to do.

    ``R, T, counts`` are the caller's :func:`fit_bones` of ``labels`` (one fit serves every
    test below).

    * spurious leaf: a leaf whose parent has another child and which holds fewer than
      ``leaf_min_fraction * M`` points -> merged into its parent;
    * blend band: see ``StructureConfig.band_ratio`` (pairs among its tree and touching
      neighbours) -> its points go to the nearer side;
    * close joints: a non-root bone with children whose head joint and every child joint lie
      within ``short_bone_ratio`` times the bone's own extent (95th percentile distance of its
      points from their centroid) -> its joints are merged: the bone is removed and
      each of its points goes to the parent or a child, whichever fits best (Eq. 14 residual);
    * invisible bone: a non-root bone whose :func:`removal_cost` against its tree neighbours
      is below ``invisible_bone_fraction`` times the size -> each point goes to the better
      neighbour (smallest cost first);
    * over the cap: while there are more than ``max_joints > 0`` bones, the bone whose
      removal adds the least misfit in all (its points times the square of its
      :func:`removal_cost`; the root included, against its children) goes the same way,
      whatever its cost.
    """
    cfg = ctx.cfg
    B = len(parent)
    children = [np.flatnonzero(parent == b) for b in range(B)]
    # spurious leaves (smallest first)
    leaves = [b for b in range(B) if parent[b] >= 0 and len(children[b]) == 0
              and len(children[parent[b]]) >= 2 and counts[b] < cfg.leaf_min_fraction * ctx.M]
    if leaves:
        b = min(leaves, key=lambda x: counts[x])
        diag.setdefault("pruned_leaves", []).append(int(counts[b]))
        return np.where(labels == b, parent[b], labels)
    # blend bands: bones explained by per-point blending of two tree neighbours
    bands = []
    touching = _touch_pairs(ctx, labels, cfg.touch_min_pairs)
    for b in range(B):
        nb = {int(c) for c in children[b]} | ({int(parent[b])} if parent[b] >= 0 else set())
        nb |= {j if i == b else i for i, j in touching if b in (i, j)}
        nb = sorted(nb)
        if len(nb) < 2 or cfg.band_ratio <= 0:
            continue
        sel = np.flatnonzero(labels == b)
        sub = sel[:: max(1, len(sel) // _BAND_SAMPLE)]  # deterministic subsample, for speed
        q, y = ctx.Q[sub], ctx.Y[:, sub]
        n = len(sub)
        own = ((y - q[None] @ R[:, b].transpose(0, 2, 1) - T[:, b, None]) ** 2).sum()
        for ia, ib, res, w in _blend_all_pairs(q, y, R, T, nb):
            # compare residual variances per degree of freedom: the rigid fit spends 6
            # per frame, the blend one per point
            ratio = (res / max(ctx.F * 3 * n - n, 1)) / max(
                own / max(ctx.F * (3 * n - 6), 1), 1e-300)
            if ratio <= cfg.band_ratio:
                bands.append((ratio, b, nb[ia], nb[ib], sel, w))
    if bands:
        ratio, b, a, c, sel, _w = min(bands, key=lambda x: x[0])
        _res, w = _blend_fit(ctx.Q[sel], ctx.Y[:, sel], R, T, a, c)
        new = labels.copy()
        new[sel] = np.where(w < 0.5, a, c)
        diag.setdefault("bands_removed", []).append(round(float(ratio), 4))
        return new
    short = []
    for b in range(B):
        if parent[b] < 0 or len(children[b]) == 0:
            continue
        qb = ctx.Q[labels == b]
        extent = float(np.percentile(np.linalg.norm(qb - qb.mean(0), axis=1), 95))
        span = max(float(np.linalg.norm(joints[c] - joints[b])) for c in children[b])
        if span < cfg.short_bone_ratio * extent:
            short.append((span / max(extent, 1e-300), b))
    if short:
        span, b = min(short)
        _cost, to = removal_cost(ctx.Q, ctx.Y, R, T, labels, b,
                                 [int(parent[b])] + [int(c) for c in children[b]])
        new = labels.copy()
        new[labels == b] = to
        diag.setdefault("short_bones_removed", []).append(round(span, 4))
        return new
    # over the cap (max_joints): the bone whose removal adds the least misfit in all goes,
    # whatever its cost, the root too
    over = 0 < cfg.max_joints < B
    invisible = cfg.invisible_bone_fraction * ctx.size  # RMS cost below which a bone goes
    if cfg.invisible_bone_fraction > 0 or over:
        best: tuple[float, float, int, np.ndarray] | None = None
        for b in range(B):
            others = ([int(parent[b])] if parent[b] >= 0 else []) + [int(c)
                                                                     for c in children[b]]
            if (parent[b] < 0 and not over) or not others:
                continue
            cost, to = removal_cost(ctx.Q, ctx.Y, R, T, labels, b, others)
            if over:
                key = float(counts[b]) * cost ** 2  # the bone's extra squared misfit, summed
            elif cost < invisible:
                key = cost
            else:
                continue
            if best is None or key < best[0]:
                best = (key, cost, b, to)
        if best is not None:
            _key, cost, b, to = best
            new = labels.copy()
            new[labels == b] = to
            what = "invisible_bones_removed" if cost < invisible else "capped_bones_removed"
            diag.setdefault(what, []).append(round(cost / ctx.size, 5))
            return new
    return None


# --------------------------------------------------------------------------------------------
# entry point
# --------------------------------------------------------------------------------------------


def _check_inputs(rest_points: np.ndarray, points: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """``Q (M, 3)`` and ``Y (F, M, 3)`` as contiguous float64, checked (``InputError``)."""
    Q = np.ascontiguousarray(rest_points, dtype=np.float64)
    Y = np.ascontiguousarray(points, dtype=np.float64)
    if Q.ndim != 2 or Q.shape[1] != 3 or Q.shape[0] == 0:
        raise InputError(f"rest_points must be (M, 3), got {Q.shape}")
    if Y.ndim != 3 or Y.shape[1:] != Q.shape or Y.shape[0] == 0:
        raise InputError(f"points must be (F, {Q.shape[0]}, 3), got {Y.shape}")
    if not (np.isfinite(Q).all() and np.isfinite(Y).all()):
        raise InputError("rest_points / points contain NaN or inf")
    return Q, Y


def extract_structure(rest_points: np.ndarray, points: np.ndarray,
                      config: StructureConfig | None = None) -> StructureResult:
    """Skeletal structure from a registered sequence (§5).

    With ``config.ensemble_seeds = n > 1`` (our deviation, docs/structure.md) the whole step
    runs from the k-means seeds ``seed, ..., seed + n - 1`` and returns the *medoid* run: the
    one whose joint trajectories are closest to the other runs' (see
    :func:`skeleton_distance`). A single run's bone boundaries depend on the k-means start,
    so two nearly equal registrations can give skeletons that differ by several joints; the
    medoid is the typical one. Runs share the neighbourhoods (``_Ctx``), so the cost is about
    ``n`` times the clustering and refinement; they run on ``config.workers`` threads (the
    same result as one after the other).

    Parameters
    ----------
    rest_points
        ``(M, 3)`` rest-pose points ``q_m``, metres.
    points
        ``(F, M, 3)`` registered points ``y_m^t`` (point ``m`` corresponds across frames), m.
    config
        :class:`~pointrig.config.StructureConfig` (defaults if ``None``).

    Returns
    -------
    StructureResult
        The chosen run; ``diagnostics["ensemble"]`` records every run's seed and bone count,
        the chosen seed and each chosen joint's support (fraction of the other runs with a
        joint within ``ensemble_radius`` of the size).

    Raises
    ------
    InputError
        On wrong shapes or non-finite values.
    """
    cfg = config or StructureConfig()
    Q, Y = _check_inputs(rest_points, points)
    t0 = time.perf_counter()
    ctx = _Ctx(Q, Y, cfg)
    view_diag: dict[str, Any] = {}
    view_camera = _view_camera(Q, cfg, view_diag)
    n = cfg.ensemble_seeds
    features = kmeans_features(Q, Y, cfg)  # the same for every seed
    # the seeds' runs share only read-only inputs: side by side (the native calls release the
    # GIL), each with the same arithmetic as alone
    with ThreadPoolExecutor(max_workers=pool_size(cfg.workers, n)) as pool:
        runs = list(pool.map(lambda i: _extract_once(ctx, features, cfg.seed + i, view_camera,
                                                     view_diag), range(n)))
    if n == 1:
        best = runs[0]
    else:
        traj = [joint_trajectories(r.joints_rest, r.R, r.T, r.bone_parent) for r in runs]
        cap = cfg.ensemble_radius * ctx.size
        # (Ja, Jb) mean-over-frames joint distances of every ordered pair of runs, once
        dist = {(a, b): _joint_distances(traj[a], traj[b])
                for a in range(n) for b in range(a + 1, n)}
        dist.update({(b, a): d.T for (a, b), d in list(dist.items())})
        D = np.zeros((n, n))
        for (a, b), d in dist.items():
            D[a, b] = _capped_distance(d, cap)
        m = int(np.argmin(D.sum(axis=1)))  # ties: the lowest seed
        best = runs[m]
        # support of each chosen joint: fraction of the other runs with a joint within cap
        support = np.mean([dist[m, b].min(axis=1) < cap for b in range(n) if b != m], axis=0)
        best.diagnostics["ensemble"] = {
            "seeds": [cfg.seed + i for i in range(n)],
            "n_bones": [r.n_bones for r in runs],
            "chosen_seed": cfg.seed + m,
            "mean_distance_m": [round(float(v) / (n - 1), 5) for v in D.sum(axis=1)],
            "joint_support": [round(float(v), 3) for v in support],
        }
        log.info("structure: seeds %s -> %s bones, medoid seed %d", best.diagnostics[
            "ensemble"]["seeds"], [r.n_bones for r in runs], cfg.seed + m)
    best.diagnostics["time_total_s"] = round(time.perf_counter() - t0, 4)
    return best


def _joint_distances(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``(Ja, Jb)`` mean over frames of the distance between every joint of ``A (F, Ja, 3)``
    and every joint of ``B (F, Jb, 3)``, metres."""
    return np.linalg.norm(A[:, :, None, :] - B[:, None, :, :], axis=3).mean(axis=0)


def _capped_distance(d: np.ndarray, cap: float) -> float:
    """:func:`skeleton_distance` from the ``(Ja, Jb)`` matrix of :func:`_joint_distances`."""
    return float((np.minimum(d.min(axis=1), cap).sum() + np.minimum(d.min(axis=0), cap).sum())
                 / (d.shape[0] + d.shape[1]))


def skeleton_distance(A: np.ndarray, B: np.ndarray, cap: float) -> float:
    """Symmetric distance between two skeletons' joint trajectories, metres.

    Each joint's distance to the other skeleton is the mean over frames of its distance to
    the nearest joint there (the nearest by that mean), capped at ``cap``; the result is the
    mean over the joints of both skeletons. A joint that the other skeleton lacks costs
    ``cap``, so the distance counts missing and extra joints as well as displaced ones.

    Parameters
    ----------
    A, B
        ``(F, Ja, 3)`` and ``(F, Jb, 3)`` joint positions per frame, metres (same frames).
    cap
        Largest cost of one joint, metres.
    """
    return _capped_distance(_joint_distances(A, B), cap)


def _extract_once(ctx: _Ctx, features: np.ndarray, seed: int,
                  view_camera: np.ndarray | None, view_diag: dict[str, Any]) -> StructureResult:
    """One run of step 2 from the k-means seed ``seed`` on the k-means ``features`` (``(M,
    d)``, :func:`kmeans_features`); ``view_camera`` and its diagnostics ``view_diag`` come from
    :func:`_view_camera`."""
    cfg = ctx.cfg
    t0 = time.perf_counter()
    M = ctx.M
    k = int(min(cfg.n_clusters, M))
    diag: dict[str, Any] = {"n_init": k, "seed": seed, **view_diag}
    rng = np.random.default_rng(seed)
    labels = _kmeans(features, k, cfg.kmeans_iterations, rng)
    labels = _cluster_rounds(ctx, labels, cfg.cluster_rounds)
    diag["n_after_clustering"] = int(labels.max() + 1)
    diag["time_clustering_s"] = round(time.perf_counter() - t0, 4)

    tree_pairs: list[tuple[int, int]] = []
    passes = 0
    # a cap on the bones (max_joints) may need one pass per bone removed beyond the usual ones
    max_passes = cfg.refine_passes + (k if cfg.max_joints > 0 else 0)
    for passes in range(1, max_passes + 1):
        for _batch in range(ctx.M):
            labels, merged = _merge_batch(ctx, labels, tree_pairs, diag)
            tree_pairs = []
            if not merged:
                break
            labels = _cluster_rounds(ctx, labels, cfg.post_merge_rounds)
        labels, B = _compact(labels)
        R, T, counts = ctx.fit(labels, B)
        parent, root, bridges = _build_tree(ctx, labels, B, R, T, diag)
        # motion test also along bridge edges (bones that do not touch)
        if bridges and (_merge_scores(ctx, labels, R, T, sorted(bridges))[0] < 1.0).any():
            tree_pairs = sorted(bridges)
            continue
        tree_pairs = []
        c_tilde = _boundary_centroids(ctx, labels, parent)
        joints = solve_joint_positions(R, T, parent, c_tilde, cfg.eta)
        new = _prune(ctx, labels, parent, joints, R, T, counts, diag)
        if new is None:
            break
        labels = _cluster_rounds(ctx, new, cfg.post_merge_rounds)
    else:
        log.warning("structure refinement stopped after %d passes", cfg.refine_passes)
        labels, B = _compact(labels)
        R, T, counts = ctx.fit(labels, B)
        parent, root, _b = _build_tree(ctx, labels, B, R, T, diag)
        c_tilde = _boundary_centroids(ctx, labels, parent)
        joints = solve_joint_positions(R, T, parent, c_tilde, cfg.eta)

    diag["refine_passes"] = passes
    res = _finish(ctx, labels, R, T, counts, parent, root, c_tilde, joints, view_camera, diag)
    diag["time_run_s"] = round(time.perf_counter() - t0, 4)
    log.info("structure (seed %d): k=%d -> %d clusters -> %d bones in %.2fs", seed, k,
             diag["n_after_clustering"], B, diag["time_run_s"])
    return res


def _finish(ctx: _Ctx, labels: np.ndarray, R: np.ndarray, T: np.ndarray, counts: np.ndarray,
            parent: np.ndarray, root: int, c_tilde: np.ndarray | None,
            joints: np.ndarray | None, view_camera: np.ndarray | None,
            diag: dict[str, Any]) -> StructureResult:
    """The final skeleton of a segmentation with its tree: the single-view correction of
    ``c~``, the Eq. 20 joints (``c_tilde`` / ``joints`` uncorrected, or ``None`` to compute
    them), the root joint and the per-bone residuals."""
    cfg, Q = ctx.cfg, ctx.Q
    B = len(parent)
    if view_camera is not None or c_tilde is None or joints is None:
        # single-view depth correction of the final c~ only: the refinement's pruning tests
        # keep the uncorrected (surface) joints, so the bone count does not depend on it.
        # The root joint is not corrected here: the root part can reach far back in depth (a
        # torso seen side-on), so its depths overshoot the axis near the joint. The output
        # corrects it on the points near it (pointrig.output.output_tree)
        c_tilde = _boundary_centroids(ctx, labels, parent, view_camera)
        joints = solve_joint_positions(R, T, parent, c_tilde, cfg.eta)
    joints = joints.copy()
    joints[root] = root_joint_position(Q, labels, root, joints, parent, cfg.root_end_alignment)
    res_own = _core.cluster_residuals(Q, ctx.Y, R, T, np.ascontiguousarray(labels[:, None]))[:, 0]
    rms = [float(np.sqrt(res_own[labels == b].mean() / ctx.F)) for b in range(B)]
    diag.update({
        "n_bones": int(B), "rms_residual_m": rms,
        "counts": [int(c) for c in counts], "rms_radius_m": ctx.rms_radius,
    })
    return StructureResult(labels=labels, bone_parent=parent, R=R, T=T, joints_rest=joints,
                           c_tilde=c_tilde, root=root, rest_points=Q, diagnostics=diag,
                           view_camera=view_camera,
                           view_quantile=cfg.view_depth_quantile if view_camera is not None
                           else 0.0)


def structure_from_labels(rest_points: np.ndarray, points: np.ndarray, labels: np.ndarray,
                          config: StructureConfig | None = None,
                          bone_parent: np.ndarray | None = None) -> StructureResult:
    """Step 2's bone tree, motions and joints for a given segmentation of the rest points.

    No clustering and no refinement: the bones are ``labels`` as given. Each bone's motion is
    the Kabsch fit to its registered points, the tree is the minimum spanning tree of the
    touching graph (§5.3, :class:`~pointrig.config.StructureConfig` ``edge_weight``), or
    ``bone_parent`` when given, and the joints come from Eq. 20 with the single-view
    correction, as at the end of :func:`extract_structure`. Called with a result's own labels
    (and tree) it reproduces that result. Uses: a segmentation from elsewhere (a painted one,
    one from exact motion in a benchmark).

    Parameters
    ----------
    rest_points
        ``(M, 3)`` rest points, metres.
    points
        ``(F, M, 3)`` registered points, metres.
    labels
        ``(M,)`` integer bone of each rest point, every bone of ``0 .. B-1`` used.
    config
        :class:`~pointrig.config.StructureConfig` (defaults if ``None``).
    bone_parent
        ``(B,)`` parent of each bone (-1 at the one root) to use instead of the spanning tree.

    Raises
    ------
    InputError
        On wrong shapes, non-finite values, labels that skip a bone or a parent array that is
        not one tree over the bones.
    """
    import networkx as nx

    cfg = config or StructureConfig()
    Q, Y = _check_inputs(rest_points, points)
    lab = np.asarray(labels)
    if lab.shape != (len(Q),) or not np.issubdtype(lab.dtype, np.integer) or lab.min() < 0:
        raise InputError(f"labels must be ({len(Q)},) non-negative integers, got {lab.shape} "
                         f"{lab.dtype}")
    B = int(lab.max()) + 1
    if len(np.unique(lab)) != B:
        raise InputError(f"labels must use every bone 0..{B - 1}")
    lab = lab.astype(np.int64)
    ctx = _Ctx(Q, Y, cfg)
    view_diag: dict[str, Any] = {}
    view_camera = _view_camera(Q, cfg, view_diag)
    diag: dict[str, Any] = {"labels_given": True, **view_diag}
    R, T, counts = ctx.fit(lab, B)
    if bone_parent is None:
        parent, root, _bridges = _build_tree(ctx, lab, B, R, T, diag)
    else:
        parent = np.asarray(bone_parent, dtype=np.int64)
        roots = np.flatnonzero(parent < 0)
        G = nx.Graph()
        G.add_nodes_from(range(B))
        if parent.shape == (B,) and len(roots) == 1 and np.all(parent < B):
            G.add_edges_from((int(b), int(p)) for b, p in enumerate(parent) if p >= 0)
        if parent.shape != (B,) or len(roots) != 1 or not nx.is_tree(G):
            raise InputError(f"bone_parent must be ({B},) with one root (-1) forming a tree")
        root = int(roots[0])
    return _finish(ctx, lab, R, T, counts, parent, root, None, None, view_camera, diag)


def _view_camera(Q: np.ndarray, cfg: StructureConfig, diag: dict[str, Any]) -> np.ndarray | None:
    """The camera position if the single-view depth correction applies, else ``None``."""
    if cfg.view_depth_quantile <= 0 or cfg.single_view == "no":
        return None
    cam = np.asarray(cfg.camera_position, dtype=float)
    if not in_view(Q, cam):
        log.warning("single-view depth correction skipped: the rest points surround "
                    "camera_position %s (clouds in a world frame? set structure.camera_position)",
                    tuple(cam))
        diag["view_depth"] = "skipped: rest points not in front of camera_position"
        return None
    if cfg.single_view == "yes":
        return cam
    frac = two_layer_fraction(Q, cam)
    diag["two_layer_fraction"] = round(frac, 4)
    return cam if frac <= SINGLE_VIEW_MAX_TWO_LAYER else None


def root_joint_position(rest_points: np.ndarray, labels: np.ndarray, root: int,
                        joints: np.ndarray, bone_parent: np.ndarray,
                        min_alignment: float) -> np.ndarray:
    """Rest position ``(3,)`` (metres) of the root joint.

    The paper puts the root joint at the root cluster's centre (§5.3). When all of the root
    part's children attach on one side of it (the mean of the unit vectors from its centre to
    its child joints has length >= ``min_alignment``, up to 1e-6; 1 = a single child, the end
    of a chain), as for an arm hanging from the shoulder or a robot arm from its base, the
    root joint is put at the part's opposite end instead: the centre moved along that
    direction to the 3rd percentile of the part's extent. Otherwise (children on several sides,
    as a pelvis or torso) the centre is kept. ``min_alignment <= 0`` always keeps the paper's
    centre.
    """
    pts = rest_points[labels == root]
    centre = pts.mean(axis=0)
    kids = np.flatnonzero(np.asarray(bone_parent) == root)
    if min_alignment <= 0 or len(kids) == 0 or len(pts) < 3:
        return centre
    dirs = joints[kids] - centre
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True) + 1e-12
    mean = dirs.mean(axis=0)
    if np.linalg.norm(mean) < min_alignment - 1e-6:
        return centre
    axis = mean / np.linalg.norm(mean)
    return centre + axis * float(np.quantile((pts - centre) @ axis, 0.03))


def to_skeleton(result: StructureResult) -> Skeleton:
    """The :class:`~pointrig.skeleton.Skeleton` of a structure result.

    Joints are the bone heads (joint ``b`` of bone ``b``, parents = ``bone_parent``), with
    per-frame positions from :func:`pointrig.kinematics.joint_trajectories`. Skeleton bones are
    the segments parent joint -> child joint (one per non-root bone, named ``b<p>_<k>``);
    ``bone_rotations`` / ``bone_translations`` are ``R``, ``T`` indexed by *motion bone* (= joint)
    index, and ``labels`` / ``rest_points`` are attached.
    """
    parent = np.asarray(result.bone_parent, np.int64)
    jp = joint_trajectories(result.joints_rest, result.R, result.T, parent)
    kids = np.flatnonzero(parent >= 0)
    return Skeleton(
        joint_names=[f"j{b}" for b in range(len(parent))],
        parents=parent,
        rest_positions=result.joints_rest,
        joint_positions=jp,
        bone_heads=parent[kids],
        bone_tails=kids,
        bone_rotations=result.R,
        bone_translations=result.T,
        rest_points=result.rest_points,
        labels=result.labels,
        bone_names=[f"b{parent[k]}_{k}" for k in kids],
    )


def write_structure_outputs(result: StructureResult, out_dir: str | Path,
                            source: dict[str, Any] | None = None,
                            params: dict[str, Any] | None = None) -> dict[str, Path]:
    """Write ``skeleton.json`` (scorable alone) and ``structure.npz`` into ``out_dir``."""
    out = Path(out_dir)
    paths = {"skeleton": out / "skeleton.json", "structure": out / "structure.npz"}
    to_skeleton(result).save_json(paths["skeleton"], source=source, params=params)
    result.save(paths["structure"])
    return paths
