"""Point-cloud geometry the steps share (metres throughout).

Nearest-neighbour distances and spacings, the truncated chamfer misfit that scores a
registration against the observed frames (§4), normals, farthest-point sampling and the
moving-least-squares projection that make the rest-pose point set surface (§4, last
paragraph), ``k``-nearest-neighbour graphs (geodesic distances), connected pieces, the
statistical and sparse-point outlier filters of the input clean-up (§3), and the surface cover
that picks a rest frame.
The heavy kernels run in the Rust core (``_core``).
"""

from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial import cKDTree

from . import _core

if TYPE_CHECKING:
    from scipy.sparse import csr_matrix

__all__ = [
    "chamfer_misfit",
    "connected_pieces_exact",
    "estimate_normals",
    "farthest_point_sampling",
    "knn_graph",
    "mean_spacing",
    "median_spacing",
    "mls_project",
    "nearest_distances",
    "nearest_distances_grouped",
    "remove_sparse_points",
    "remove_statistical_outliers",
    "keep_normals",
    "reuse_normals",
    "surface_cover",
]


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
    if not _NORMALS.active():
        return _core.surface_normals(pts, src, float(radius), cam)
    key = (_digest(pts), None if source is None else _digest(src), float(radius), cam)
    found = _NORMALS.get(key)
    if found is not None:
        return found.copy()
    out = _core.surface_normals(pts, src, float(radius), cam)
    _NORMALS.put(key, out.copy())
    return out


def _digest(a: np.ndarray) -> tuple[tuple[int, ...], bytes]:
    """The shape and a 128-bit hash of the bytes of the contiguous float64 array ``a``."""
    return a.shape, hashlib.blake2b(memoryview(a).cast("B"), digest_size=16).digest()


class _NormalsMemo:
    """The normals :func:`estimate_normals` computed inside :func:`reuse_normals`, by the
    content of their points and source, radius and camera; at most ``budget`` bytes, the
    oldest dropped first."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.depth = 0
        self.budget = 0
        self.store: OrderedDict[tuple, np.ndarray] = OrderedDict()
        self.nbytes = 0

    def active(self) -> bool:
        return self.depth > 0

    def get(self, key: tuple) -> np.ndarray | None:
        with self.lock:
            return self.store.get(key)

    def put(self, key: tuple, value: np.ndarray) -> None:
        with self.lock:
            if self.depth == 0 or key in self.store or value.nbytes > self.budget:
                return
            self.store[key] = value
            self.nbytes += value.nbytes
            while self.nbytes > self.budget:
                self.nbytes -= self.store.popitem(last=False)[1].nbytes

    def keep(self, radius: float) -> None:
        """Drop the normals of every radius but ``radius``."""
        with self.lock:
            for key in [k for k in self.store if k[2] != radius]:
                self.nbytes -= self.store.pop(key).nbytes

    def enter(self, max_bytes: int) -> None:
        """A :func:`reuse_normals` block opens: the largest budget of those open applies."""
        with self.lock:
            self.depth += 1
            self.budget = max(self.budget, max_bytes)

    def leave(self) -> None:
        """A block ends; the outermost one releases every kept normal."""
        with self.lock:
            self.depth -= 1
            if self.depth == 0:
                self.store.clear()
                self.nbytes = 0
                self.budget = 0


_NORMALS = _NormalsMemo()


def keep_normals(radius: float) -> None:
    """Drop the kept normals (:func:`reuse_normals`) of every radius but ``radius`` (metres):
    those of the rest-frame candidates that were not chosen."""
    _NORMALS.keep(float(radius))


@contextmanager
def reuse_normals(max_bytes: int = 256 << 20) -> Iterator[None]:
    """Inside this block, :func:`estimate_normals` returns the normals it already computed
    for the same points, source, radius and camera (the same values, computed once): the
    pipeline estimates each frame's normals in several places (step 1 and its refinement, the
    two rounds of step 3). At most ``max_bytes`` of normals are kept (the oldest dropped
    first; the largest budget of the blocks open at once applies); they are released when the
    outermost block ends."""
    _NORMALS.enter(int(max_bytes))
    try:
        yield
    finally:
        _NORMALS.leave()


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


def nearest_distances_grouped(queries: np.ndarray, query_offsets: np.ndarray,
                              points: np.ndarray, point_offsets: np.ndarray,
                              cap: float) -> np.ndarray:
    """:func:`nearest_distances` of ``G`` groups at once (Rust, the groups side by side).

    Parameters
    ----------
    queries
        ``(n, 3)`` the groups' queries one after another, metres.
    query_offsets
        ``(G + 1,)`` group ``g``'s queries are rows ``query_offsets[g]:query_offsets[g + 1]``.
    points
        ``(N, 3)`` the groups' points searched, one after another, metres.
    point_offsets
        ``(G + 1,)`` group ``g``'s points are rows ``point_offsets[g]:point_offsets[g + 1]``.
    cap
        Distances are returned as ``min(d, cap)`` (metres, > 0).

    Returns
    -------
    np.ndarray
        ``(n,)`` float64 distances, metres, each query's to the nearest point of its own group
        (``cap`` for a group without points); the same values as one call per group.
    """
    return _core.capped_nn_distances_grouped(
        np.ascontiguousarray(queries, dtype=np.float64),
        np.ascontiguousarray(query_offsets, dtype=np.int64),
        np.ascontiguousarray(points, dtype=np.float64),
        np.ascontiguousarray(point_offsets, dtype=np.int64), float(cap))


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
