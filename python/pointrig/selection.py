"""Joint selection: a joint stays only where the raw frames need it (BIC on the observed points).

Steps 2 and 3 propose a bone tree; a bone boundary inside a part that moves rigidly (the
registration slides along a limb, so step 2 cuts it) adds degrees of freedom that explain
nothing in the observed frames. This module removes such joints by model selection on the raw
points, not on the registration:

- the model of a frame is the rest points posed rigidly by their bones, ``R_t[l_m] q_m +
  T_t[l_m]``; a raw point's residual is its distance to the nearest posed point, truncated at
  ``c = 3 sigma_r`` (``sigma_r`` from the median residual, so outliers and background cost a
  constant and decide nothing);
- the model resolves no more than its ``M`` rest points: raw points sharing a nearest rest point
  share its error, so they are not independent observations. Frame ``t``'s ``N_t`` raw points
  count as the ``M_t`` distinct rest points they are nearest to: each weighs ``M_t / N_t`` in
  the sums and counts below, and the choice does not depend on the sampling density (the same
  frames sampled four times as densely keep the same joints);
- with Gaussian residuals of variance ``sigma^2`` (the mean truncated squared residual of the
  full tree), ``-2 log L = SSE / sigma^2`` up to a constant;
- removing the joint between bone ``b`` and its parent ``p`` replaces their two motions by the
  least-squares rigid motion of their posed points (one motion per frame); the raw points
  nearest those two bones give the change ``dSSE``;
- a ball joint costs a relative rotation per frame (3 parameters each) and its position (3).
  Each frame's rotation is estimated from that frame's raw points on the two parts only, and
  the position from all of them, so the Bayesian information criterion charges
  ``pen = 3 F ln(n / F) + 3 ln(n)``, ``n`` the (weighted) raw points nearest the two parts in
  the ``F`` frames scored, and keeps the joint when ``dSSE / sigma^2 > penalty_scale * pen``;
- joints are removed greedily, the least supported first, until every remaining joint passes.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from ._core import cluster_fit
from .geometry import nearest_distances

__all__ = ["JointSelection", "select_joints"]


@dataclass
class JointSelection:
    """What :func:`select_joints` kept.

    Attributes
    ----------
    keep
        ``(B',)`` indices of the input bones that remain, increasing.
    merged_into
        ``(B,)`` for every input bone, the index (into ``keep``'s order) of the bone it is part of.
    labels
        ``(M,)`` bone of each rest point, in the kept bones' numbering.
    bone_parent
        ``(B',)`` parent of each kept bone, ``-1`` for the root.
    R, T
        ``(F, B', 3, 3)`` and ``(F, B', 3)``: ``T_frame_rest`` of each kept bone, metres.
    removed
        ``(bone, parent, margin)`` per removed joint in removal order (input numbering), the
        margin ``dSSE / sigma^2 - penalty_scale * pen`` (dimensionless, negative).
    sigma2
        Residual variance of the full tree, m^2.
    """

    keep: np.ndarray
    merged_into: np.ndarray
    labels: np.ndarray
    bone_parent: np.ndarray
    R: np.ndarray
    T: np.ndarray
    removed: list[tuple[int, int, float]] = field(default_factory=list)
    sigma2: float = 0.0

    def merge_weights(self, weights: np.ndarray) -> np.ndarray:
        """``(M, B')`` skinning weights: each removed bone's weight added to the bone it joined."""
        W = np.asarray(weights, dtype=float)
        out = np.zeros((W.shape[0], len(self.keep)))
        np.add.at(out.T, self.merged_into, W.T)
        return out


def _posed(rest_points: np.ndarray, labels: np.ndarray, R: np.ndarray, T: np.ndarray
           ) -> np.ndarray:
    return np.einsum("mij,mj->mi", R[labels], rest_points) + T[labels]


def select_joints(frames: Sequence[np.ndarray], rest_points: np.ndarray, labels: np.ndarray,
                  bone_parent: np.ndarray, R: np.ndarray, T: np.ndarray, *,
                  penalty_scale: float = 1.0, max_frames: int = 30) -> JointSelection:
    """Remove the joints that the raw frames do not support (module docstring).

    Parameters
    ----------
    frames
        The ``F`` observed clouds ``(N_t, 3)``, metres, in the frame of ``T``.
    rest_points
        ``(M, 3)`` rest points, metres.
    labels
        ``(M,)`` bone of each rest point.
    bone_parent
        ``(B,)`` parent bone, ``-1`` for the root.
    R, T
        ``(F, B, 3, 3)``, ``(F, B, 3)``: ``T_frame_rest`` of each bone, metres.
    penalty_scale
        Multiplier of the BIC penalty (1 = BIC; the pipeline's ``joint_penalty`` is 0.5);
        0 keeps every joint.
    max_frames
        Frames scored (evenly spaced); the penalty counts the same frames.

    Returns
    -------
    JointSelection
    """
    Q = np.asarray(rest_points, dtype=float)
    labels = np.asarray(labels).copy()
    parent = np.asarray(bone_parent).copy()
    R, T = np.array(R, dtype=float), np.array(T, dtype=float)
    F, B = R.shape[:2]
    alive = list(range(B))
    removed: list[tuple[int, int, float]] = []
    fidx = np.unique(np.linspace(0, F - 1, min(F, max(1, max_frames))).round().astype(int))
    X = [np.asarray(frames[t], dtype=float) for t in fidx]
    n = sum(len(x) for x in X)
    # residual of every raw point under the full tree, the bone of its nearest posed point, and
    # the weight of each frame's raw points: the distinct rest points they are nearest to over
    # their number (the observations the model can tell apart; the module docstring)
    d2, near, wt = [], [], []
    for i, t in enumerate(fidx):
        d, j = cKDTree(_posed(Q, labels, R[t], T[t])).query(X[i])
        d2.append(d ** 2)
        near.append(labels[j])
        wt.append(len(np.unique(j)) / max(len(j), 1))
    resid = np.sqrt(np.concatenate(d2)) if n else np.zeros(1)
    cap = 3.0 * float(np.median(resid)) / 0.6745
    if penalty_scale <= 0 or B < 2 or n == 0 or cap <= 0:
        keep = np.arange(B)
        return JointSelection(keep, keep.copy(), labels, parent, R, T)
    cap2 = cap * cap
    d2 = [np.minimum(x, cap2) for x in d2]
    sigma2 = float(np.mean(np.concatenate(d2)))

    def merged_motion(g: np.ndarray, frames_t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(len(frames_t), 3, 3)``, ``(len(frames_t), 3)``: the least-squares rigid motion
        (Eq. 14, Rust) of the posed points of ``g`` in the frames ``frames_t``."""
        Qg, lg = np.ascontiguousarray(Q[g]), labels[g]
        posed = np.einsum("fmij,mj->fmi", R[frames_t][:, lg], Qg) + T[frames_t][:, lg]
        Rm, Tm, _ = cluster_fit(Qg, np.ascontiguousarray(posed), np.zeros(len(Qg), np.int64), 1)
        return Rm[:, 0], Tm[:, 0]

    def evidence(b: int) -> float:
        p = parent[b]
        g = (labels == b) | (labels == p)
        dsse = 0.0
        n_pair = 0.0
        Rm_all, Tm_all = merged_motion(g, fidx)
        for i in range(len(fidx)):
            sel = (near[i] == b) | (near[i] == p)
            n_pair += wt[i] * int(sel.sum())
            if not sel.any():
                continue
            dm = nearest_distances(X[i][sel], Q[g] @ Rm_all[i].T + Tm_all[i], cap)
            dsse += wt[i] * float(np.sum(dm * dm) - np.sum(d2[i][sel]))
        nf = len(fidx)
        pen = penalty_scale * (3 * nf * np.log(max(n_pair / nf, 2.0))
                               + 3 * np.log(max(n_pair, 2)))
        return dsse / sigma2 - pen

    cache: dict[tuple[int, int], float] = {}
    while True:
        cand = []
        for b in alive:
            if parent[b] >= 0:
                key = (b, int(parent[b]))
                if key not in cache:
                    cache[key] = evidence(b)
                cand.append((cache[key], b))
        if not cand:
            break
        ev, b = min(cand)
        if ev >= 0:
            break
        p = int(parent[b])
        removed.append((b, p, ev))
        g = (labels == b) | (labels == p)
        R[:, p], T[:, p] = merged_motion(g, np.arange(F))
        labels[labels == b] = p
        parent[parent == b] = p
        alive.remove(b)
        Qp = Q[labels == p]
        for i, t in enumerate(fidx):
            near[i][near[i] == b] = p
            sel = near[i] == p
            d2[i][sel] = nearest_distances(X[i][sel], Qp @ R[t, p].T + T[t, p], cap) ** 2
        cache = {k: v for k, v in cache.items() if p not in k and b not in k}
    keep = np.array(alive, dtype=np.int64)
    index = -np.ones(B, dtype=np.int64)
    index[keep] = np.arange(len(keep))
    into = np.arange(B)
    for b, p, _ in removed:
        into[into == b] = p
    return JointSelection(
        keep=keep, merged_into=index[into], labels=index[labels],
        bone_parent=np.array([index[parent[b]] if parent[b] >= 0 else -1 for b in keep],
                             dtype=np.int64),
        R=R[:, keep], T=T[:, keep], removed=removed, sigma2=sigma2)
