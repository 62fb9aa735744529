"""Background removal: static dominant planes (floor, walls) and what they leave stranded.

The paper (§3) crops the room out of a consumer depth camera's frames by hand. Here the
static dominant planes are found by RANSAC over the frames (:func:`find_background_planes`)
and removed from every frame with the clutter they strand (:func:`remove_background`,
``[preprocess] background = "auto"``); a recording with no such plane is left unchanged.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy.spatial import cKDTree

from .errors import EmptyFrameError
from .geometry import _connected_pieces, median_spacing
from .sequence import check_frame, frames_like

if TYPE_CHECKING:
    from .sequence import PointSequence

__all__ = [
    "BackgroundPlane",
    "BackgroundReport",
    "find_background_planes",
    "remove_background",
]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class BackgroundPlane:
    """A static scene plane removed from every frame.

    Attributes
    ----------
    normal
        ``(3,)`` unit normal in the input frame.
    offset
        ``d`` of the plane ``normal . x + d = 0``, metres.
    band
        Points closer than this to the plane are removed, metres.
    fraction
        Share of the sampled frames' (voxel-downsampled) points on the plane.
    span
        In-plane extent of its points (5th-95th percentile, longer axis), metres.
    static
        Voxel overlap of its points between the sampled frames (1 = identical in every frame).
    """

    normal: np.ndarray
    offset: float
    band: float
    fraction: float
    span: float
    static: float

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Unsigned distances ``(N,)`` (metres) of ``points (N, 3)`` to the plane."""
        return np.abs(points @ self.normal + self.offset)


@dataclass
class BackgroundReport:
    """What :func:`remove_background` removed."""

    planes: list[BackgroundPlane]
    removed_fraction: np.ndarray  # (F,) share of each frame's points removed
    candidates: int = 0  # planes found by RANSAC before the static / extent tests

    def summary(self) -> str:
        if not self.planes:
            return f"no static background plane found ({self.candidates} candidate(s) rejected)"
        return (f"removed {len(self.planes)} static background plane(s) (floor/walls) and stray "
                f"fragments: {100 * float(np.mean(self.removed_fraction)):.0f}% of the points")


def _band_distance(planes: list[BackgroundPlane], points: np.ndarray) -> np.ndarray:
    """Distance ``(N,)`` of ``points (N, 3)`` to the nearest plane in units of that plane's
    band (< 1 = inside a band; ``inf`` without planes)."""
    out = np.full(len(points), np.inf)
    for pl in planes:
        out = np.minimum(out, pl.distance(points) / pl.band)
    return out


def _fit_plane(p: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares plane of ``p (n, 3)``: unit normal and offset."""
    c = p.mean(axis=0)
    _, _, vt = np.linalg.svd(p - c, full_matrices=False)
    n = vt[2]
    return n, -float(n @ c)


def _ransac_plane(p: np.ndarray, threshold: float, iterations: int,
                  rng: np.random.Generator) -> tuple[np.ndarray, float, np.ndarray]:
    """The plane with the most points within ``threshold`` of ``p (n, 3)`` (seeded RANSAC,
    then two least-squares refits); returns normal, offset and the inlier mask."""
    n = len(p)
    idx = rng.integers(0, n, size=(iterations, 3))
    a, b, c = p[idx[:, 0]], p[idx[:, 1]], p[idx[:, 2]]
    nrm = np.cross(b - a, c - a)
    ln = np.linalg.norm(nrm, axis=1)
    ok = ln > 1e-12
    nrm, a = nrm[ok] / ln[ok, None], a[ok]
    off = -np.einsum("ij,ij->i", nrm, a)
    best, best_count = 0, -1
    pf = p.astype(np.float32)
    for s in range(0, len(nrm), 32):
        d = np.abs(pf @ nrm[s:s + 32].T.astype(np.float32) + off[s:s + 32].astype(np.float32))
        counts = (d < threshold).sum(axis=0)
        k = int(np.argmax(counts))
        if counts[k] > best_count:
            best, best_count = s + k, int(counts[k])
    normal, offset = nrm[best], float(off[best])
    inl = np.abs(p @ normal + offset) < threshold
    for _ in range(2):
        if inl.sum() < 3:
            break
        normal, offset = _fit_plane(p[inl])
        inl = np.abs(p @ normal + offset) < threshold
    return normal, offset, inl


def _voxel_set(points: np.ndarray, voxel: float) -> set[tuple[int, int, int]]:
    return set(map(tuple, np.floor(points / voxel).astype(np.int64)))


def find_background_planes(
    frames: list[np.ndarray],
    *,
    threshold: float = 0.03,
    min_fraction: float = 0.05,
    span_ratio: float = 1.5,
    min_static: float = 0.7,
    min_front: float = 0.9,
    camera: tuple[float, float, float] = (0.0, 0.0, 0.0),
    sample_frames: int = 5,
    max_planes: int = 6,
    voxel: float = 0.02,
    iterations: int = 400,
    seed: int = 0,
) -> tuple[list[BackgroundPlane], int]:
    """Static dominant planes of a depth sequence (floor, walls): what to remove before step 1.

    ``sample_frames`` evenly spaced frames are voxel-downsampled (``voxel`` metres) and pooled;
    planes are found one after another by RANSAC (``threshold`` metres, seeded) on the pooled
    points. A plane is background only if all of these hold, so that a flat part of the subject
    (a torso, a robot's base plate, a snake lying on its side) is never taken:

    * it holds at least ``min_fraction`` of the pooled points;
    * it is static: the voxels (side ``4 * threshold``) its points occupy in each sampled frame
      are, in the median over frames, at least ``min_static`` occupied in the first sampled
      frame too (a moving subject's flat part changes place);
    * the rest of the scene is in front of it: at least ``min_front`` of the points off all
      candidate planes (and farther than twice its band and ``8 * threshold`` from it) lie on
      the camera's side (a floor or wall is behind or under the subject; a flat part of a
      subject has the subject's other parts behind it);
    * it is large: its in-plane extent (5th-95th percentile, longer axis) is at least
      ``span_ratio`` times the subject's extent (bounding-box diagonal of the largest
      connected piece of what the static, in-front planes leave, median over the sampled
      frames), i.e. it reaches well past the subject.

    Parameters
    ----------
    frames
        ``F`` arrays ``(N_t, 3)``, metres.

    Returns
    -------
    (planes, candidates)
        The accepted :class:`BackgroundPlane` list (removal band = max(``threshold``, the 97.5th
        percentile of its points' distances to it)) and how many candidate planes RANSAC
        found (parallel candidates less than ``8 * threshold`` apart count as one).
    """
    from .io.readers import voxel_downsample

    rng = np.random.default_rng(seed)
    camera = np.asarray(camera, dtype=np.float64)
    f = len(frames)
    picks = np.unique(np.linspace(0, f - 1, min(sample_frames, f)).round().astype(int))
    parts = [voxel_downsample(np.asarray(frames[t], dtype=np.float64), voxel) for t in picks]
    which = np.concatenate([np.full(len(p), k) for k, p in enumerate(parts)])
    pool = np.concatenate(parts)
    if len(pool) > 120_000:  # bound the RANSAC cost; keep the frame tags aligned
        sel = np.sort(rng.choice(len(pool), 120_000, replace=False))
        pool, which = pool[sel], which[sel]
    total = len(pool)
    left = np.ones(total, dtype=bool)
    found: list[tuple[np.ndarray, float, np.ndarray]] = []
    for _ in range(max_planes):
        if left.sum() < 100:
            break
        normal, offset, inl_left = _ransac_plane(pool[left], threshold, iterations, rng)
        if inl_left.sum() < min_fraction * total:
            break
        inl = np.zeros(total, dtype=bool)
        inl[np.flatnonzero(left)[inl_left]] = True
        found.append((normal, offset, inl))
        left &= ~inl
    # one physical plane can come out as several parallel candidates (depth quantisation puts
    # a far wall on layers several centimetres apart): merge those within 8 thresholds
    merged: list[tuple[np.ndarray, float, np.ndarray]] = []
    for normal, offset, inl in found:
        for k, (n0, d0, i0) in enumerate(merged):
            s = float(np.sign(normal @ n0))
            if abs(normal @ n0) > np.cos(np.radians(5.0)) and abs(s * offset - d0) < 8 * threshold:
                union = i0 | inl
                n1, d1 = _fit_plane(pool[union])
                merged[k] = (n1, d1, union)
                break
        else:
            merged.append((normal, offset, inl))
    # parallel layers too thin to be candidates themselves join their plane: bins (width
    # threshold) of the signed distance within 8 thresholds holding >= 5 % of its points
    for k, (normal, offset, inl) in enumerate(merged):
        r = pool @ normal + offset
        near = left & (np.abs(r) < 8 * threshold)
        b = np.floor(r[near] / threshold).astype(np.int64)
        vals, counts = np.unique(b, return_counts=True)
        layer = np.isin(b, vals[counts >= 0.05 * inl.sum()])
        if layer.any():
            inl[np.flatnonzero(near)[layer]] = True
            left &= ~inl
            merged[k] = (normal, offset, inl)
    found = merged
    rest = pool[left]
    cell = 4.0 * threshold
    cands: list[BackgroundPlane] = []
    fronts: list[float] = []
    for normal, offset, inl in found:
        pts = pool[inl]
        # in-plane extent along the plane's two principal in-plane axes
        c = pts.mean(axis=0)
        _, _, vt = np.linalg.svd(pts - c, full_matrices=False)
        uv = (pts - c) @ vt[:2].T
        span = float(np.max(np.percentile(uv, 95, axis=0) - np.percentile(uv, 5, axis=0)))
        ref = _voxel_set(pts[which[inl] == 0], cell)
        over = []
        for k in range(1, len(picks)):
            vk = _voxel_set(pts[which[inl] == k], cell)
            if vk:
                over.append(len(vk & ref) / len(vk))
        static = float(np.median(over)) if over else 0.0
        band = max(threshold, float(np.percentile(np.abs(pts @ normal + offset), 97.5)))
        # a floor or wall has the rest of the scene on the camera's side of it; a flat part
        # of a subject has the subject's other parts (limbs, sides curving away) behind it
        side = np.sign(float(normal @ camera) + offset)
        # clear of the plane's own tail and depth-quantisation layers (the merge distance)
        off = np.abs(rest @ normal + offset) >= max(2.0 * band, 8.0 * threshold)
        front = float(np.mean(np.sign(rest[off] @ normal + offset) == side)) if off.any() else 0.0
        cands.append(BackgroundPlane(normal=normal, offset=offset, band=band,
                                     fraction=float(inl.mean()), span=span, static=static))
        fronts.append(front)
    # the subject: the largest connected piece of what the static, in-front planes leave
    rel = _band_distance([pl for pl, front in zip(cands, fronts)
                          if pl.static >= min_static and front >= min_front], pool)
    extents = []  # per sampled frame (a walking subject's pooled extent is the whole walk)
    for k in range(len(picks)):
        sel = (rel >= 1.0) & (which == k)
        sub = pool[sel]
        if len(sub) >= 10:
            clear = (rel[sel] >= 2.0).astype(np.float64)
            core = sub[_keep_near_largest(sub, 3.0 * voxel, 0.0, weight=clear)]
            extents.append(float(np.linalg.norm(core.max(axis=0) - core.min(axis=0))))
    subject_extent = float(np.median(extents)) if extents else 0.0
    planes = []
    for pl, front in zip(cands, fronts):
        ok = (pl.static >= min_static and front >= min_front
              and pl.span >= span_ratio * subject_extent)
        log.debug("background candidate: normal %s, %.0f%% of points, span %.2f m (subject "
                  "%.2f m), static %.2f, in front %.3f -> %s", np.round(pl.normal, 3),
                  100 * pl.fraction, pl.span, subject_extent, pl.static, front,
                  "removed" if ok else "kept")
        if ok:
            planes.append(pl)
    return planes, len(found)


def _keep_near_largest(points: np.ndarray, radius: float, reach: float,
                       weight: np.ndarray | None = None) -> np.ndarray:
    """Mask ``(N,)`` of the points in the largest connected piece (neighbours within about
    ``radius`` metres, :func:`_connected_pieces`; size = number of points, or the sum of
    ``weight (N,)``) or within ``reach`` times its bounding-box diagonal of it (fragments of the
    subject split off by occlusion stay; far speckle and clutter go)."""
    comp = _connected_pieces(points, radius)
    main = comp == int(np.argmax(np.bincount(comp, weights=weight)))
    core = points[main]
    limit = reach * float(np.linalg.norm(core.max(axis=0) - core.min(axis=0)))
    if limit <= 0:
        return main
    d = cKDTree(core).query(points[~main], distance_upper_bound=limit)[0]
    keep = main.copy()
    keep[np.flatnonzero(~main)[np.isfinite(d)]] = True
    return keep


def remove_background(seq: PointSequence, *, seed: int = 0,
                      **plane_options: Any) -> tuple[PointSequence, BackgroundReport]:
    """Remove static floor / wall planes and what they leave stranded, from every frame.

    A consumer depth camera sees the room as well as the subject; the paper (§3) crops it by
    hand. Here the static dominant planes of :func:`find_background_planes` are removed from
    every frame (points within each plane's band, and points within two bands that have no
    point clear of the planes within 3 spacings), and then, in each frame, the points that
    are neither in the largest connected piece (neighbours within 10 times the median point
    spacing: depth quantisation opens gaps of several spacings on sloped surfaces; size =
    its points farther than twice the band from every plane) nor within 10 % of its size of
    it: leftover plane speckle and far clutter. When no plane passes the tests the sequence is
    returned unchanged, so a recording that is already cropped is never touched.

    Parameters
    ----------
    seq
        The input frames, metres.
    seed
        RANSAC seed (same seed, same planes).
    **plane_options
        Passed to :func:`find_background_planes`.

    Returns
    -------
    (PointSequence, BackgroundReport)

    Raises
    ------
    EmptyFrameError
        If a frame has fewer than 10 points left (naming the frame).
    """
    planes, cand = find_background_planes(seq.frames, seed=seed, **plane_options)
    if not planes:
        return seq, BackgroundReport([], np.zeros(seq.n_frames), cand)
    out, removed = frames_like(seq.frames), []  # on disk when the input frames are
    for i, pts in enumerate(seq.frames):
        dist = _band_distance(planes, pts)
        sub, dist = pts[dist >= 1.0], dist[dist >= 1.0]
        if len(sub) >= 10:
            spacing = median_spacing(sub)
            # within two bands of a plane keep only points next to points clear of it (the
            # subject's feet stay, the plane's scattered noise tail goes)
            margin = dist < 2.0
            if margin.any() and (~margin).any():
                d = cKDTree(sub[~margin]).query(sub[margin], distance_upper_bound=3 * spacing)[0]
                ok = ~margin
                ok[np.flatnonzero(margin)[np.isfinite(d)]] = True
                sub, dist = sub[ok], dist[ok]
            # the subject's piece is the one with the most points clear of the planes (plane
            # speckle just outside a band can outnumber a far subject's points)
            clear = (dist >= 2.0).astype(np.float64)
            sub = sub[_keep_near_largest(sub, 10.0 * spacing, 0.1, weight=clear)]
        if len(sub) < 10:
            raise EmptyFrameError(
                f"only {len(sub)} point(s) left after removing the background planes; "
                "set [preprocess] background = \"keep\" and crop by hand", seq.source, frame=i)
        out.append(check_frame(sub, seq.source, i))
        removed.append(1.0 - len(sub) / len(pts))
    new = seq.with_frames(out)
    return new, BackgroundReport(planes, np.asarray(removed), cand)
