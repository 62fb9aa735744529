"""Shared helpers for the registration tests and benchmark: metrics against ground truth,
a numpy oracle of Eq. 8a, and a tiny synthetic articulated generator (no dependencies)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def nearest_observed(points: np.ndarray, frames: list[np.ndarray]) -> np.ndarray:
    """``(F, M)`` distance of each registered point to the nearest observed point of its frame."""
    return np.stack([cKDTree(x).query(y)[0] for y, x in zip(points, frames)])


def correspondence_error(
    rest_points: np.ndarray, points: np.ndarray, surface: np.ndarray, rest_frame: int = 0,
    max_offset: float = 0.01,
) -> np.ndarray:
    """``(F, M')`` displacement error against exact surface correspondences.

    Each rest point is tied to its nearest ground-truth surface sample in the rest frame
    (only points within ``max_offset`` of one); the error at frame t is
    ``|(Y^t_m - Y^rest_m) - (S^t_s - S^rest_s)|``, which removes the fixed sampling offset.
    """
    d, s = cKDTree(surface[rest_frame]).query(rest_points)
    ok = d < max_offset
    dy = points[:, ok] - points[rest_frame][ok]
    ds = surface[:, s[ok]] - surface[rest_frame][s[ok]]
    return np.linalg.norm(dy - ds, axis=2)


def energy_8a(
    y_def: np.ndarray, x: np.ndarray, sigma2: float, omega: float, p: np.ndarray,
    nodes: np.ndarray, r: np.ndarray, t: np.ndarray, r_pre: np.ndarray, t_pre: np.ndarray,
    edges: np.ndarray, beta_smooth: float, beta_small: float,
) -> float:
    """Eq. 8a in numpy with an explicit posterior matrix ``p (M, N)`` (Eq. 5b + 6 + 7)."""
    d2 = ((y_def[:, None, :] - x[None, :, :]) ** 2).sum(-1)
    e_gmm = (p * d2).sum() / (2 * sigma2) + 1.5 * p.sum() * np.log(sigma2)
    j, k = edges[:, 0], edges[:, 1]
    res = np.einsum("eab,eb->ea", r[j], nodes[k] - nodes[j]) + nodes[j] + t[j] - nodes[k] - t[k]
    e_smooth = (res**2).sum()
    e_small = ((r - r_pre) ** 2).sum() + ((t - t_pre) ** 2).sum()
    return float(e_gmm + beta_smooth / 2 * e_smooth + beta_small / 2 * e_small)


def posteriors(y: np.ndarray, x: np.ndarray, sigma2: float, omega: float) -> np.ndarray:
    """Dense Eq. 4, ``(M, N)``."""
    m, n = len(y), len(x)
    e = np.exp(-((y[:, None, :] - x[None, :, :]) ** 2).sum(-1) / (2 * sigma2))
    c0 = (2 * np.pi * sigma2) ** 1.5 * omega * m / ((1 - omega) * n)
    return e / (e.sum(0) + c0)


def capsule_arm(n_frames: int = 10, step_deg: float = 8.0, n: int = 1500, seed: int = 0):
    """Two capsules (upper and lower arm) seen from +z; the elbow bends ``step_deg`` per frame.

    Returns ``(frames, truth)``: visible points per frame ``(N_t, 3)`` and the same material
    points for every frame ``(F, n, 3)`` (all points, visible or not).
    """
    rng = np.random.default_rng(seed)
    u = rng.uniform(0, 1, n)
    a = rng.uniform(0, 2 * np.pi, n)
    seg = u < 0.5
    along = np.where(seg, u * 2 * 0.3, (u - 0.5) * 2 * 0.28)
    rad = 0.045
    local = np.stack([along, rad * np.cos(a), rad * np.sin(a)], 1)
    normals_local = np.stack([np.zeros(n), np.cos(a), np.sin(a)], 1)
    frames, truth = [], []
    for f in range(n_frames):
        ang = np.deg2rad(step_deg * f)
        c, s = np.cos(ang), np.sin(ang)
        rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
        p = local.copy()
        nrm = normals_local.copy()
        low = ~seg
        p[low] = local[low] @ rz.T + np.array([0.3, 0, 0])
        nrm[low] = normals_local[low] @ rz.T
        p = p + np.array([-0.3, 0.0, 2.0])
        truth.append(p)
        vis = nrm[:, 2] < 0  # camera at origin looking along +z: facing points have n_z < 0
        frames.append(np.ascontiguousarray(p[vis]))
    return frames, np.stack(truth)


def scissor_legs(n_frames: int = 12, amp_deg: float = 30.0, n: int = 2000, gap: float = 0.0,
                 seed: int = 0) -> tuple[list[np.ndarray], np.ndarray]:
    """A hip block with two capsule legs side by side, seen from +z: the legs swing apart in
    the image plane (a V of up to ``2 amp_deg``) and close at the middle frame, where their
    surfaces are ``gap`` metres apart (0: touching, the rest-frame contact of a walking
    figure whose legs pass each other).

    Returns ``(frames, truth)``: the seen points per frame ``(n, 3)`` with 2 mm noise and the
    same material points without noise ``(F, n, 3)``, metres (the camera at the origin, the
    legs 2 m away).
    """
    rng = np.random.default_rng(seed)
    rad, length = 0.05, 0.5
    nb = n // 4
    nl = (n - nb) // 2

    def leg(m: int) -> np.ndarray:  # the half of a capsule that faces the camera (-z)
        u = rng.uniform(0.0, 1.0, m)
        a = rng.uniform(np.pi, 2.0 * np.pi, m)
        return np.stack([rad * np.cos(a), -u * length, rad * np.sin(a)], 1)

    left, right = leg(nl), leg(n - nb - nl)
    block = np.stack([rng.uniform(-0.15, 0.15, nb), rng.uniform(0.0, 0.2, nb),
                      np.full(nb, -0.06)], 1)
    mid = (n_frames - 1) / 2.0
    truth = []
    for t in range(n_frames):
        th = np.deg2rad(amp_deg) * abs(t - mid) / max(mid, 1.0)
        c, s = np.cos(th), np.sin(th)
        rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        a = left @ rz + [-(rad + gap / 2.0), 0.0, 0.0]  # turned by -th
        b = right @ rz.T + [rad + gap / 2.0, 0.0, 0.0]  # turned by +th
        truth.append(np.concatenate([block, a, b]) + [0.0, 0.0, 2.0])
    truth_arr = np.stack(truth)
    frames = [p + rng.normal(scale=0.002, size=p.shape) for p in truth_arr]
    return frames, truth_arr
