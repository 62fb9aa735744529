"""Single-view geometry: a depth camera sees only the near side of every part.

Step 2's boundary centroids ``c~`` (Eq. 20) and step 3's joint prior are averages of *visible*
rest points, so on single-view data they sit on the near surface, in front of the joint by a
fraction of the part's thickness. :func:`view_depth_correct` moves ``c~`` back along the ray
(never towards the camera) to an estimate of the depth of the part's axis: by default the front
depth of the points that define ``c~`` plus the radius of a round cross-section read from their
spread across the view; the session-6 rule, a high quantile of their depths (silhouette points
reach the axis depth), falls short because a depth camera samples the silhouette thinly and
loses it first.
:func:`two_layer_fraction` tells single-view input (one surface layer along every ray from the
camera) from two-sided or fused input, where the correction must stay off. docs/structure.md
("Session 6" and "Session 13") has the derivations and the ablations.

Units: metres. The camera position is in the input frame (the origin for camera-frame clouds).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["two_layer_fraction", "is_single_view", "in_view", "view_depth_correct",
           "SINGLE_VIEW_MAX_TWO_LAYER"]

#: Point sets with more than this fraction of two-layer camera rays are not one depth view
#: (measured: rest points of single-view sequences 0.04-0.25, two-sided samples 0.41-0.57).
SINGLE_VIEW_MAX_TWO_LAYER = 1.0 / 3.0


def _rays(points: np.ndarray, camera: np.ndarray
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """Rays from ``camera (3,)`` to ``points (M, 3)``: offsets ``(M, 3)``, ranges ``(M,)``,
    unit directions ``(M, 3)``, the unit mean direction ``(3,)`` and each ray's cosine to it
    ``(M,)``; ``None`` if there are no points, a point sits on the camera or the directions
    cancel out."""
    P = np.asarray(points, dtype=np.float64) - np.asarray(camera, dtype=np.float64)
    r = np.linalg.norm(P, axis=1)
    if len(P) == 0 or np.any(r <= 0):
        return None
    dirs = P / r[:, None]
    m = dirs.mean(0)
    n = np.linalg.norm(m)
    if n <= 0:
        return None
    m /= n
    return P, r, dirs, m, dirs @ m


def two_layer_fraction(points: np.ndarray, camera: np.ndarray, *, bin_spacings: float = 1.0,
                       layer_spacings: float = 4.0) -> float:
    """Fraction of the camera's rays that cross the point set twice or more.

    Rays are binned by a gnomonic projection about the mean viewing direction, with bins
    ``bin_spacings`` times the median nearest-neighbour spacing (at the median range) wide; a
    bin holding at least two points is *two-layer* when their ranges differ by more than
    ``layer_spacings`` spacings.

    Parameters
    ----------
    points
        ``(M, 3)`` points, metres.
    camera
        ``(3,)`` camera position, metres, same frame.

    Returns
    -------
    float
        In ``[0, 1]``: about 0 for a single depth view, about 1/2 or more for a closed surface.
        1.0 when some points are not in front of the camera (no single view can see them all).
    """
    if len(points) < 8:
        return 0.0
    rays = _rays(points, camera)
    if rays is None:
        return 1.0
    P, rng_, dirs, m, cos = rays
    if np.any(cos <= 0.1):
        return 1.0
    e1 = np.cross(m, [1.0, 0.0, 0.0] if abs(m[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(m, e1)
    uv = np.stack([dirs @ e1, dirs @ e2], 1) / cos[:, None]
    spacing = float(np.median(cKDTree(P).query(P, k=2)[0][:, 1]))
    if spacing <= 0:
        return 0.0
    cell = bin_spacings * spacing / float(np.median(rng_))
    keys = np.floor(uv / cell).astype(np.int64)
    _, inv = np.unique(keys, axis=0, return_inverse=True)
    inv = inv.ravel()
    n = np.bincount(inv)
    lo = np.full(n.size, np.inf)
    hi = np.full(n.size, -np.inf)
    np.minimum.at(lo, inv, rng_)
    np.maximum.at(hi, inv, rng_)
    multi = n >= 2
    if not multi.any():
        return 0.0
    return float(np.mean(hi[multi] - lo[multi] > layer_spacings * spacing))


def in_view(points: np.ndarray, camera: np.ndarray, min_cos: float = 0.5) -> bool:
    """True if every point of ``points (M, 3)`` lies within a cone of half-angle
    ``arccos(min_cos)`` (default 60 deg) about the mean viewing direction from ``camera (3,)``:
    the camera can be where the points were seen from (not inside or beside the subject, as
    when clouds are given in a world frame centred on the subject)."""
    rays = _rays(points, camera)
    return rays is not None and bool(np.all(rays[4] >= min_cos))


def is_single_view(points: np.ndarray, camera: np.ndarray,
                   max_two_layer: float = SINGLE_VIEW_MAX_TWO_LAYER) -> bool:
    """True if ``points (M, 3)`` look like one depth view from ``camera (3,)`` (metres): at most
    ``max_two_layer`` of the occupied rays cross two surface layers (:func:`two_layer_fraction`)."""
    return two_layer_fraction(points, camera) <= max_two_layer


def _weighted_quantile(x: np.ndarray, w: np.ndarray, q: float) -> float:
    """The ``q``-quantile of ``x (n,)`` with non-negative weights ``w (n,)`` (lower value)."""
    order = np.argsort(x, kind="stable")
    cw = np.cumsum(w[order])
    i = int(np.searchsorted(cw, min(max(q, 0.0), 1.0) * cw[-1]))
    return float(x[order[min(i, len(x) - 1)]])


def view_depth_correct(points: np.ndarray, weights: np.ndarray | None, centre: np.ndarray,
                       camera: np.ndarray, quantile: float, method: str = "quantile"
                       ) -> np.ndarray:
    """Move ``centre`` away from the camera to the estimated depth of its part's axis.

    Depth is measured along the unit ray ``u`` from ``camera`` through ``centre``. Two
    estimates of the axis depth ``d_a`` (docs/structure.md, sessions 6 and 13):

    * ``method="quantile"`` (session 6): the (weighted) ``quantile`` of the points' depths
      ``(p - camera) . u``. Points of a convex cross-section seen from one side reach back to
      about its centre's depth at the silhouette, so a high quantile estimates the axis depth,
      if the silhouette is sampled.
    * ``method="width"`` (session 13): the front depth plus the radius read from the width of
      the points across the view, ``d_a = d_(1-q) + (s_q - s_(1-q)) / (2 (2q - 1))``, with
      ``d_(1-q)`` the ``1 - quantile`` depth quantile and ``s`` the points' coordinate along
      the major axis of their spread perpendicular to ``u``. A depth camera samples the image
      uniformly, so across a round cross-section of radius ``r`` the coordinate ``s`` is
      uniform on ``[-r, r]``: its ``q`` and ``1 - q`` quantiles are ``+-(2q - 1) r`` and the
      estimate is unbiased (the front lies ``r`` in front of the axis). The depth quantile
      needs the silhouette, which that sampling makes sparse (``|s| > 0.97 r`` holds 3 % of
      the points, still ``0.24 r`` in front of the axis) and which the sensor loses first:
      cutting the points beyond a viewing angle ``theta`` shortens the depth reach by
      ``r cos(theta)`` but the width only by ``r (1 - sin(theta))`` (``theta`` = 70 deg: 0.34 r
      against 0.06 r).

    The result is ``centre + max(d_a - d_centre, 0) u``: never towards the camera.

    Parameters
    ----------
    points
        ``(n, 3)`` the visible points that define ``centre`` (e.g. a boundary band), metres.
    weights
        ``(n,)`` non-negative weights, or ``None`` for equal weights.
    centre
        ``(3,)`` the centroid to correct, metres.
    camera
        ``(3,)`` camera position, metres.
    quantile
        In ``[0, 1]``; 0 returns ``centre`` unchanged. ``"width"`` needs ``quantile > 1/2``.
    method
        ``"quantile"`` or ``"width"``.

    Returns
    -------
    numpy.ndarray
        ``(3,)`` corrected centre, metres.
    """
    c = np.asarray(centre, dtype=np.float64)
    P = np.asarray(points, dtype=np.float64)
    if quantile <= 0 or len(P) == 0:
        return c.copy()
    cam = np.asarray(camera, dtype=np.float64)
    u = c - cam
    n = np.linalg.norm(u)
    if n <= 0:
        return c.copy()
    u /= n
    d = (P - cam) @ u
    w = np.ones(len(d)) if weights is None else np.asarray(weights, dtype=np.float64)
    if not np.sum(w) > 0:
        return c.copy()
    if method == "width":
        q = float(quantile)
        if not q > 0.5:
            raise ValueError(f"view_depth_correct: the width method needs quantile > 1/2, got {q}")
        lateral = (P - c) - np.outer((P - c) @ u, u)  # (n, 3) offsets across the view
        mu = w @ lateral / w.sum()
        cov = (w[:, None] * (lateral - mu)).T @ (lateral - mu) / w.sum()
        axis = np.linalg.eigh(cov)[1][:, -1]  # major axis of the spread across the view
        s = lateral @ axis
        spread = _weighted_quantile(s, w, q) - _weighted_quantile(s, w, 1.0 - q)
        radius = spread / (2.0 * (2.0 * q - 1.0))  # s uniform on [-r, r]: spread = 2 (2q - 1) r
        da = _weighted_quantile(d, w, 1.0 - q) + radius
    elif method == "quantile":
        da = _weighted_quantile(d, w, quantile)
    else:
        raise ValueError(f"view_depth_correct: unknown method {method!r}")
    return c + max(da - n, 0.0) * u
