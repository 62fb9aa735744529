"""Input clean-up and the rest-pose point set surface (paper §3 and §4, last paragraphs).

§4: "we first reconstruct a point set surface from the initial frame. This point set is chosen
as the rest pose". Here: statistical outlier removal, a moving-least-squares projection of each
point onto the plane fitted to its neighbours (a point set surface in the sense of Alexa et al.),
and farthest-point resampling to ``M`` near-uniformly spaced points. No mesh is built, so a
fragmented single-view cloud stays fragmented rather than being bridged by a reconstruction.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy.spatial import cKDTree

from . import _core
from .errors import EmptyFrameError, InputError

if TYPE_CHECKING:
    from scipy.sparse import csr_matrix

    from .sequence import PointSequence

__all__ = [
    "BackgroundPlane",
    "BackgroundReport",
    "chamfer_misfit",
    "farthest_point_sampling",
    "find_background_planes",
    "knn_graph",
    "mls_project",
    "nearest_distances",
    "remove_background",
    "remove_sparse_frames",
    "remove_sparse_points",
    "remove_statistical_outliers",
    "rest_surface",
    "surface_cover",
]

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


def remove_sparse_points(points: np.ndarray, k: int = 10, ratio: float = 4.0) -> np.ndarray:
    """Keep points whose distance to their ``k``-th nearest neighbour is at most ``ratio``
    times the median of that distance over all points.

    A depth camera samples a surface at about one point per pixel, so the ``k``-th neighbour
    distance on the subject varies little (with depth and viewing angle). Flying pixels (a
    sparse curtain up to tens of centimetres behind each silhouette edge) and uniform outliers
    lie 5-10x farther apart. :func:`remove_statistical_outliers` thresholds at ``mean + ratio
    x std`` of a distribution these points inflate themselves and keeps about half of them;
    farthest-point sampling then picks them first, since each is far from every other point.
    The median is not moved by a few percent of them.

    Parameters
    ----------
    points
        ``(N, 3)`` float64, metres.
    k
        Neighbour rank (>= 1).
    ratio
        Threshold as a multiple of the median ``k``-th neighbour distance (> 1); ``0`` keeps
        every point.

    Returns
    -------
    ``(N', 3)`` kept points, in input order.
    """
    n = len(points)
    if ratio <= 0 or n <= k + 1:
        return points.copy()
    # the k-th neighbour other than the point itself: rank k + 1 counting the point
    p = np.ascontiguousarray(points, dtype=np.float64)
    dk = _core.kth_nn_distances(p, p, k + 1)
    return points[dk <= ratio * np.median(dk)]


def remove_sparse_frames(seq: PointSequence, k: int = 10, ratio: float = 4.0,
                         min_points: int = 10) -> tuple[PointSequence, np.ndarray]:
    """:func:`remove_sparse_points` on every frame of a sequence.

    Parameters
    ----------
    seq
        The input frames, ``(N_t, 3)`` metres each.
    k, ratio
        As in :func:`remove_sparse_points` (``ratio = 0`` returns ``seq`` itself).
    min_points
        Fewer points left in a frame is an error.

    Returns
    -------
    (PointSequence, ndarray)
        The cleaned sequence (same source, names and format) and the ``(F,)`` fraction of
        each frame's points removed.

    Raises
    ------
    EmptyFrameError
        If a frame keeps fewer than ``min_points`` points (naming the frame).
    """
    if ratio <= 0:
        return seq, np.zeros(seq.n_frames)
    out, removed = [], np.zeros(seq.n_frames)
    for i, pts in enumerate(seq.frames):
        kept = remove_sparse_points(pts, k, ratio)
        if len(kept) < min_points:
            raise EmptyFrameError(
                f"only {len(kept)} point(s) left after removing sparse points (fewer than "
                f"{min_points}); set [preprocess] sparse_ratio = 0 to keep them", seq.source,
                frame=i)
        out.append(kept)
        removed[i] = 1.0 - len(kept) / max(len(pts), 1)
    return seq.with_frames(out), removed


def surface_cover(frames: Sequence[np.ndarray], spacing_factor: float = 4.0) -> np.ndarray:
    """How much surface each frame shows: its occupied cells of one voxel grid.

    A depth camera's point density falls with the square of the distance, so a point count
    measures distance as much as visible surface; the number of occupied voxels of a size
    well above every frame's point spacing does not (it is the visible area over the voxel's
    face, for a surface seen at every voxel it crosses). The voxel edge is ``spacing_factor``
    times the largest median nearest-neighbour spacing of up to 10 frames spread over the
    sequence. Scattered outliers add a cell each: remove them first
    (:func:`remove_sparse_frames`).

    Parameters
    ----------
    frames
        ``F`` arrays ``(N_t, 3)``, metres.
    spacing_factor
        Voxel edge over the point spacing (> 1).

    Returns
    -------
    ``(F,)`` int64 occupied-voxel counts.
    """
    if not len(frames):
        return np.zeros(0, dtype=np.int64)
    probe = np.unique(np.linspace(0, len(frames) - 1, min(10, len(frames))).astype(int))
    voxel = spacing_factor * max(median_spacing(frames[i]) for i in probe)
    if not voxel > 0:  # every probed frame has coincident points
        return np.array([len(f) for f in frames], dtype=np.int64)
    return np.array([_occupied_cells(np.asarray(f), voxel) for f in frames], dtype=np.int64)


def _occupied_cells(points: np.ndarray, voxel: float) -> int:
    """Number of distinct cells of edge ``voxel`` (metres) that ``points (N, 3)`` occupy: the
    cell indices packed into one integer per point (``np.unique(..., axis=0)`` on the index
    triples counts the same, several times slower)."""
    if len(points) == 0:
        return 0
    idx = np.floor(points / voxel).astype(np.int64)
    idx -= idx.min(axis=0)
    span = idx.max(axis=0) + 1
    return len(np.unique((idx[:, 0] * span[1] + idx[:, 1]) * span[2] + idx[:, 2]))


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


def estimate_normals(
    points: np.ndarray,
    radius: float,
    camera: tuple[float, float, float] = (0.0, 0.0, 0.0),
    source: np.ndarray | None = None,
) -> np.ndarray:
    """Unit surface normals of a single-view cloud, facing the camera (Rust, parallel).

    Parameters
    ----------
    points
        ``(n, 3)`` query points, metres.
    radius
        The least-squares plane of each query is fitted to the ``source`` points within this
        distance, metres.
    camera
        Camera centre in the points' frame, metres: each normal is flipped to point towards
        it, as every surface a depth camera sees faces it.
    source
        ``(N, 3)`` points the planes are fitted to, metres (default ``points``).

    Returns
    -------
    np.ndarray
        ``(n, 3)`` float64 unit normals; a zero row where fewer than 3 source points (or only
        collinear ones) lie within ``radius``.
    """
    pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    src = pts if source is None else np.ascontiguousarray(source, dtype=np.float64)
    cam = tuple(float(v) for v in camera)
    return _core.surface_normals(pts, src, float(radius), cam)


def farthest_point_sampling(points: np.ndarray, n: int, seed: int = 0) -> np.ndarray:
    """Indices of ``n`` points chosen by farthest-point sampling (near-uniform spacing).

    The first index is drawn from ``numpy.random.default_rng(seed)``; each next one is the
    point farthest from those chosen (Rust, ``_core.farthest_point_sampling``, the same
    arithmetic as the numpy loop it replaced, so the same indices).

    Parameters
    ----------
    points
        ``(m, 3)`` points, metres.
    n
        Number of samples; ``n >= m`` returns ``arange(m)``.
    seed
        Seed of the first index.

    Returns
    -------
    np.ndarray
        ``(min(n, m),)`` int64 indices into ``points``.
    """
    m = len(points)
    if n >= m:
        return np.arange(m)
    first = int(np.random.default_rng(seed).integers(m))
    return _core.farthest_point_sampling(np.ascontiguousarray(points, dtype=np.float64),
                                         int(n), first)


#: the cap that is no cap: the largest finite float (its square is infinite, above any distance)
_NO_CAP = float(np.finfo(np.float64).max)


def nearest_distances(queries: np.ndarray, points: np.ndarray,
                      cap: float | None = None) -> np.ndarray:
    """Distance from each query to its nearest point, metres (Rust grid, exact).

    Parameters
    ----------
    queries
        ``(n, 3)`` query points, metres.
    points
        ``(N, 3)`` points searched, metres.
    cap
        Distances are returned as ``min(d, cap)`` (metres, > 0); the search stops at the
        cap. ``None``: no cap (the largest float).

    Returns
    -------
    np.ndarray
        ``(n,)`` float64 distances, metres (``cap`` for every query when ``N = 0``).
    """
    return _core.capped_nn_distances(np.ascontiguousarray(queries, dtype=np.float64),
                                     np.ascontiguousarray(points, dtype=np.float64),
                                     _NO_CAP if cap is None else float(cap))


def chamfer_misfit(template: np.ndarray, data: np.ndarray, trunc: float) -> float:
    """How well a posed template explains a frame: the symmetric, truncated chamfer distance.

    Mean over template points of the distance to the nearest data point plus the mean over
    data points of the distance to the nearest template point, each distance capped at
    ``trunc`` so that outliers and parts one side does not see count a bounded amount.
    Exact nearest distances on a uniform grid in Rust (``_core.chamfer_misfit``; the same
    values as a k-d tree's, tested against ``scipy.spatial.cKDTree``), summed in point
    order, so the value does not depend on the thread count.

    Parameters
    ----------
    template
        ``(M, 3)`` posed template points, metres (``M >= 1``).
    data
        ``(N, 3)`` observed points of the frame, metres (``N >= 1``).
    trunc
        Cap of each nearest-point distance, metres (> 0).

    Returns
    -------
    float
        The misfit, metres (0 when each set lies on the other; at most ``2 * trunc``).
    """
    return float(_core.chamfer_misfit(np.ascontiguousarray(template, dtype=np.float64),
                                      np.ascontiguousarray(data, dtype=np.float64),
                                      float(trunc)))


def rest_surface(
    points: np.ndarray,
    n_points: int = 2000,
    *,
    sor_neighbors: int = 20,
    sor_std_ratio: float = 2.0,
    mls_neighbors: int = 16,
    seed: int = 0,
    sparse_neighbors: int = 10,
    sparse_ratio: float = 4.0,
) -> np.ndarray:
    """The rest-pose point set surface: ``(M, 3)`` float64, metres, ``M = min(n_points, N')``.

    Statistical outlier removal, then :func:`remove_sparse_points` (``sparse_ratio = 0``
    turns it off), farthest-point sampling and the MLS projection.

    Raises
    ------
    InputError
        If fewer than 10 points survive the outlier removal.
    """
    pts = np.ascontiguousarray(points, dtype=np.float64)
    clean = remove_statistical_outliers(pts, sor_neighbors, sor_std_ratio)
    clean = remove_sparse_points(clean, sparse_neighbors, sparse_ratio)
    if len(clean) < 10:
        raise InputError(f"rest frame has only {len(clean)} points after outlier removal")
    sel = clean[farthest_point_sampling(clean, n_points, seed)]
    if mls_neighbors > 0:
        sel = mls_project(sel, mls_neighbors, source=clean)
    log.debug("rest surface: %d -> %d clean -> %d points", len(pts), len(clean), len(sel))
    return np.ascontiguousarray(sel)


# ---- background: static dominant planes (floor, walls) ------------------------------------


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


#: cell size of :func:`_connected_pieces`, as a fraction of the connection radius
PIECE_CELL_FRACTION = 0.25


def _connected_pieces(points: np.ndarray, radius: float) -> np.ndarray:
    """Connected-piece label ``(N,)`` of each point, two points being neighbours when they are
    within about ``radius`` metres.

    The graph is built on one representative per occupied cubic cell of side
    ``PIECE_CELL_FRACTION * radius`` (the centroid of its points; points of one cell are
    always in one piece), with edges between representatives within ``radius``; every point
    lies within ``sqrt(3) / 4 = 0.43`` radius of its representative, so the effective radius
    is ``radius`` give or take that much at each end. The exact point graph has
    ``O(N (radius / spacing)^2)`` edges: on 150k-point frames of a room scene at ``radius`` =
    10 point spacings it took 0.7-1.4 s a frame against 0.13-0.16 s here, with the same
    largest piece but for 0-4 points (benchmarks/bench_background.py).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    if not np.isfinite(radius) or radius <= 0.0:  # only coincident points are neighbours
        return np.unique(points, axis=0, return_inverse=True)[1].ravel()
    cell = PIECE_CELL_FRACTION * radius
    ijk = np.floor((points - points.min(axis=0)) / cell).astype(np.int64)
    dims = ijk.max(axis=0) + 1
    if float(np.prod(dims.astype(np.float64))) < 2.0 ** 62:  # one int64 key per cell
        _, inv = np.unique((ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2],
                           return_inverse=True)
    else:
        _, inv = np.unique(ijk, axis=0, return_inverse=True)
    inv = inv.ravel()
    n_cells = int(inv.max()) + 1
    cnt = np.bincount(inv, minlength=n_cells).astype(np.float64)
    reps = np.stack([np.bincount(inv, weights=points[:, k], minlength=n_cells)
                     for k in range(3)], axis=1) / cnt[:, None]
    pairs = cKDTree(reps).query_pairs(radius, output_type="ndarray")
    g = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])),
                   shape=(n_cells, n_cells))
    return connected_components(g, directed=False)[1][inv]


def connected_pieces_exact(points: np.ndarray, radius: float) -> np.ndarray:
    """Reference for :func:`_connected_pieces`: connected-piece labels ``(N,)`` of the exact
    graph of every point pair within ``radius`` metres (the tests and
    ``benchmarks/bench_background.py`` compare against it)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n = len(points)
    pairs = cKDTree(points).query_pairs(radius, output_type="ndarray")
    g = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    return connected_components(g, directed=False)[1]


def median_spacing(points: np.ndarray) -> float:
    """Median nearest-neighbour distance of ``points (N, 3)``, metres."""
    return float(np.median(_nn_distances(points)))


def mean_spacing(points: np.ndarray) -> float:
    """Mean nearest-neighbour distance of ``points (N, 3)``, metres (the rest points' spacing
    that the registration's and the tracker's length scales refer to)."""
    return float(np.mean(_nn_distances(points)))


def knn_graph(points: np.ndarray, k: int = 8, cap: float | None = None) -> csr_matrix:
    """The ``k``-nearest-neighbour graph of ``points (N, 3)`` as a sparse ``(N, N)`` CSR matrix
    of edge lengths in metres, each point to its ``min(k, N - 1)`` nearest other points (for
    ``scipy.sparse.csgraph``, read as undirected). With ``cap``, edges longer than ``cap`` times
    the median ``k``-th neighbour distance are left out (no bridges across gaps)."""
    from scipy.sparse import csr_matrix

    n = len(points)
    d, idx = cKDTree(points).query(points, k=min(k + 1, n))
    d, idx = d[:, 1:], idx[:, 1:]
    ok = np.ones(d.size, dtype=bool) if cap is None else \
        (d <= cap * float(np.median(d[:, -1]))).ravel()
    rows = np.repeat(np.arange(n), d.shape[1])[ok]
    return csr_matrix((d.ravel()[ok], (rows, idx.ravel()[ok])), shape=(n, n))


def _nn_distances(points: np.ndarray) -> np.ndarray:
    """Distance of each of ``points (N, 3)`` to its nearest other point, ``(N,)`` metres."""
    return cKDTree(points).query(points, k=2)[0][:, 1]


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
    out, removed = [], []
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
        out.append(sub)
        removed.append(1.0 - len(sub) / len(pts))
    new = seq.with_frames(out)
    return new, BackgroundReport(planes, np.asarray(removed), cand)
