"""Articulated point-set generator for the structure tests (independent of pointrig.synth).

A figure is a tree of capsule parts; each non-root part rotates about its joint (the start of
its capsule) with a smooth joint-angle trajectory, the root moves rigidly. Points are sampled
on the capsule surfaces in the rest pose (frame 0 is the rest pose) and carried to every frame
by the exact part transforms, optionally blended with the parent near each joint (imitating a
registration that over-smooths near joints) and jittered.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation


@dataclass
class Figure:
    names: list[str]
    parent: np.ndarray  # (P,)
    a: np.ndarray  # (P, 3) capsule start = joint with the parent (root: its base)
    b: np.ndarray  # (P, 3) capsule end
    radius: np.ndarray  # (P,)
    hinge: np.ndarray  # (P, 3) hinge axis, or zeros for a ball joint

    @property
    def edges(self) -> set[frozenset[int]]:
        return {frozenset((int(p), k)) for k, p in enumerate(self.parent) if p >= 0}


def _fig(rows) -> Figure:
    names = [r[0] for r in rows]
    idx = {n: i for i, n in enumerate(names)}
    parent = np.array([idx[r[1]] if r[1] else -1 for r in rows])
    a = np.array([r[2] for r in rows], float)
    b = np.array([r[3] for r in rows], float)
    rad = np.array([r[4] for r in rows], float)
    hinge = np.array([r[5] if len(r) > 5 else (0, 0, 0) for r in rows], float)
    return Figure(names, parent, a, b, rad, hinge)


X, Z = (1, 0, 0), (0, 0, 1)


def make_figure(kind: str) -> Figure:
    """``humanoid`` (11 parts), ``arm`` (4), ``quadruped`` (11)."""
    if kind == "humanoid":
        return _fig([
            ("pelvis", None, (0, 0.92, 0), (0, 1.04, 0), 0.13),
            ("torso", "pelvis", (0, 1.06, 0), (0, 1.42, 0), 0.14),
            ("head", "torso", (0, 1.52, 0), (0, 1.70, 0), 0.09),
            ("l_upper", "torso", (0.21, 1.42, 0), (0.30, 1.15, 0), 0.045),
            ("l_fore", "l_upper", (0.30, 1.15, 0), (0.38, 0.90, 0), 0.04, X),
            ("r_upper", "torso", (-0.21, 1.42, 0), (-0.30, 1.15, 0), 0.045),
            ("r_fore", "r_upper", (-0.30, 1.15, 0), (-0.38, 0.90, 0), 0.04, X),
            ("l_thigh", "pelvis", (0.10, 0.88, 0), (0.11, 0.50, 0), 0.065),
            ("l_shin", "l_thigh", (0.11, 0.50, 0), (0.11, 0.10, 0), 0.05, X),
            ("r_thigh", "pelvis", (-0.10, 0.88, 0), (-0.11, 0.50, 0), 0.065),
            ("r_shin", "r_thigh", (-0.11, 0.50, 0), (-0.11, 0.10, 0), 0.05, X),
        ])
    if kind == "humanoid_raised":  # left arm raised beside the head (occlusion test)
        fig = make_figure("humanoid")
        i, j = fig.names.index("l_upper"), fig.names.index("l_fore")
        fig.a[i], fig.b[i] = (0.19, 1.42, 0), (0.20, 1.74, 0)
        fig.a[j], fig.b[j] = (0.20, 1.74, 0), (0.21, 1.98, 0)
        fig.hinge[j] = X
        return fig
    if kind == "arm":
        return _fig([
            ("base", None, (0, 0, 0), (0, 0.10, 0), 0.06),
            ("upper", "base", (0, 0.12, 0), (0, 0.40, 0), 0.04, Z),
            ("fore", "upper", (0, 0.40, 0), (0, 0.65, 0), 0.035, Z),
            ("hand", "fore", (0, 0.65, 0), (0, 0.76, 0), 0.03, X),
        ])
    if kind == "quadruped":
        rows = [("body", None, (-0.40, 0.60, 0), (0.40, 0.60, 0), 0.15),
                ("head", "body", (0.50, 0.65, 0), (0.70, 0.78, 0), 0.08),
                ("tail", "body", (-0.52, 0.62, 0), (-0.80, 0.72, 0), 0.03)]
        for sx, fx in ((1, "f"), (-1, "h")):
            for sz, lr in ((1, "l"), (-1, "r")):
                x, z = 0.30 * sx, 0.09 * sz
                rows.append((f"{fx}{lr}_up", "body", (x, 0.45, z), (x, 0.27, z), 0.045, Z))
                rows.append((f"{fx}{lr}_lo", f"{fx}{lr}_up", (x, 0.27, z), (x, 0.03, z),
                             0.035, Z))
        return _fig(rows)
    raise ValueError(kind)


def sample_surface(fig: Figure, n_points: int, rng: np.random.Generator):
    """Points on the capsule side surfaces (hemispherical caps included), ``(M, 3)`` + labels."""
    P = len(fig.names)
    length = np.linalg.norm(fig.b - fig.a, axis=1)
    area = 2 * np.pi * fig.radius * length + 4 * np.pi * fig.radius ** 2
    n = np.maximum(np.round(n_points * area / area.sum()).astype(int), 8)
    pts, lab = [], []
    for p in range(P):
        ax = (fig.b[p] - fig.a[p]) / length[p]
        u = np.cross(ax, [0.3, 0.5, 0.8])
        u /= np.linalg.norm(u)
        v = np.cross(ax, u)
        s = rng.uniform(-fig.radius[p], length[p] + fig.radius[p], n[p])
        phi = rng.uniform(0, 2 * np.pi, n[p])
        # radius shrinks on the caps
        over = np.where(s < 0, -s, np.where(s > length[p], s - length[p], 0.0))
        r = np.sqrt(np.maximum(fig.radius[p] ** 2 - over ** 2, 0.0))
        q = fig.a[p] + s[:, None] * ax + r[:, None] * (np.cos(phi)[:, None] * u
                                                        + np.sin(phi)[:, None] * v)
        pts.append(q)
        lab.append(np.full(n[p], p))
    pts, lab = np.vstack(pts), np.concatenate(lab)
    # keep only the surface of the union: drop points inside another part's capsule
    inside = np.zeros(len(pts), bool)
    for p in range(P):
        ab = fig.b[p] - fig.a[p]
        s = np.clip(((pts - fig.a[p]) @ ab) / (ab @ ab), 0.0, 1.0)
        d = np.linalg.norm(pts - (fig.a[p] + s[:, None] * ab), axis=1)
        inside |= (d < fig.radius[p] * 0.999) & (lab != p)
    return pts[~inside], lab[~inside]


def animate(fig: Figure, n_frames: int, rng: np.random.Generator, amp_deg=(35.0, 70.0)):
    """World transforms ``R (F, P, 3, 3)``, ``T (F, P, 3)`` (``T_frame_rest``); frame 0 = rest."""
    P = len(fig.names)
    t = np.arange(n_frames) / max(n_frames - 1, 1)
    R = np.zeros((n_frames, P, 3, 3))
    T = np.zeros((n_frames, P, 3))
    local = np.zeros((n_frames, P, 3))  # rotation vectors
    for p in range(P):
        if fig.parent[p] < 0:
            # root: slow turn about y plus a drift
            ang = np.radians(25) * np.sin(2 * np.pi * 0.5 * t)
            local[:, p] = ang[:, None] * np.array([0, 1, 0])
            continue
        amp = np.radians(rng.uniform(*amp_deg))
        freq = rng.uniform(0.7, 2.0)
        phase = np.sin(2 * np.pi * freq * t) if rng.random() < 0.5 else (1 - np.cos(2 * np.pi * freq * t)) / 2
        if np.linalg.norm(fig.hinge[p]) > 0:
            local[:, p] = (amp * phase)[:, None] * fig.hinge[p]
        else:
            ax2 = rng.normal(size=3)
            ax2 /= np.linalg.norm(ax2)
            ax1 = rng.normal(size=3)
            ax1 /= np.linalg.norm(ax1)
            f2 = rng.uniform(0.5, 1.5)
            local[:, p] = (amp * phase)[:, None] * ax1 + (0.5 * amp * np.sin(2 * np.pi * f2 * t))[:, None] * ax2
    drift = np.stack([0.1 * np.sin(2 * np.pi * t), 0.02 * t, 0.05 * t], 1)
    for p in range(P):  # parents come first in every figure
        Rl = Rotation.from_rotvec(local[:, p]).as_matrix()
        j = fig.a[p]
        if fig.parent[p] < 0:
            R[:, p] = Rl
            T[:, p] = j - np.einsum("fij,j->fi", Rl, j) + drift
        else:
            pp = fig.parent[p]
            R[:, p] = R[:, pp] @ Rl
            T[:, p] = np.einsum("fij,j->fi", R[:, pp], j) + T[:, pp] - np.einsum("fij,j->fi", R[:, p], j)
    return R, T


def pose(rest, labels, R, T, fig: Figure | None = None, blend: float = 0.0):
    """``(F, M, 3)`` positions; within ``blend`` metres of a joint a point is LBS-blended with the
    bone on the other side of that joint (weight up to 0.5 at the joint)."""
    W = np.zeros((rest.shape[0], R.shape[1]))
    W[np.arange(len(labels)), labels] = 1.0
    if blend > 0 and fig is not None:
        for k, p in enumerate(fig.parent):
            if p < 0:
                continue
            d = np.linalg.norm(rest - fig.a[k], axis=1)
            near = (d < blend) & ((labels == k) | (labels == p))
            other = np.where(labels[near] == k, p, k)
            w = 0.5 * (1 - d[near] / blend) ** 2
            rows = np.flatnonzero(near)
            W[rows, labels[near]] -= w
            W[rows, other] += w
    out = np.zeros((R.shape[0], rest.shape[0], 3))
    for b in range(R.shape[1]):
        sel = W[:, b] > 0
        if sel.any():
            out[:, sel] += W[sel, b, None] * (np.einsum("fij,mj->fmi", R[:, b], rest[sel]) + T[:, b, None])
    return out


def make_sequence(kind: str, n_points: int = 1500, n_frames: int = 40, seed: int = 0,
                  noise: float = 0.0, blend: float = 0.0, smooth_frames: int = 0,
                  hide_near_joint: tuple[str, float] | None = None,
                  amp_deg: tuple[float, float] = (35.0, 70.0)):
    """A dict with rest (M,3), points (F,M,3), labels (M,), figure, R, T.

    ``noise``: per-frame Gaussian jitter (m); ``smooth_frames``: temporal moving-average window
    applied to the trajectories (imitates over-smoothed registration); ``hide_near_joint``:
    (part name, radius) drops every point within radius of that part's joint (occlusion);
    ``amp_deg``: range of the joint-angle amplitudes (degrees, see :func:`animate`).
    """
    rng = np.random.default_rng(seed)
    fig = make_figure(kind)
    rest, labels = sample_surface(fig, n_points, rng)
    if hide_near_joint is not None:
        name, rad = hide_near_joint
        keep = np.linalg.norm(rest - fig.a[fig.names.index(name)], axis=1) > rad
        rest, labels = rest[keep], labels[keep]
    R, T = animate(fig, n_frames, rng, amp_deg)
    pts = pose(rest, labels, R, T, fig, blend)
    if smooth_frames > 1:
        ker = np.ones(smooth_frames) / smooth_frames
        pad = np.concatenate([np.repeat(pts[:1], smooth_frames // 2, 0), pts,
                              np.repeat(pts[-1:], smooth_frames // 2, 0)])
        pts = np.apply_along_axis(lambda s: np.convolve(s, ker, mode="valid"), 0, pad)[:n_frames]
    if noise > 0:
        pts = pts + rng.normal(scale=noise, size=pts.shape)
    return {"rest": rest, "points": np.ascontiguousarray(pts), "labels": labels, "figure": fig,
            "R": R, "T": T}


def purity(labels: np.ndarray, truth: np.ndarray) -> float:
    """Fraction of points whose bone's majority ground-truth part equals their own part."""
    tot = 0
    for b in np.unique(labels):
        tot += np.bincount(truth[labels == b]).max()
    return tot / len(labels)


def bone_to_part(labels: np.ndarray, truth: np.ndarray, n_bones: int) -> np.ndarray:
    return np.array([np.bincount(truth[labels == b]).argmax() for b in range(n_bones)])


def topology_matches(labels, bone_parent, truth, fig: Figure) -> bool:
    """One bone per part and the undirected tree edges equal the figure's."""
    B = len(bone_parent)
    part = bone_to_part(labels, truth, B)
    if B != len(fig.names) or len(set(part.tolist())) != B:
        return False
    edges = {frozenset((int(part[k]), int(part[p]))) for k, p in enumerate(bone_parent) if p >= 0}
    return edges == fig.edges
