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
- a bone ``b`` between its parent ``p`` and its only child ``c`` can lose a joint in a second
  way: its rest points are shared out between ``p``'s and ``c``'s motions (each point to the one
  that poses it nearer both the raw points and ``b``'s own pose of it over the frames scored)
  and ``c`` hangs from ``p``. This is the smaller model a blend zone calls for: where the
  registration spreads a joint's bend over a band of the surface, step 2 makes the band a short
  bone of its own, and neither of its two joints goes when it is merged into a neighbour whole.
  The same ``dSSE`` (the raw points nearest the three bones) and the same penalty of one joint
  decide; ``c``'s joint moves from its own place towards ``b``'s by the fraction of ``b``'s
  points that went to ``c``;
- joints are removed greedily, the least supported removal first, until every remaining joint
  passes.
"""

from __future__ import annotations

from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from ._core import cluster_fit
from .config import pool_size
from .geometry import nearest_distances_grouped

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
    shared_out
        ``(bone, child, fraction)`` per bone whose points were shared out between its parent
        and its only child, in removal order (input numbering): ``fraction`` of its rest points
        went to the child.
    point_bone
        ``(M, B)`` the kept bone that takes each input bone's weight at each rest point:
        ``merged_into`` but in the shared-out bones' columns; ``None`` when none was shared
        out.
    """

    keep: np.ndarray
    merged_into: np.ndarray
    labels: np.ndarray
    bone_parent: np.ndarray
    R: np.ndarray
    T: np.ndarray
    removed: list[tuple[int, int, float]] = field(default_factory=list)
    sigma2: float = 0.0
    shared_out: list[tuple[int, int, float]] = field(default_factory=list)
    point_bone: np.ndarray | None = None

    def merge_weights(self, weights: np.ndarray) -> np.ndarray:
        """``(M, B')`` skinning weights from the input's ``(M, B)``: each removed bone's
        weight added to the bone it joined (per rest point for a shared-out bone)."""
        W = np.asarray(weights, dtype=float)
        m = W.shape[0]
        dest = (np.broadcast_to(self.merged_into, W.shape) if self.point_bone is None
                else self.point_bone)
        out = np.zeros((m, len(self.keep)))
        np.add.at(out, (np.repeat(np.arange(m), W.shape[1]), dest.ravel()), W.ravel())
        return out

    def rest_joints(self, joints_rest: np.ndarray) -> np.ndarray:
        """``(B', 3)`` rest joints of the kept bones from the input's ``(B, 3)`` (metres): a
        shared-out bone's child moves its joint towards the bone's own by the fraction of the
        bone's points it took (the module docstring); the others stay."""
        jr = np.array(joints_rest, dtype=float)
        for b, c, frac in self.shared_out:
            jr[c] = jr[c] + frac * (jr[b] - jr[c])
        return jr[self.keep]


def _posed(rest_points: np.ndarray, labels: np.ndarray, R: np.ndarray, T: np.ndarray
           ) -> np.ndarray:
    return np.einsum("mij,mj->mi", R[labels], rest_points) + T[labels]


def select_joints(frames: Sequence[np.ndarray], rest_points: np.ndarray, labels: np.ndarray,
                  bone_parent: np.ndarray, R: np.ndarray, T: np.ndarray, *,
                  penalty_scale: float = 1.0, max_frames: int = 30, workers: int = 0
                  ) -> JointSelection:
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
    workers
        Threads for the candidates' margins (0 = all cores; the same result for any number).

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
    d2a = np.concatenate(d2) if n else np.zeros(1)
    resid = np.sqrt(d2a)
    cap = 3.0 * float(np.median(resid)) / 0.6745
    if penalty_scale <= 0 or B < 2 or n == 0 or cap <= 0:
        keep = np.arange(B)
        return JointSelection(keep, keep.copy(), labels, parent, R, T)
    cap2 = cap * cap
    # the frames scored one after another: raw points Xa, their frame, capped squared residual
    # and the bone of their nearest posed point; the frames' rows start at xoff
    nf = len(fidx)
    Xa = np.concatenate(X)
    xoff = np.concatenate([[0], np.cumsum([len(x) for x in X])])
    frame_of = np.repeat(np.arange(nf), np.diff(xoff))
    d2a, neara = np.minimum(d2a, cap2), np.concatenate(near)
    del d2, near
    sigma2 = float(np.mean(d2a))

    def distances(sel: np.ndarray, posed: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """The capped distances of the raw points ``sel`` (increasing flat indices) to the
        posed points of their own frame (``posed[i]`` for frame ``i``), one Rust call; and
        the ``(nf + 1,)`` offsets of each frame's share of ``sel``."""
        qoff = np.concatenate([[0], np.cumsum(np.bincount(frame_of[sel], minlength=nf))])
        poff = np.concatenate([[0], np.cumsum([len(x) for x in posed])])
        return nearest_distances_grouped(Xa[sel], qoff, np.concatenate(posed), poff, cap), qoff

    def dsse_of(sel: np.ndarray, dm: np.ndarray, qoff: np.ndarray) -> float:
        """``sum_i wt_i (sum dm^2 - sum d2)`` over the frames, for the raw points ``sel``
        with new distances ``dm``, each frame summed on its own."""
        out = 0.0
        for i in range(nf):
            a, z = qoff[i], qoff[i + 1]
            if z > a:
                out += wt[i] * float(np.sum(dm[a:z] * dm[a:z]) - np.sum(d2a[sel[a:z]]))
        return out

    def count(qoff: np.ndarray) -> float:
        """The weighted count of the raw points whose per-frame offsets are ``qoff``."""
        out = 0.0
        for i in range(nf):
            out += wt[i] * int(qoff[i + 1] - qoff[i])
        return out

    def merged_motion(g: np.ndarray, frames_t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(len(frames_t), 3, 3)``, ``(len(frames_t), 3)``: the least-squares rigid motion
        (Eq. 14, Rust) of the posed points of ``g`` in the frames ``frames_t``."""
        Qg, lg = np.ascontiguousarray(Q[g]), labels[g]
        posed = np.einsum("fmij,mj->fmi", R[frames_t][:, lg], Qg) + T[frames_t][:, lg]
        Rm, Tm, _ = cluster_fit(Qg, np.ascontiguousarray(posed), np.zeros(len(Qg), np.int64), 1)
        return Rm[:, 0], Tm[:, 0]

    def penalty(n_pair: float) -> float:
        """The BIC's charge for one ball joint seen by ``n_pair`` (weighted) raw points."""
        return penalty_scale * (3 * nf * np.log(max(n_pair / nf, 2.0))
                                + 3 * np.log(max(n_pair, 2)))

    def evidence(b: int) -> float:
        p = parent[b]
        g = (labels == b) | (labels == p)
        Rm_all, Tm_all = merged_motion(g, fidx)
        sel = np.flatnonzero((neara == b) | (neara == p))
        Qg = Q[g]
        dm, qoff = distances(sel, [Qg @ Rm_all[i].T + Tm_all[i] for i in range(nf)])
        return dsse_of(sel, dm, qoff) / sigma2 - penalty(count(qoff))

    # the raw points of each frame scored (a far dummy point for an empty frame), built when
    # the first bone with one child is scored
    trees: list[cKDTree] = []

    def share(b: int, p: int, c: int) -> np.ndarray:
        """``(M_b,)`` ``p`` or ``c`` for each rest point of ``b``: the motion that poses it
        nearer, over the frames scored, both the raw points (capped) and ``b``'s own pose of
        it (squared distances, summed)."""
        qb = Q[labels == b]
        own = [qb @ R[t, b].T for t in fidx]  # b's own pose of its points, less T[t, b]
        cost = []
        for x in (p, c):
            cx = np.zeros(len(qb))
            for i, t in enumerate(fidx):
                y = qb @ R[t, x].T + T[t, x]
                cx += np.sum((y - own[i] - T[t, b]) ** 2, axis=1)
                cx += np.minimum(trees[i].query(y, distance_upper_bound=cap)[0], cap) ** 2
            cost.append(cx)
        return np.where(cost[0] <= cost[1], p, c)

    def share_evidence(b: int, p: int, c: int) -> tuple[float, np.ndarray]:
        """The margin of sharing ``b`` out between ``p`` and ``c`` (their motions stay): the
        raw points nearest the three bones against the posed points of ``p`` and ``c`` with
        ``b``'s shared out, and the penalty of one joint; and the split (:func:`share`)."""
        to = share(b, p, c)
        lab = labels.copy()
        lab[labels == b] = to
        g = (lab == p) | (lab == c)
        Qg, lg = Q[g], lab[g]
        sel = np.flatnonzero((neara == b) | (neara == p) | (neara == c))
        dm, qoff = distances(sel, [_posed(Qg, lg, R[t], T[t]) for t in fidx])
        return dsse_of(sel, dm, qoff) / sigma2 - penalty(count(qoff)), to

    def margin(key: tuple[int, ...]) -> tuple[float, np.ndarray | None]:
        """``(b, parent)``: merging ``b``; ``(b, parent, child)``: sharing ``b`` out."""
        return (evidence(key[0]), None) if len(key) == 2 else share_evidence(*key)

    point_bone = np.broadcast_to(np.arange(B), (len(Q), B)).copy()
    shared_out: list[tuple[int, int, float]] = []
    cache: dict[tuple[int, ...], tuple[float, np.ndarray | None]] = {}
    with ThreadPoolExecutor(max_workers=pool_size(workers, B)) as pool:
        while True:
            # the removals open now: (b, parent) merges b into its parent, (b, parent, child)
            # shares b out; each margin reads the state and changes nothing, so the missing ones
            # are computed side by side with the same result as one after the other
            keys: list[tuple[int, ...]] = []
            for b in alive:
                if parent[b] >= 0:
                    keys.append((b, int(parent[b])))
                    kids = [k for k in alive if parent[k] == b]
                    if len(kids) == 1:
                        keys.append((b, int(parent[b]), kids[0]))
            todo = [k for k in keys if k not in cache]
            if not trees and any(len(k) == 3 for k in todo):
                trees.extend(cKDTree(x if len(x) else np.full((1, 3), 1e9)) for x in X)
            cache.update(zip(todo, pool.map(margin, todo)))
            if not keys:
                break
            ev, b, c = min((cache[k][0], k[0], k[2] if len(k) == 3 else -1) for k in keys)
            if ev >= 0:
                break
            p = int(parent[b])
            removed.append((b, p, ev))
            if c >= 0:  # b's points shared out between p and c, c hung from p
                to = cache[(b, p, c)][1]
                shared_out.append((b, c, float(np.mean(to == c))))
                labels[labels == b] = to
                point_bone[:, b] = np.where(labels == c, c, p)
                parent[c] = p
                alive.remove(b)
                # the raw points nearest the three bones: their residuals and nearest bones
                # against the posed points of p and c
                g = (labels == p) | (labels == c)
                Qg, lg = Q[g], labels[g]
                sel = np.flatnonzero((neara == b) | (neara == p) | (neara == c))
                cut = np.searchsorted(sel, xoff)
                for i, t in enumerate(fidx):
                    s_i = sel[cut[i]:cut[i + 1]]
                    d, j = cKDTree(_posed(Qg, lg, R[t], T[t])).query(Xa[s_i])
                    d2a[s_i], neara[s_i] = np.minimum(d, cap) ** 2, lg[j]
                cache = {k: v for k, v in cache.items() if not {p, b, c} & set(k)}
                continue
            g = (labels == b) | (labels == p)
            R[:, p], T[:, p] = merged_motion(g, np.arange(F))
            labels[labels == b] = p
            parent[parent == b] = p
            alive.remove(b)
            Qp = Q[labels == p]
            neara[neara == b] = p
            sel = np.flatnonzero(neara == p)
            dm, _ = distances(sel, [Qp @ R[t, p].T + T[t, p] for t in fidx])
            d2a[sel] = dm ** 2
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
        R=R[:, keep], T=T[:, keep], removed=removed, sigma2=sigma2, shared_out=shared_out,
        point_bone=index[into[point_bone]] if shared_out else None)
