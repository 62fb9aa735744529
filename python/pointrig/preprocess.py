"""Per-sequence input clean-up and the rest-pose point set surface (paper §3 and §4, last
paragraphs).

:func:`remove_sparse_frames` takes sparse points (flying pixels, outliers) out of every frame
before step 1 (``[preprocess] sparse_*``). :func:`rest_surface` makes the rest pose. §4: "we
first reconstruct a point set surface from the initial frame. This point set is chosen as the
rest pose". Here: statistical outlier removal, a moving-least-squares projection of each point
onto the plane fitted to its neighbours (a point set surface in the sense of Alexa et al.), and
farthest-point resampling to ``M`` near-uniformly spaced points. No mesh is built, so a
fragmented single-view cloud stays fragmented rather than being bridged by a reconstruction.
The point-cloud geometry these use is :mod:`pointrig.geometry`; background planes are removed
by :mod:`pointrig.background`.
"""

from __future__ import annotations

import logging

import numpy as np

from . import _core
from .errors import EmptyFrameError, InputError
from .geometry import (
    farthest_point_sampling,
    mls_project,
    nearest_distances,
    remove_sparse_points,
    remove_statistical_outliers,
)
from .sequence import PointSequence, check_frame, frames_like

__all__ = ["OUTLIER_FACTOR", "OUTLIER_SUSPECT", "outlier_fraction", "remove_sparse_frames",
           "rest_surface"]

#: A point "looks like an outlier" when its k-th neighbour distance exceeds this many times the
#: frame's 10th percentile of that distance (a surface seen by a depth camera: about 1.25 times
#: at the median, so a few percent of a clean frame's points exceed 3 times).
OUTLIER_FACTOR = 3.0
#: A frame whose points look like outliers in more than this fraction after the clean-up is
#: mostly outliers: its median neighbour distance, the clean-up's reference, lies among them.
OUTLIER_SUSPECT = 0.2

log = logging.getLogger(__name__)


def _kth_distances(points: np.ndarray, k: int) -> np.ndarray:
    """``(N,)`` distance of each point to its ``k``-th nearest other point, metres."""
    p = np.ascontiguousarray(points, dtype=np.float64)
    return _core.kth_nn_distances(p, p, k + 1)


def outlier_fraction(points: np.ndarray, k: int = 10) -> float:
    """Fraction of the ``(N, 3)`` points (metres) that look like sparse outliers: their
    ``k``-th neighbour distance exceeds :data:`OUTLIER_FACTOR` times the frame's 10th
    percentile of it. The low percentile stays on the subject's surface as long as the surface
    holds a good part of the points, where the median (the clean-up's reference) does not."""
    if len(points) <= k + 1:
        return 0.0
    return _fraction(_kth_distances(points, k))


def _fraction(dk: np.ndarray) -> float:
    """:func:`outlier_fraction` from the ``(N,)`` ``k``-th neighbour distances."""
    return float(np.mean(dk > OUTLIER_FACTOR * np.quantile(dk, 0.1)))


def _kept_fraction(points: np.ndarray, dk: np.ndarray, keep: np.ndarray, k: int) -> float:
    """:func:`outlier_fraction` of ``points[keep]`` from ``dk (N,)``, the ``k``-th neighbour
    distances among all ``points (N, 3)`` (:func:`_kept_distances`)."""
    if int(keep.sum()) <= k + 1:
        return 0.0
    return _fraction(_kept_distances(points, dk, keep, k))


def _kept_distances(points: np.ndarray, dk: np.ndarray, keep: np.ndarray, k: int
                    ) -> np.ndarray:
    """``(N',)`` the ``k``-th neighbour distance (metres) of each of ``points[keep]`` among
    those points alone, from ``dk (N,)``, the distances among all ``points (N, 3)``: a kept
    point's distance changes only where a removed point lies within it, and only those points
    are searched again, so the values are those of searching every kept point (more than
    ``k + 1`` kept)."""
    kept = np.ascontiguousarray(points[keep], dtype=np.float64)
    d = dk[keep].copy()
    gone = points[~keep]
    if len(gone) and d.max() > 0:
        again = nearest_distances(kept, gone, float(d.max())) <= d
        if again.any():
            d[again] = _core.kth_nn_distances(np.ascontiguousarray(kept[again]), kept, k + 1)
    return d


def remove_sparse_frames(seq: PointSequence, k: int = 10, ratio: float = 4.0,
                         min_points: int = 10, report: dict | None = None
                         ) -> tuple[PointSequence, np.ndarray]:
    """:func:`remove_sparse_points` on every frame of a sequence.

    A frame that still looks mostly like outliers afterwards (:func:`outlier_fraction` above
    :data:`OUTLIER_SUSPECT`: a heavy uniform scatter moved the median neighbour distance the
    clean-up measures against) is cleaned again against the median of its dense points only.
    Other frames are cleaned exactly as :func:`remove_sparse_points` does.

    Parameters
    ----------
    seq
        The input frames, ``(N_t, 3)`` metres each.
    k, ratio
        As in :func:`remove_sparse_points` (``ratio = 0`` returns ``seq`` itself).
    min_points
        Fewer points left in a frame is an error.
    report
        If given, filled with ``"suspect"``: ``(F,)`` bool, the frames that looked mostly like
        outliers after the usual clean-up, and ``"outliers_left"``: ``(F,)`` the fraction of
        each cleaned frame's points that still look like outliers.

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
    suspect, left = np.zeros(seq.n_frames, bool), np.zeros(seq.n_frames)
    if report is not None:
        report.update(suspect=suspect, outliers_left=left)
    if ratio <= 0:
        left[:] = [outlier_fraction(p, k) for p in seq.frames] if report is not None else 0.0
        return seq, np.zeros(seq.n_frames)
    out, removed = frames_like(seq.frames), np.zeros(seq.n_frames)  # on disk if the input is
    for i, pts in enumerate(seq.frames):
        if len(pts) <= k + 1:  # too few to judge: kept whole, as remove_sparse_points does
            kept = pts.copy()
        else:
            # remove_sparse_points, and the fraction left from the same neighbour distances
            dk = _kth_distances(pts, k)
            keep = dk <= ratio * np.median(dk)
            left[i] = _kept_fraction(pts, dk, keep, k)
            if left[i] > OUTLIER_SUSPECT:
                # cleaned again against the median of the points that do not look like
                # outliers: a frame mostly of a uniform scatter, whose median lies among them
                suspect[i] = True
                keep = dk <= ratio * np.median(dk[dk <= OUTLIER_FACTOR * np.quantile(dk, 0.1)])
                left[i] = _kept_fraction(pts, dk, keep, k)
            kept = pts[keep]
        if len(kept) < min_points:
            raise EmptyFrameError(
                f"only {len(kept)} point(s) left after removing sparse points (fewer than "
                f"{min_points}); set [preprocess] sparse_ratio = 0 to keep them", seq.source,
                frame=i)
        out.append(check_frame(kept, seq.source, i))
        removed[i] = 1.0 - len(kept) / max(len(pts), 1)
    return seq.with_frames(out), removed


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
