"""Single-view geometry: a depth camera sees only the near side of every part.

Step 2's boundary centroids ``c~`` (Eq. 20) are averages of *visible* rest points, so on
single-view data they sit on the near surface, in front of the joint by a fraction of the
part's thickness. :func:`view_depth_correct` moves ``c~`` back along the ray (never towards the
camera) to an estimate of the depth of the part's axis: the front depth of the points that
define ``c~`` plus the radius of a round cross-section read from their spread across the view.
:func:`view_depth_joints` does the same for the output joints from the observed frames (the
chord rule). :func:`two_layer_fraction` tells single-view input (one surface layer along every
ray from the camera) from two-sided or fused input, where the correction must stay off.
docs/structure.md and docs/joints.md have the derivations.

Units: metres. The camera position is in the input frame (the origin for camera-frame clouds).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import numpy as np
from scipy.spatial import cKDTree

from . import _core
from .kinematics import joint_trajectories

__all__ = [
    "SINGLE_VIEW_MAX_TWO_LAYER",
    "chord_depth_offset",
    "chord_half_width",
    "chord_roundness",
    "image_coordinates",
    "in_view",
    "is_single_view",
    "two_layer_fraction",
    "view_depth_correct",
    "view_depth_joints",
]

#: Point sets with more than this fraction of two-layer camera rays are not one depth view
#: (measured: rest points of single-view sequences 0.04-0.25, two-sided samples 0.41-0.57).
SINGLE_VIEW_MAX_TWO_LAYER = 1.0 / 3.0

#: Directions tried for the shortest chord through a pixel (:func:`chord_half_width`).
CHORD_DIRECTIONS = 12
#: Fraction of the chord's half-length about its middle whose depths :func:`chord_roundness`
#: fits (a depth camera loses a round part's grazing edges first).
PROFILE_INNER = 0.8


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
    P, rng_, _, m, cos = rays
    if np.any(cos <= 0.1):
        return 1.0
    uv = image_coordinates(points, camera, m)[0]
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
                       camera: np.ndarray, quantile: float) -> np.ndarray:
    """Move ``centre`` away from the camera to the estimated depth of its part's axis.

    Depth is measured along the unit ray ``u`` from ``camera`` through ``centre``. The axis
    depth is the front depth plus the radius read from the width of the points across the
    view, ``d_a = d_(1-q) + (s_q - s_(1-q)) / (2 (2q - 1))``, with ``d_(1-q)`` the
    ``1 - quantile`` (weighted) quantile of the points' depths ``(p - camera) . u`` and ``s``
    the points' coordinate along the major axis of their spread perpendicular to ``u``. A
    depth camera samples the image uniformly, so across a round cross-section of radius ``r``
    the coordinate ``s`` is uniform on ``[-r, r]``: its ``q`` and ``1 - q`` quantiles are
    ``+-(2q - 1) r`` and the estimate is unbiased (the front lies ``r`` in front of the axis).
    Unlike a high quantile of the depths, it does not need the silhouette, which that sampling
    makes sparse and which the sensor loses first (cutting the points beyond a viewing angle
    ``theta`` shortens the width only by ``r (1 - sin(theta))``).

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
        ``q`` in ``(1/2, 1]``; 0 returns ``centre`` unchanged.

    Returns
    -------
    numpy.ndarray
        ``(3,)`` corrected centre, metres.

    Raises
    ------
    ValueError
        If ``0 < quantile <= 1/2``.
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
    q = float(quantile)
    if not q > 0.5:
        raise ValueError(f"view_depth_correct: quantile must be above 1/2, got {q}")
    lateral = (P - c) - np.outer((P - c) @ u, u)  # (n, 3) offsets across the view
    mu = w @ lateral / w.sum()
    cov = (w[:, None] * (lateral - mu)).T @ (lateral - mu) / w.sum()
    axis = np.linalg.eigh(cov)[1][:, -1]  # major axis of the spread across the view
    s = lateral @ axis
    spread = _weighted_quantile(s, w, q) - _weighted_quantile(s, w, 1.0 - q)
    radius = spread / (2.0 * (2.0 * q - 1.0))  # s uniform on [-r, r]: spread = 2 (2q - 1) r
    da = _weighted_quantile(d, w, 1.0 - q) + radius
    return c + max(da - n, 0.0) * u


def image_coordinates(points: np.ndarray, camera: np.ndarray, axis: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Gnomonic image coordinates of ``points (n, 3)`` seen from ``camera (3,)`` looking along
    the unit ``axis (3,)`` (metres): ``(uv (n, 2), depth (n,))``, ``uv`` in tangent units
    (pixels / focal length) and ``depth`` along ``axis`` in metres. Points with ``depth <= 0``
    get ``nan`` coordinates."""
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    e1 = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(a, e1)
    P = np.asarray(points, dtype=np.float64) - np.asarray(camera, dtype=np.float64)
    z = P @ a
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = np.stack([P @ e1, P @ e2], 1) / np.where(z > 0, z, np.nan)[:, None]
    return uv, z


def chord_half_width(uv: np.ndarray, centre: np.ndarray, band: float, gap: float,
                     n_directions: int = CHORD_DIRECTIONS) -> float:
    """Half the length of the shortest chord through ``centre`` of the silhouette of ``uv``.

    For each of ``n_directions`` directions evenly spread over 180 deg, the points within
    ``band`` of the line through ``centre`` are sorted along it; the chord is the run of them
    around ``centre`` with no gap wider than ``gap``. Directions where ``centre`` falls in a gap
    wider than ``gap`` (or past the run's ends) give no chord.

    Parameters
    ----------
    uv
        ``(n, 2)`` image coordinates of the part's points (any unit, e.g. tangent units).
    centre
        ``(2,)`` the query point, same unit.
    band, gap
        Half-width of the strip about each line and the largest gap inside a chord, same unit
        (a few times the sampling spacing).
    n_directions
        Number of directions tried.

    Returns
    -------
    float
        The half-length, same unit; ``inf`` if no direction gives a chord.
    """
    chord = _shortest_chord(uv, centre, band, gap, n_directions)
    return np.inf if chord is None else 0.5 * (chord[1] - chord[0])


def _shortest_chord(uv: np.ndarray, centre: np.ndarray, band: float, gap: float,
                    n_directions: int) -> tuple[float, float, np.ndarray] | None:
    """The shortest chord of :func:`chord_half_width`: ``(a, b, d)``, the chord running from
    ``centre + a d`` to ``centre + b d`` along its unit direction ``d (2,)`` (``a < 0 < b`` up
    to the sampling), or ``None``. Rust (``_core.shortest_chord``)."""
    dirs = _directions(n_directions)
    chord = _core.shortest_chord(np.ascontiguousarray(uv, dtype=np.float64),
                                 np.asarray(centre, dtype=np.float64).reshape(2), dirs,
                                 float(band), float(gap))
    return None if chord is None else (chord[0], chord[1], dirs[chord[2]].copy())


@functools.lru_cache(maxsize=8)
def _directions(n: int) -> np.ndarray:
    """``(n, 2)`` unit directions evenly spread over 180 deg from the x axis (read-only)."""
    d = np.array([[np.cos(th), np.sin(th)]
                  for th in np.linspace(0.0, np.pi, n, endpoint=False)]).reshape(n, 2)
    d.flags.writeable = False
    return d


def chord_roundness(uv: np.ndarray, z: np.ndarray, centre: np.ndarray, band: float,
                    gap: float, inner: float = PROFILE_INNER,
                    n_directions: int = CHORD_DIRECTIONS) -> float:
    """How deep the part under ``centre`` is for its width: the depth of a circular profile
    fitted to the observed depths along the shortest chord, over the chord's half-length.

    Along the shortest chord through ``centre`` (:func:`chord_half_width`), the depths ``z`` of
    the points in the strip within ``inner`` of the half-length from the chord's middle are
    fitted by least squares with ``z0 + h (1 - sqrt(1 - t^2))``, ``t`` the position over the
    half-length: a circular cross-section gives ``h`` equal to its radius (ratio 1), a flat
    part facing the camera (a palm, a board) a ratio near 0. The chord's ends are left out
    because a depth camera loses a round part's grazing edges first.

    Parameters
    ----------
    uv, z
        ``(n, 2)`` image coordinates (tangent units) and ``(n,)`` depths (metres) of the points
        (:func:`image_coordinates`).
    centre
        ``(2,)`` the query pixel, tangent units.
    band, gap
        Chord strip half-width and largest gap, tangent units.
    inner
        Fraction of the half-length about the chord's middle whose points are fitted.
    n_directions
        Directions tried for the chord.

    Returns
    -------
    float
        ``h`` over the half-length in metres at the fitted depth (dimensionless); ``nan`` if no
        chord passes through ``centre`` or fewer than 5 points lie on its inner part.
    """
    uv = np.asarray(uv, dtype=np.float64)
    z = np.asarray(z, dtype=np.float64)
    return _profile_roundness(uv, z, centre, _shortest_chord(uv, centre, band, gap,
                                                             n_directions), band, inner)


def _profile_roundness(uv: np.ndarray, z: np.ndarray, centre: np.ndarray,
                       chord: tuple[float, float, np.ndarray] | None, band: float,
                       inner: float) -> float:
    """:func:`chord_roundness` along a chord already found by :func:`_shortest_chord`."""
    if chord is None:
        return float("nan")
    a, b, d = chord
    half, mid = 0.5 * (b - a), 0.5 * (a + b)
    if not half > 0:
        return float("nan")
    rel = uv - np.asarray(centre, dtype=np.float64)
    x = rel @ d
    on = ((np.abs(rel @ np.array([-d[1], d[0]])) < band) & (x >= a) & (x <= b)
          & (np.abs(x - mid) <= inner * half))
    if on.sum() < 5:
        return float("nan")
    t = (x[on] - mid) / half
    g = 1.0 - np.sqrt(np.clip(1.0 - t * t, 0.0, 1.0))
    (z0, h), *_ = np.linalg.lstsq(np.stack([np.ones_like(g), g], 1), z[on], rcond=None)
    return float(h / (half * z0)) if z0 > 0 else float("nan")


def chord_depth_offset(points: np.ndarray, joint: np.ndarray, camera: np.ndarray,
                       axis: np.ndarray, radius: float, band: float, gap: float,
                       front_quantile: float = 0.2) -> float:
    """How far behind ``joint`` the axis of its part lies along the camera ray, metres.

    The part's axis depth is estimated as the depth of the front surface at the joint's pixel
    (the ``front_quantile`` of the depths of ``points`` seen within ``radius`` metres of the
    joint across the view) plus the half-width of the silhouette's shortest chord through that
    pixel (:func:`chord_half_width`, scaled to metres at the front depth): a round limb is as
    deep as it is wide.

    Parameters
    ----------
    points
        ``(n, 3)`` observed points of the part (e.g. the two bones meeting at the joint) in one
        frame, metres.
    joint
        ``(3,)`` the joint in the same frame, metres.
    camera, axis
        ``(3,)`` camera position and unit viewing axis (:func:`image_coordinates`).
    radius
        Neighbourhood radius for the front depth, metres.
    band, gap
        Chord strip half-width and largest gap, tangent units (:func:`chord_half_width`).
    front_quantile
        Depth quantile of the neighbourhood taken as the front surface.

    Returns
    -------
    float
        ``d_axis - d_joint`` in metres along the ray (positive: the axis lies behind the joint);
        ``nan`` if no point lies near the joint's pixel or no chord passes through it.
    """
    uv, z = image_coordinates(points, camera, axis)
    front, half, _ = _projected_chord_parts(uv, z, joint, camera, axis, radius, band, gap,
                                            front_quantile)
    return front + half


def _projected_chord_parts(uv: np.ndarray, z: np.ndarray, joint: np.ndarray,
                           camera: np.ndarray, axis: np.ndarray, radius: float, band: float,
                           gap: float, front_quantile: float = 0.2, roundness: bool = False
                           ) -> tuple[float, float, float]:
    """The parts of :func:`chord_depth_offset` on points already projected by
    :func:`image_coordinates` (``uv (n, 2)``, ``z (n,)``, so that a frame is projected once for
    all its joints): ``(front, half, round)``, the front surface's offset from the joint along
    its ray (metres, positive behind the joint), the chord's half-width (metres along the ray)
    and, if ``roundness``, :func:`chord_roundness` at the joint's pixel (else ``nan``). ``nan``
    where undefined."""
    nan = float("nan")
    juv, jz = image_coordinates(np.asarray(joint, dtype=np.float64)[None], camera, axis)
    if not jz[0] > 0 or len(z) == 0:
        return nan, nan, nan
    ok = np.isfinite(uv[:, 0])
    uv, z = uv[ok], z[ok]
    near = np.linalg.norm(uv - juv[0], axis=1) <= radius / jz[0]
    if not near.any():
        return nan, nan, nan
    ray = np.asarray(joint, dtype=np.float64) - np.asarray(camera, dtype=np.float64)
    cos = float(ray @ np.asarray(axis, dtype=np.float64)) / float(np.linalg.norm(ray))
    front = float(np.quantile(z[near], front_quantile))
    chord = _shortest_chord(uv, juv[0], band, gap, CHORD_DIRECTIONS)
    rnd = _profile_roundness(uv, z, juv[0], chord, band, PROFILE_INNER) if roundness else nan
    if chord is None:
        return (front - float(jz[0])) / cos, nan, rnd
    return (front - float(jz[0])) / cos, 0.5 * (chord[1] - chord[0]) * front / cos, rnd


def _nanmedian0(x: np.ndarray, empty: float) -> np.ndarray:
    """Median over axis 0 of ``x (K, B)`` ignoring NaN; ``empty`` where a column is all NaN."""
    out = np.full(x.shape[1], empty)
    valid = np.isfinite(x).any(0)
    if valid.any():
        out[valid] = np.nanmedian(x[:, valid], axis=0)
    return out


def view_depth_joints(frames: Sequence[np.ndarray], registered: np.ndarray, labels: np.ndarray,
                      bone_parent: np.ndarray, joints_rest: np.ndarray, R: np.ndarray,
                      T: np.ndarray, camera: np.ndarray, *, n_frames: int = 10,
                      band_spacings: float = 4.5, gap_spacings: float = 6.0,
                      radius_fraction: float = 0.02, label_fraction: float = 0.03,
                      visible_fraction: float = 0.01, min_roundness: float = 0.7,
                      max_roundness: float = 1.0 / 0.7, flat_roundness: float = 0.5
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Move each joint along the camera ray to the depth of its part's axis (the chord rule).

    In ``n_frames`` frames spread over the sequence, each joint's offset to its part's axis
    depth is read from the observed points by :func:`chord_depth_offset`, and the median over
    the frames is taken. Three silhouettes give three readings:

    * all observed points (a part in front of the joint's pixel, or behind it within the
      chord, counts as its own);
    * the points labelled with the joint's two bones (bone ``b`` and its parent; the root: its
      bone and children), each observed point taking the label of the nearest registered
      point if one lies within ``label_fraction`` of the subject size;
    * the points labelled with bone ``b`` alone.

    Each fails in its own way (occluders, wrong labels, flat parts whose image width is not
    their depth). The joint takes the reading of all points where its two failures are ruled
    out. No occluder: the front depth at the joint's pixel read from the joint's own bone is
    within ``visible_fraction`` of the subject size of the front read from all points (the
    bone itself is what the camera sees there). Round: the depth profile along the shortest
    chord is that of a circle, :func:`chord_roundness` between ``min_roundness`` and
    ``max_roundness`` (a flat part reads near 0; a thin part in front of a wider one, whose
    chord runs on over it, reads a step far above 1). Where the profile is flat (roundness
    below ``flat_roundness``) the silhouette's width says nothing of the depth, and the joint
    stays. Elsewhere it moves only where the three readings agree in sign, by their median.
    The joint moves by the result along its rest-frame ray.

    Parameters
    ----------
    frames
        ``F`` observed clouds ``(n_f, 3)``, camera frame, metres.
    registered
        ``(F, M, 3)`` the rest points registered to each frame, metres.
    labels
        ``(M,)`` bone of each rest point.
    bone_parent
        ``(B,)`` parent bone of each bone (-1 for the root); joint ``b`` heads bone ``b``.
    joints_rest
        ``(B, 3)`` rest-frame joints, metres (the rest frame is one of the camera frames).
    R, T
        ``(F, B, 3, 3)`` and ``(F, B, 3)`` bone transforms rest -> frame.
    camera
        ``(3,)`` camera position, metres.
    n_frames
        Number of frames read.
    band_spacings, gap_spacings
        Chord strip half-width and largest gap, in median image spacings of the frame's points.
    radius_fraction
        Front-depth neighbourhood radius, fraction of the subject size (the registered rest
        points' bounding-box diagonal).
    label_fraction
        Largest distance from an observed point to its registered point that labels it.
    visible_fraction, min_roundness, max_roundness, flat_roundness
        The tolerances above: front depths, fraction of the subject size; the range of the
        roundness ratio (a circle within 30 % by default); the ratio below which the part is
        flat.

    Returns
    -------
    tuple of numpy.ndarray
        ``(joints (B, 3), shift (B,))``: the moved rest joints (metres) and each joint's move
        along its ray (metres, positive = away from the camera, 0 where undefined).
    """
    parent = np.asarray(bone_parent, dtype=np.int64)
    J0 = np.asarray(joints_rest, dtype=np.float64)
    cam = np.asarray(camera, dtype=np.float64)
    F, B = len(frames), len(parent)
    lab = np.asarray(labels, dtype=np.int64)
    rest = np.asarray(registered[0], dtype=np.float64) if F else np.zeros((0, 3))
    size = float(np.linalg.norm(rest.max(0) - rest.min(0))) if len(rest) else 0.0
    shift = np.zeros(B)
    if F == 0 or B == 0 or size <= 0 or n_frames <= 0:
        return J0.copy(), shift
    # the readings' silhouettes: all points (None), the joint's two bones, its own bone
    bones: list[list[np.ndarray | None]] = [[None] * B, [], []]
    for b in range(B):
        others = [int(parent[b])] if parent[b] >= 0 else list(np.flatnonzero(parent == b))
        bones[1].append(np.array([b] + others, dtype=np.int64))
        bones[2].append(np.array([b], dtype=np.int64))
    idx = np.unique(np.linspace(0, F - 1, min(n_frames, F)).round().astype(np.int64))
    pos = joint_trajectories(J0, np.asarray(R)[idx], np.asarray(T)[idx], parent)  # (K, B, 3)
    offs = np.full((3, len(idx), B), np.nan)
    fronts = np.full((3, len(idx), B), np.nan)
    rnd = np.full((len(idx), B), np.nan)
    for k, f in enumerate(idx):
        X = np.asarray(frames[f], dtype=np.float64)
        rays = _rays(X, cam)
        if rays is None:
            continue
        axis = rays[3]  # the mean viewing direction
        uv, z = image_coordinates(X, cam, axis)  # once per frame, shared by every joint
        ok = np.isfinite(uv[:, 0])
        if ok.sum() < 8:
            continue
        spacing = float(np.median(cKDTree(uv[ok]).query(uv[ok], k=2)[0][:, 1]))
        if not spacing > 0:
            continue
        d, nn = cKDTree(np.asarray(registered[f], dtype=np.float64)).query(X)
        xl = np.where(d <= label_fraction * size, lab[nn], -1)
        for i in range(3):
            for b in range(B):
                sel = bones[i][b]
                part = slice(None) if sel is None else np.isin(xl, sel)
                front, half, r = _projected_chord_parts(
                    uv[part], z[part], pos[k, b], cam, axis, radius_fraction * size,
                    band_spacings * spacing, gap_spacings * spacing, roundness=i == 0)
                offs[i, k, b], fronts[i, k, b] = front + half, front
                if i == 0:
                    rnd[k, b] = r
    med = np.stack([_nanmedian0(offs[i], 0.0) for i in range(3)])
    sign = np.sign(med)
    agree = (sign[0] == sign[1]) & (sign[0] == sign[2])
    shift = np.where(agree, np.median(med, axis=0), 0.0)
    f_all, f_own = _nanmedian0(fronts[0], np.nan), _nanmedian0(fronts[2], np.nan)
    with np.errstate(invalid="ignore"):
        seen = np.abs(f_all - f_own) < visible_fraction * size
        ratio = _nanmedian0(rnd, np.nan)
        round_ = (ratio >= min_roundness) & (ratio <= max_roundness)
        flat = ratio < flat_roundness
    shift = np.where(seen & round_, med[0], np.where(flat, 0.0, shift))
    ray = J0 - cam
    n = np.linalg.norm(ray, axis=1, keepdims=True)
    out = J0 + shift[:, None] * np.divide(ray, n, out=np.zeros_like(ray), where=n > 0)
    return out, shift
