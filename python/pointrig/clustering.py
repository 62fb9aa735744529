"""Step 2, stage 1: motion-based clustering of the rest points (paper §5.2, Eq. 14).

k-means on rest positions concatenated with scaled displacement trajectories
(:func:`kmeans_features`, :func:`_kmeans`) gives ``k`` initial clusters; then
``cluster_rounds`` rounds (:func:`_cluster_rounds`) of (i) one rigid transform per cluster
and frame by weighted absolute orientation (Kabsch, Eq. 14, ``_core.cluster_fit``), (ii)
relabelling each point by the candidate bone (its own and its rest-pose neighbours',
:func:`_candidates`) with the smallest residual summed over frames
(``_core.cluster_residuals``), (iii) a majority vote of the labels in a rest-pose ball around
each point (:func:`_vote`), guarded by the motion evidence. The context ``ctx`` of every
function is :class:`pointrig.structure._Ctx` (rest points, registered points, neighbourhoods).

Conventions: metres; ``x = R[t, b] @ q + T[t, b]`` (``T_frame_rest``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from . import _core

if TYPE_CHECKING:
    from .config import StructureConfig
    from .structure import _Ctx

__all__ = ["kmeans_features"]


def _compact(labels: np.ndarray) -> tuple[np.ndarray, int]:
    uniq, inv = np.unique(labels, return_inverse=True)
    return inv.astype(np.int64), len(uniq)


def _kmeans(X: np.ndarray, k: int, iters: int, rng: np.random.Generator) -> np.ndarray:
    """k-means++ seeding then Lloyd iterations; deterministic given ``rng``."""
    n = X.shape[0]
    centers = np.empty((k, X.shape[1]))
    centers[0] = X[rng.integers(n)]
    d2 = ((X - centers[0]) ** 2).sum(1)
    for c in range(1, k):
        p = d2 / d2.sum() if d2.sum() > 0 else np.full(n, 1.0 / n)
        centers[c] = X[rng.choice(n, p=p)]
        d2 = np.minimum(d2, ((X - centers[c]) ** 2).sum(1))
    labels = np.zeros(n, np.int64)
    xx = (X ** 2).sum(1)[:, None]
    for it in range(iters):
        dist = xx - 2.0 * X @ centers.T + (centers ** 2).sum(1)[None, :]
        new = dist.argmin(1)
        if it > 0 and np.array_equal(new, labels):
            break
        labels = new
        cnt = np.bincount(labels, minlength=k)
        order = np.argsort(labels, kind="stable")
        starts = np.concatenate([[0], np.cumsum(cnt)[:-1]])
        nz = cnt > 0
        centers[nz] = np.add.reduceat(X[order], starts[nz], axis=0) / cnt[nz, None]
    return labels


def kmeans_features(Q: np.ndarray, Y: np.ndarray, cfg: StructureConfig) -> np.ndarray:
    """k-means features: rest position and scaled displacement trajectories, ``(M, 3 + 3 F')``.

    Both blocks are scaled to the same total variance, then the trajectory block is multiplied
    by ``cfg.trajectory_weight`` (0 = positions only).
    """
    Qc = Q - Q.mean(0)
    if cfg.trajectory_weight <= 0 or Y.shape[0] < 2:
        return Qc
    nf = min(cfg.kmeans_frames, Y.shape[0])
    frames = np.unique(np.linspace(0, Y.shape[0] - 1, nf).round().astype(int))
    D = (Y[frames] - Q[None]).transpose(1, 0, 2).reshape(Q.shape[0], -1)
    D = D - D.mean(0)
    vq, vd = (Qc ** 2).sum(), (D ** 2).sum()
    if vd <= 1e-12 * max(vq, 1e-30):
        return Qc
    return np.hstack([Qc, cfg.trajectory_weight * np.sqrt(vq / vd) * D])


def _neighbor_labels(ctx: _Ctx, labels: np.ndarray) -> np.ndarray:
    """``(M, k)`` label of each rest point's ball neighbour (``ctx.nbr``), -1 for none."""
    return np.where(ctx.nbr >= 0, labels[np.maximum(ctx.nbr, 0)], -1)


def _candidates(ctx: _Ctx, labels: np.ndarray) -> np.ndarray:
    """Candidate bones per point: own label and labels of rest-pose neighbours, ``(M, C)``."""
    nl = _neighbor_labels(ctx, labels)
    cand = np.sort(np.hstack([labels[:, None], nl]), axis=1)
    dup = np.zeros_like(cand, dtype=bool)
    dup[:, 1:] = cand[:, 1:] == cand[:, :-1]
    cand[dup] = -1
    return np.ascontiguousarray(cand)


def _vote(ctx: _Ctx, labels: np.ndarray) -> np.ndarray:
    """Step (iii): majority label in the rest-pose ball (ties keep the current label)."""
    nl = _neighbor_labels(ctx, labels)
    allv = np.hstack([labels[:, None], nl])  # (M, 1 + k)
    counts = (allv[:, :, None] == allv[:, None, :]).sum(2).astype(float)
    counts[allv < 0] = -1
    counts[:, 0] += 0.5  # tie-break towards the own label
    return allv[np.arange(len(labels)), counts.argmax(1)]


def _cluster_rounds(ctx: _Ctx, labels: np.ndarray, rounds: int) -> np.ndarray:
    """``rounds`` iterations of (i) fit, (ii) relabel among candidates, (iii) vote (§5.2)."""
    labels, B = _compact(labels)
    for _ in range(rounds):
        R, T, _c = ctx.fit(labels, B)
        cand = _candidates(ctx, labels)
        res = _core.cluster_residuals(ctx.Q, ctx.Y, R, T, cand)
        new = cand[np.arange(ctx.M), res.argmin(1)]
        # (iii) majority vote in the rest-pose ball, guarded by the motion evidence: a point
        # takes the voted bone only if that bone is one of its candidates with a residual of
        # at most vote_guard_ratio times its best one (otherwise thin parts are voted away)
        voted = _vote(ctx, new)
        if ctx.cfg.vote_guard_ratio > 0:
            rv = np.where(cand == voted[:, None], res, np.inf).min(1)
            new = np.where(rv <= ctx.cfg.vote_guard_ratio * res.min(1), voted, new)
        else:
            new = voted
        new, B = _compact(new)
        if np.array_equal(new, labels):
            break
        labels = new
    return labels
