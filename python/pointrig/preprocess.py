"""Input clean-up and the rest-pose point set surface (paper §3 and §4, last paragraphs).

§4: "we first reconstruct a point set surface from the initial frame. This point set is chosen
as the rest pose". Here: statistical outlier removal, a moving-least-squares projection of each
point onto the plane fitted to its neighbours (a point set surface in the sense of Alexa et al.),
and farthest-point resampling to ``M`` near-uniformly spaced points. No mesh is built, so a
fragmented single-view cloud stays fragmented rather than being bridged by a reconstruction.
"""

from __future__ import annotations

import logging

import numpy as np
from scipy.spatial import cKDTree

from .errors import InputError

__all__ = ["remove_statistical_outliers", "mls_project", "farthest_point_sampling", "rest_surface"]

log = logging.getLogger(__name__)


def remove_statistical_outliers(points: np.ndarray, k: int = 20, std_ratio: float = 2.0) -> np.ndarray:
    """Keep points whose mean distance to their ``k`` neighbours is below mean + ratio * std.

    Parameters
    ----------
    points
        ``(N, 3)`` float64, metres.

    Returns
    -------
    ``(N', 3)`` kept points.
    """
    n = len(points)
    if n <= k + 1:
        return points.copy()
    d, _ = cKDTree(points).query(points, k=k + 1)
    md = d[:, 1:].mean(axis=1)
    keep = md <= md.mean() + std_ratio * md.std()
    return points[keep]


def mls_project(points: np.ndarray, k: int = 16, source: np.ndarray | None = None) -> np.ndarray:
    """Project each point onto the least-squares plane of its ``k`` nearest ``source`` points.

    ``points (n, 3)``, ``source (N, 3)`` (default ``points``), metres; returns ``(n, 3)``.
    """
    src = points if source is None else source
    if k < 3 or len(src) < k:
        return points.copy()
    _, idx = cKDTree(src).query(points, k=k)
    nb = src[idx]  # (n, k, 3)
    c = nb.mean(axis=1)
    cov = np.einsum("nki,nkj->nij", nb - c[:, None], nb - c[:, None])
    _, vecs = np.linalg.eigh(cov)
    normal = vecs[:, :, 0]
    off = np.einsum("ni,ni->n", points - c, normal)
    return points - off[:, None] * normal


def farthest_point_sampling(points: np.ndarray, n: int, seed: int = 0) -> np.ndarray:
    """Indices of ``n`` points chosen by farthest-point sampling (near-uniform spacing)."""
    m = len(points)
    if n >= m:
        return np.arange(m)
    rng = np.random.default_rng(seed)
    idx = np.empty(n, dtype=np.int64)
    idx[0] = rng.integers(m)
    d = np.sum((points - points[idx[0]]) ** 2, axis=1)
    for i in range(1, n):
        idx[i] = int(np.argmax(d))
        d = np.minimum(d, np.sum((points - points[idx[i]]) ** 2, axis=1))
    return idx


def rest_surface(
    points: np.ndarray,
    n_points: int = 2000,
    *,
    sor_neighbors: int = 20,
    sor_std_ratio: float = 2.0,
    mls_neighbors: int = 16,
    seed: int = 0,
) -> np.ndarray:
    """The rest-pose point set surface: ``(M, 3)`` float64, metres, ``M = min(n_points, N')``.

    Raises
    ------
    InputError
        If fewer than 10 points survive the outlier removal.
    """
    pts = np.ascontiguousarray(points, dtype=np.float64)
    clean = remove_statistical_outliers(pts, sor_neighbors, sor_std_ratio)
    if len(clean) < 10:
        raise InputError(f"rest frame has only {len(clean)} points after outlier removal")
    sel = clean[farthest_point_sampling(clean, n_points, seed)]
    if mls_neighbors > 0:
        sel = mls_project(sel, mls_neighbors, source=clean)
    log.debug("rest surface: %d -> %d clean -> %d points", len(pts), len(clean), len(sel))
    return np.ascontiguousarray(sel)
