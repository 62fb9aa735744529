"""Step 1: non-rigid point-set registration of the whole sequence (paper §4, Algorithm 1).

The rest-pose point set surface ``Y`` (M points, from the rest frame) is deformed by an
embedded deformation graph (Eq. 2) to fit every frame with the GMM/EM of Eqs. 1-12; frames are
registered in order, each starting from the previous result, so point ``m`` corresponds
across frames. The E-step (Eq. 4), the M-step solvers (the paper's node sweeps, Eqs. 9 and 11,
or a joint Gauss-Newton step) and sigma^2 (Eq. 12) run in Rust (``pointrig._core``).

Deviations from the plain §4 (each selectable in :class:`~pointrig.config.RegistrationConfig`,
whose ``paper()`` turns them off; derivations in docs/registration.md): joint Gauss-Newton
M-step, beta_smooth relative to the data term, a data-driven coarse sigma^2 start per frame,
rigid pre-alignment, constant-velocity prediction, normal agreement, a sigma^2 floor,
tracking-loss detection with a coarse retry, the choice of the rest frame and the refinement
from the skeleton (:func:`refine_registration`).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import threading
import zipfile
import zlib
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from . import _core
from .config import RegistrationConfig, pool_size
from .errors import ConfigError, FormatError, InputError
from .geometry import (
    chamfer_misfit,
    estimate_normals,
    farthest_point_sampling,
    keep_normals,
    knn_graph,
    mean_spacing,
    nearest_distances,
    surface_cover,
)
from .io import write_npz
from .preprocess import rest_surface
from .sequence import PointSequence

__all__ = [
    "PartialRegistration",
    "DeformationGraph",
    "RegistrationResult",
    "build_graph",
    "cache_key",
    "node_transforms_from_points",
    "refine_registration",
    "register_sequence",
]

log = logging.getLogger(__name__)

_FORMAT_VERSION = 1
#: RegistrationConfig fields that do not change :func:`register_sequence`'s result
_NOT_IN_KEY = frozenset({"refine_rounds", "workers"})


@dataclass
class RegistrationResult:
    """Output of step 1.

    Attributes
    ----------
    rest_points
        ``(M, 3)`` rest-pose point set surface, metres, input coordinates.
    points
        ``(F, M, 3)`` registered points ``Y^t`` (point ``m`` corresponds across frames).
    sigma2
        ``(F,)`` final sigma^2 per frame, m^2.
    iterations
        ``(F,)`` EM iterations per frame.
    energy
        ``(F,)`` final Eq. 8a energy per frame.
    params
        The registration parameters (``dataclasses.asdict(config)``).
    matched
        ``(F,)`` matched fraction ``N_p / N`` of the last E-step per frame.
    key
        :func:`cache_key` of the input and parameters ("" when unknown).
    """

    rest_points: np.ndarray
    points: np.ndarray
    sigma2: np.ndarray
    iterations: np.ndarray
    energy: np.ndarray
    params: dict[str, Any]
    matched: np.ndarray = field(default_factory=lambda: np.zeros(0))
    key: str = ""

    def save(self, path: str | Path) -> None:
        """Write an ``.npz`` checkpoint atomically."""
        write_npz(
            path,
            rest_points=self.rest_points,
            points=self.points,
            sigma2=self.sigma2,
            iterations=self.iterations,
            energy=self.energy,
            matched=self.matched,
            params=np.array(json.dumps(self.params, sort_keys=True)),
            cache_key=np.array(self.key),
            format_version=np.array(_FORMAT_VERSION),
        )

    @classmethod
    def load(cls, path: str | Path) -> RegistrationResult:
        """Read a checkpoint written by :meth:`save`.

        Raises
        ------
        FormatError
            If the file is not a registration checkpoint.
        """
        try:
            with np.load(path, allow_pickle=False) as z:
                res = cls(
                    rest_points=z["rest_points"],
                    points=z["points"],
                    sigma2=z["sigma2"],
                    iterations=z["iterations"],
                    energy=z["energy"],
                    params=json.loads(str(z["params"])),
                    matched=z["matched"] if "matched" in z else np.zeros(0),
                    key=str(z["cache_key"]) if "cache_key" in z else "",
                )
        except (KeyError, ValueError, OSError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
            raise FormatError(f"not a registration checkpoint: {exc}", str(path)) from None
        for name in ("rest_points", "points", "sigma2"):
            arr = np.asarray(getattr(res, name))
            if arr.dtype.kind != "f" or not np.isfinite(arr).all():
                raise FormatError(f"registration checkpoint holds non-finite or non-float "
                                  f"values in {name!r}", str(path))
        return res


@dataclass
class DeformationGraph:
    """Embedded deformation graph (Eq. 2): nodes ``(J, 3)``, point-node indices and weights
    ``(M, k)``, directed node edges ``(E, 2)`` for Eq. 6."""

    rest: np.ndarray
    nodes: np.ndarray
    pn_idx: np.ndarray
    pn_w: np.ndarray
    edges: np.ndarray
    normals: np.ndarray | None = None  # (M, 3) unit rest-pose normals, or None

    def native(self) -> Any:
        return _core.DeformGraph(self.rest, self.nodes, self.pn_idx, self.pn_w, self.edges,
                                 self.normals)


def build_graph(rest: np.ndarray, config: RegistrationConfig) -> DeformationGraph:
    """``n_nodes`` nodes sampled uniformly from the rest points (farthest-point sampling);
    each point driven by its ``k_point_nodes`` nearest nodes with
    Sumner et al.'s weights ``(1 - d / d_max)^2`` (normalised); node edges by Euclidean k-NN,
    so separate fragments of a single-view cloud stay connected, minus the edges whose path
    over the rest points is more than ``node_geodesic_ratio`` times longer (parts that only
    touch in the rest pose)."""
    rest = np.ascontiguousarray(rest, dtype=np.float64)
    node_idx = farthest_point_sampling(rest, min(config.n_nodes, len(rest)), config.seed)
    nodes = np.ascontiguousarray(rest[node_idx])
    j = len(nodes)
    k = max(1, min(config.k_point_nodes, j))
    tree = cKDTree(nodes)
    d, idx = tree.query(rest, k=min(k + 1, j))
    d = np.atleast_2d(d.reshape(len(rest), -1))
    idx = np.atleast_2d(idx.reshape(len(rest), -1))
    if d.shape[1] > k:
        dmax = d[:, k:k + 1]
        d, idx = d[:, :k], idx[:, :k]
    else:
        dmax = d[:, -1:] * 1.5 + 1e-12
    w = np.clip(1.0 - d / np.maximum(dmax, 1e-12), 0.0, None) ** 2
    bad = w.sum(1) <= 1e-12
    w[bad] = 1.0
    w /= w.sum(1, keepdims=True)
    kn = min(config.k_node_neighbors, j - 1)
    if kn > 0:
        _, nidx = tree.query(nodes, k=kn + 1)
        src = np.repeat(np.arange(j), kn)
        dst = nidx[:, 1:].reshape(-1)
        edges = np.stack([src, dst], axis=1)
        edges = edges[edges[:, 0] != edges[:, 1]]
        if config.node_geodesic_ratio > 0 and len(edges):
            edges = _geodesic_filter(rest, np.asarray(node_idx), edges,
                                     config.node_geodesic_ratio)
    else:
        edges = np.zeros((0, 2), dtype=np.int64)
    return DeformationGraph(
        rest,
        nodes,
        np.ascontiguousarray(idx, dtype=np.int64),
        np.ascontiguousarray(w),
        np.ascontiguousarray(edges, dtype=np.int64),
    )


def _geodesic_filter(rest: np.ndarray, node_idx: np.ndarray, edges: np.ndarray,
                     ratio: float, k: int = 8) -> np.ndarray:
    """Node edges ``(E, 2)`` (nodes are the rest points ``node_idx``) whose geodesic length
    (shortest path over the k-NN graph of the rest points, neighbours within twice the median
    k-th neighbour distance) is at most ``ratio`` times their Euclidean length, plus edges
    between nodes the graph does not connect (fragments)."""
    from scipy.sparse.csgraph import connected_components, dijkstra

    G = knn_graph(rest, k, cap=2.0)
    eu = np.linalg.norm(rest[node_idx[edges[:, 0]]] - rest[node_idx[edges[:, 1]]], axis=1)
    src = np.unique(edges[:, 0])
    geo = dijkstra(G, directed=False, indices=node_idx[src], limit=ratio * float(eu.max()) + 1e-12)
    g = geo[np.searchsorted(src, edges[:, 0]), node_idx[edges[:, 1]]]
    # unreachable within the limit: a separate fragment (keep) or a long detour (drop)
    comp = connected_components(G, directed=False)[1]
    same = comp[node_idx[edges[:, 0]]] == comp[node_idx[edges[:, 1]]]
    keep = (g <= ratio * eu + 1e-12) | ~same
    return edges[keep]


def cache_key(seq: PointSequence, config: RegistrationConfig) -> str:
    """SHA-256 of the input frames and the registration parameters (checkpoint key)."""
    h = hashlib.sha256()
    h.update(f"pointrig-registration-v{_FORMAT_VERSION}".encode())
    # refine_rounds acts after steps 2-3 (refine_registration), not on this result, and the
    # worker count does not change it
    params = {k: v for k, v in dataclasses.asdict(config).items() if k not in _NOT_IN_KEY}
    h.update(json.dumps(params, sort_keys=True).encode())
    for f in seq.frames:
        a = np.ascontiguousarray(f, dtype=np.float64)
        h.update(np.array(a.shape, dtype=np.int64).tobytes())
        h.update(a.tobytes())
    return h.hexdigest()


def resolve_rest_frame(config: RegistrationConfig, n_frames: int,
                       frames: Sequence[np.ndarray] | None = None) -> int:
    """Index of the rest frame: ``config.rest_frame`` if an index; for "fit", its first
    candidate (:func:`rest_candidates`): of the frames of the middle half of the sequence
    (``F // 4`` to ``F - F // 4 - 1``) whose points cover within
    ``config.rest_cover_tolerance`` of the most surface any of them covers
    (:func:`pointrig.geometry.surface_cover`), the one nearest the middle (the shortest
    chains of frame-to-frame registrations).

    Parameters
    ----------
    config
        The step-1 parameters.
    n_frames
        ``F``.
    frames
        The ``F`` frames, ``(N_t, 3)`` metres each; needed for "fit" only.

    Raises
    ------
    ConfigError
        If the index is outside ``[0, n_frames)``, or "fit" without ``frames``.
    """
    rf = config.rest_frame
    if rf == "fit":
        if frames is None or len(frames) != n_frames:
            raise ConfigError("[registration] rest_frame 'fit' needs the frames")
        return _nearest_middle(_cover_candidates(config, frames), n_frames)
    if not 0 <= rf < n_frames:
        raise ConfigError(f"[registration] rest_frame {rf!r} outside 0..{n_frames - 1}")
    return int(rf)


def _cover_candidates(config: RegistrationConfig, frames: Sequence[np.ndarray]) -> np.ndarray:
    """Indices of the frames of the middle half (``F // 4`` to ``F - F // 4 - 1``) whose
    surface cover lies within ``rest_cover_tolerance`` of the largest among them."""
    n = len(frames)
    lo, hi = n // 4, n - n // 4
    cover = surface_cover(frames[lo:hi])
    return np.flatnonzero(cover >= (1.0 - config.rest_cover_tolerance) * cover.max()) + lo


def _nearest_middle(good: np.ndarray, n_frames: int) -> int:
    """The index of ``good`` nearest the middle frame ``n_frames // 2`` (the shortest
    registration chains)."""
    return int(good[np.argmin(np.abs(good - n_frames // 2))])


def _misfit_cap(config: RegistrationConfig) -> float:
    """Cap (metres) of each distance in the chamfer misfits of step 1: three coarse-start
    standard deviations, ``3 sqrt(sigma2_start_max)``."""
    return 3.0 * float(np.sqrt(config.sigma2_start_max))


def _cpd_sigma2(y: np.ndarray, x: np.ndarray) -> float:
    """CPD's data-driven start, ``sum_mn |x_n - y_m|^2 / (D M N)``, in O(M + N)."""
    m, n = len(y), len(x)
    s = n * np.sum(y * y) + m * np.sum(x * x) - 2.0 * np.dot(y.sum(0), x.sum(0))
    return float(s / (3.0 * m * n))


def _residual_sigma2(y: np.ndarray, x: np.ndarray) -> float:
    """Start sigma^2 from how far a posed template ``y (M, 3)`` is from the data ``x (N, 3)``:
    the mean squared nearest-neighbour distance in both directions, per dimension (m^2)."""
    dy = nearest_distances(y, x)
    dx = nearest_distances(x, y)
    return float((np.mean(dy**2) + np.mean(dx**2)) / 6.0)


def _predict(r1, t1, r0, t0, nodes, gain):
    """Constant-velocity prediction of node transforms from the last two frames."""
    if gain <= 0 or r0 is None:
        return r1.copy(), t1.copy()
    dr = Rotation.from_matrix(np.einsum("jab,jcb->jac", r1, r0))
    step = Rotation.from_rotvec(dr.as_rotvec() * gain)
    r = np.einsum("jab,jbc->jac", step.as_matrix(), r1)
    p1 = nodes + t1
    p0 = nodes + t0
    t = p1 + gain * (p1 - p0) - nodes
    return np.ascontiguousarray(r), np.ascontiguousarray(t)


def _frame_params(config: RegistrationConfig) -> Any:
    """The parameters of ``DeformGraph.register_frame`` that are the same for every frame
    (``_core.FrameParams``)."""
    relative = config.beta_smooth_mode == "relative"
    return _core.FrameParams(
        omega=config.omega,
        beta_smooth=config.beta_smooth_rel if relative else config.beta_smooth,
        beta_relative=relative,
        beta_small=config.beta_small,
        sigma2_min=config.sigma2_min,
        anneal=config.sigma2_anneal,
        anneal_floor=config.sigma2_init,
        max_iter=config.max_iterations,
        tol=config.tolerance,
        cutoff=config.cutoff if config.cutoff > 0 else None,
        solver=config.solver,
        damping=config.gn_damping,
        cg_tol=config.cg_tolerance,
        cg_max=config.cg_max_iterations,
        subsample=config.subsample,
        motion_tol=config.motion_tol,
        kappa=config.normal_kappa,
    )


class PartialRegistration:
    """The frames registered so far, per rest candidate, to resume an interrupted step 1 where
    it stopped with the same result as an uninterrupted run.

    ``frames[rf][t]`` holds frame ``t``'s result registered from rest frame ``rf``:
    ``(R (J, 3, 3), T (J, 3), points (M, 3), sigma2, iterations, energy, matched)``.
    ``key`` is :func:`cache_key` of the input and parameters it belongs to.
    """

    FIELDS = ("R", "T", "points", "sigma2", "iterations", "energy", "matched")

    def __init__(self, key: str, frames: dict[int, dict[int, tuple]] | None = None):
        self.key = key
        self.frames: dict[int, dict[int, tuple]] = frames or {}
        self.lock = threading.Lock()

    def n_frames(self) -> int:
        """Number of (candidate, frame) results held."""
        return sum(len(v) for v in self.frames.values())

    def save(self, path: str | Path) -> None:
        """Write the state to an ``.npz``, atomically."""
        with self.lock:
            frames = {rf: dict(d) for rf, d in self.frames.items()}
        arrays: dict[str, Any] = {"cache_key": np.array(self.key),
                                  "candidates": np.array(sorted(frames), dtype=np.int64)}
        for rf, d in frames.items():
            ts = sorted(d)
            arrays[f"c{rf}_t"] = np.array(ts, dtype=np.int64)
            for i, name in enumerate(self.FIELDS):
                arrays[f"c{rf}_{name}"] = np.array([d[t][i] for t in ts])
        write_npz(path, **arrays)

    @classmethod
    def load(cls, path: str | Path) -> PartialRegistration:
        """Read a state written by :meth:`save`.

        Raises
        ------
        FormatError
            Not such a state, or one holding non-finite values.
        """
        try:
            with np.load(path, allow_pickle=False) as z:
                out = cls(str(z["cache_key"]))
                for rf in z["candidates"].tolist():
                    cols = [z[f"c{rf}_{name}"] for name in cls.FIELDS]
                    out.frames[int(rf)] = {
                        int(t): tuple(c[i] for c in cols)
                        for i, t in enumerate(z[f"c{rf}_t"].tolist())}
        except (KeyError, ValueError, OSError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
            raise FormatError(f"not a partial registration: {exc}", str(path)) from None
        for d in out.frames.values():
            for vals in d.values():
                if not all(np.isfinite(np.asarray(v, dtype=np.float64)).all() for v in vals):
                    raise FormatError("partial registration holds non-finite values",
                                      str(path))
        return out


def register_sequence(
    seq: PointSequence,
    config: RegistrationConfig | None = None,
    progress: Callable[[int, int], None] | None = None,
    partial: PartialRegistration | None = None,
    on_frame: Callable[[PartialRegistration], None] | None = None,
) -> RegistrationResult:
    """Register the whole sequence (Algorithm 1 per frame, frames in order).

    Frames after the rest frame are registered forwards from it and frames before it
    backwards, each starting from its neighbour's result (with constant-velocity prediction
    when ``predict_velocity > 0``, kept only if it explains the frame better than the
    neighbour's own pose, ``predict_check``). The two chains run side by side on
    ``config.workers`` threads once the rest frame and the frame after it are done; the result
    is the same as one after the other.
    With ``rest_frame = "fit"`` (the default) the sequence is registered from each of
    :func:`rest_candidates` and the result whose points explain the frames best
    (:func:`sequence_misfit`) is returned, unless it beats the first candidate by no more than
    ``rest_fit_margin``; its ``params["rest_candidates_misfit"]`` maps each candidate (the
    frame index as a string, as in JSON) to its misfit (metres). The candidates run side by
    side on ``config.workers`` threads (the same result as one after the other). With a single
    candidate (``rest_candidates = 1``, the default) nothing is scored and the key is absent.

    Parameters
    ----------
    seq
        The input frames, metres.
    config
        Parameters (default: :class:`RegistrationConfig`).
    progress
        Called as ``progress(done, total)`` after each frame.
    partial
        Frames already registered (an interrupted run's :class:`PartialRegistration`, whose
        key must match): they are taken as they are, and the frames registered now are added.
    on_frame
        Called with the partial state after each frame registered (from the worker threads;
        e.g. to save it every few frames).

    Returns
    -------
    RegistrationResult
        Registered points in the input coordinates.

    Raises
    ------
    ConfigError
        If ``rest_frame`` is an index outside the sequence.
    """
    config = config or RegistrationConfig()
    if partial is None:
        partial = PartialRegistration(cache_key(seq, config))
    f = seq.n_frames
    lo, hi = seq.bounds()
    if np.linalg.norm(hi - lo) > 50.0:
        log.warning(
            "sequence spans %.0f units: parameters assume metres (Table 1); scale the input",
            np.linalg.norm(hi - lo),
        )
    if config.rest_frame != "fit":
        rf = resolve_rest_frame(config, f)  # also checks the index against the frames
        return _register_from(seq, config, rf, progress, partial, on_frame)
    candidates = rest_candidates(config, seq.frames)
    k = len(candidates)
    if k == 1:  # nothing to choose between: no misfit to score
        return _register_from(seq, config, candidates[0], progress, partial, on_frame)
    done_by = [0] * k
    counting = threading.Lock()

    def sub(i: int) -> Callable[[int, int], None] | None:
        if progress is None:
            return None

        def report(done: int, total: int) -> None:
            with counting:
                done_by[i] = done
                progress(sum(done_by), k * total)
        return report

    trunc = _misfit_cap(config)

    def candidate(i: int) -> tuple[RegistrationResult, float]:
        res = _register_from(seq, config, candidates[i], sub(i), partial, on_frame)
        return res, sequence_misfit(res.points, seq.frames, trunc)

    # the candidates are independent registrations (each its own rest points, graph and
    # chains): they run side by side, each with the same arithmetic as alone
    pool = ThreadPoolExecutor(max_workers=pool_size(config.workers, k))
    try:
        outcomes = list(pool.map(candidate, range(k)))
    finally:
        pool.shutdown(cancel_futures=True)
    results = [r for r, _ in outcomes]
    scores = [v for _, v in outcomes]
    # the best fit, unless it explains the frames better than the first candidate by no more
    # than rest_fit_margin
    i = int(np.argmin(scores))
    if scores[i] >= (1.0 - config.rest_fit_margin) * scores[0]:
        i = 0
    best = results[i]
    # the refinement estimates the data normals again with the chosen rest points' radius
    keep_normals(config.normal_radius * mean_spacing(best.rest_points))
    log.info("rest frame: candidates %s, mean misfit %s cm; chose %d",
             candidates, [round(100 * v, 3) for v in scores], candidates[i])
    # keys as strings, as the JSON of the checkpoint and skeleton.json hold them (a saved and
    # reloaded result has the same params)
    best.params["rest_candidates_misfit"] = {str(int(c)): float(v)
                                             for c, v in zip(candidates, scores)}
    return best


def sequence_misfit(points: np.ndarray, frames: Sequence[np.ndarray], trunc: float) -> float:
    """Mean over frames of the symmetric truncated chamfer misfit
    (:func:`pointrig.geometry.chamfer_misfit`) between the registered points ``(F, M, 3)``
    and the frames (``F`` arrays ``(N_t, 3)``), metres; empty frames are skipped."""
    vals = [chamfer_misfit(y, x, trunc) for y, x in zip(points, frames) if len(x)]
    return float(np.mean(vals)) if vals else 0.0


def rest_candidates(config: RegistrationConfig, frames: Sequence[np.ndarray]) -> list[int]:
    """Candidate rest frames of ``rest_frame = "fit"``: :func:`resolve_rest_frame`'s frame
    first, then up to ``rest_candidates - 1`` more of the same near-largest surface cover, each
    the one whose pose differs most from those already chosen (farthest-point sampling on the
    symmetric chamfer distance between centred frames, up to 2000 points each), while one
    differs by more than twice the point spacing."""
    n = len(frames)
    good = _cover_candidates(config, frames)
    first = _nearest_middle(good, n)
    rng = np.random.default_rng(config.seed)

    def centred(t: int) -> np.ndarray:
        x = np.asarray(frames[t], dtype=float)
        if len(x) > 2000:
            x = x[np.sort(rng.choice(len(x), 2000, replace=False))]
        return x - x.mean(axis=0)

    pts = {int(t): centred(int(t)) for t in good}
    trees = {t: cKDTree(x) for t, x in pts.items()}

    def dist(a: int, b: int) -> float:
        return float(trees[b].query(pts[a])[0].mean() + trees[a].query(pts[b])[0].mean())

    # two samples of one surface lie about a spacing apart: a pose that differs by less than
    # twice the subsample's spacing from every chosen one is not new
    same = 2.0 * float(np.median(trees[first].query(pts[first], k=2)[0][:, 1]))
    chosen = [first]
    nearest = {int(t): dist(int(t), first) for t in good if int(t) != first}
    while len(chosen) < config.rest_candidates and nearest:
        t = max(nearest, key=lambda u: (nearest[u], -abs(u - n // 2)))
        if nearest[t] <= same:
            break
        chosen.append(t)
        del nearest[t]
        for u, d in nearest.items():
            nearest[u] = min(d, dist(u, t))
    return chosen


def _register_from(seq: PointSequence, config: RegistrationConfig, rf: int,
                   progress: Callable[[int, int], None] | None,
                   partial: PartialRegistration | None = None,
                   on_frame: Callable[[PartialRegistration], None] | None = None
                   ) -> RegistrationResult:
    """:func:`register_sequence` from rest frame ``rf`` (frames of ``partial`` reused)."""
    if partial is None:
        partial = PartialRegistration(cache_key(seq, config))
    with partial.lock:
        known = partial.frames.setdefault(rf, {})
    f = seq.n_frames
    rest = rest_surface(
        seq.frames[rf],
        config.n_rest_points,
        sor_neighbors=config.sor_neighbors,
        sor_std_ratio=config.sor_std_ratio,
        mls_neighbors=config.mls_neighbors,
        seed=config.seed,
        sparse_neighbors=config.rest_sparse_neighbors,
        sparse_ratio=config.rest_sparse_ratio,
    )
    graph, g, params, normal_radius = _frame_setup(rest, seq.frames[rf], config)
    j = len(graph.nodes)
    m = len(rest)

    points = np.zeros((f, m, 3))
    sigma2 = np.zeros(f)
    iters = np.zeros(f, dtype=np.int64)
    energy = np.zeros(f)
    matched = np.zeros(f)
    eye = np.ascontiguousarray(np.broadcast_to(np.eye(3), (j, 3, 3)))
    zero = np.zeros((j, 3))
    hist: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    lock = threading.Lock()
    done = 0
    stop = threading.Event()

    def one(t: int) -> None:
        """Register frame ``t`` from its neighbour's result (towards the rest frame)."""
        nonlocal done
        if t in known:  # registered before an interruption: the same arithmetic's result
            r_k, t_k, points[t], sigma2[t], iters[t], energy[t], matched[t] = known[t]
            hist[t] = (np.ascontiguousarray(r_k), np.ascontiguousarray(t_k))
            with lock:
                done += 1
                if progress is not None:
                    progress(done, f)
            return
        step = 1 if t >= rf else -1
        prev = hist.get(t - step)
        prev2 = hist.get(t - 2 * step)
        if prev is None:
            r_init, t_init = eye.copy(), zero.copy()
        else:
            r_init, t_init = _predict(
                prev[0], prev[1], None if prev2 is None else prev2[0],
                None if prev2 is None else prev2[1], graph.nodes, config.predict_velocity,
            )
        x = seq.frames[t]
        if prev2 is not None and config.predict_velocity > 0 and config.predict_check > 0 \
                and len(x):
            # hold the previous pose instead when it explains the frame better than the
            # prediction: after a jump or a sudden stop the prediction repeats the jump
            trunc = _misfit_cap(config)
            m_hold = chamfer_misfit(points[t - step], x, trunc)
            m_pred = chamfer_misfit(g.deform(r_init, t_init), x, trunc)
            if m_hold < config.predict_check * m_pred:
                log.debug("frame %d: the previous pose explains it better than the prediction "
                          "(misfit %.4f < %.4f m); holding it", t, m_hold, m_pred)
                r_init, t_init = prev[0].copy(), prev[1].copy()
        x_normals = estimate_normals(x, normal_radius) if config.normal_kappa > 0 else None
        res = _register_one(g, x, r_init, t_init, config, params, x_normals)
        frac = res["n_p"] / max(res["n_data"], 1)
        if frac < config.lost_fraction and prev is not None:
            log.warning(
                "frame %d: tracking lost (matched fraction %.3f < %.3f); retrying coarse",
                t, frac, config.lost_fraction,
            )
            retry = _register_one(
                g, x, prev[0], prev[1], config, params, x_normals,
                sigma2_start=4.0 * config.sigma2_start_max, extra_rigid=3,
            )
            if retry["n_p"] > res["n_p"]:
                res = retry
                frac = res["n_p"] / max(res["n_data"], 1)
        hist[t] = (res["R"], res["T"])
        points[t] = res["points"]
        sigma2[t] = res["sigma2"]
        iters[t] = res["iterations"]
        energy[t] = res["energy"]
        matched[t] = frac
        with partial.lock:
            known[t] = (res["R"], res["T"], res["points"], res["sigma2"], res["iterations"],
                        res["energy"], frac)
        if on_frame is not None:
            on_frame(partial)
        with lock:
            done += 1
            if progress is not None:
                progress(done, f)

    def chain(frames: list[int]) -> None:
        for t in frames:
            if stop.is_set():
                return
            one(t)

    # The rest frame, then the first frame after it (the first frame before it predicts from
    # both); from there the forward and the backward chains depend on nothing of each other
    # and run side by side (the native calls and the nearest-distance queries release the
    # GIL), each with the same arithmetic as one after the other.
    chain([rf] + ([rf + 1] if rf + 1 < f else []))
    chains = [c for c in (list(range(rf + 2, f)), list(range(rf - 1, -1, -1))) if c]
    pool = ThreadPoolExecutor(max_workers=pool_size(config.workers, len(chains)))
    try:
        futures = [pool.submit(chain, c) for c in chains]
        for fut in as_completed(futures):
            fut.result()  # the first error stops the other chain at its next frame
    finally:
        stop.set()
        pool.shutdown(cancel_futures=True)
    return RegistrationResult(
        rest_points=rest,
        points=points,
        sigma2=sigma2,
        iterations=iters,
        energy=energy,
        params={**dataclasses.asdict(config), "rest_frame_index": rf},
        matched=matched,
        key=cache_key(seq, config),
    )


def _frame_setup(rest: np.ndarray, rest_frame: np.ndarray, config: RegistrationConfig
                 ) -> tuple[DeformationGraph, Any, Any, float]:
    """The deformation graph of the rest points (with their normals when ``normal_kappa >
    0``, estimated on the rest frame's points), its native form, the per-sequence
    ``_core.FrameParams`` and the data normals' radius (metres)."""
    graph = build_graph(rest, config)
    # mean nearest-neighbour distance of the rest points: the template's resolution
    normal_radius = config.normal_radius * mean_spacing(rest)
    if config.normal_kappa > 0:
        graph.normals = estimate_normals(rest, normal_radius, source=rest_frame)
    return graph, graph.native(), _frame_params(config), normal_radius


def _register_one(g: Any, x: np.ndarray, r_init: np.ndarray, t_init: np.ndarray,
                  config: RegistrationConfig, params: Any, x_normals: np.ndarray | None,
                  sigma2_start: float | None = None, extra_rigid: int = 0) -> dict[str, Any]:
    """One frame's EM (``DeformGraph.register_frame``) from the node transforms ``r_init (J,
    3, 3)``, ``t_init (J, 3)`` against ``x (N, 3)``, starting at ``sigma2_start`` (m^2; by
    default the ``sigma2_start`` rule of the config) with ``extra_rigid`` more rigid
    iterations."""
    if sigma2_start is None:
        if config.sigma2_start == "data":
            y0 = g.deform(r_init, t_init)
            sigma2_start = min(max(_cpd_sigma2(y0, x), config.sigma2_init),
                               config.sigma2_start_max)
        else:
            sigma2_start = config.sigma2_init
    return g.register_frame(np.ascontiguousarray(x), r_init, t_init, params,
                            sigma2_start=sigma2_start,
                            rigid_iters=config.rigid_iterations + extra_rigid,
                            x_normals=x_normals)


def _node_neighbours(graph: DeformationGraph, k: int) -> np.ndarray:
    """``(J, k')`` indices of each node's ``k' = min(max(k, 3), M)`` nearest rest points."""
    kk = int(min(max(k, 3), len(graph.rest)))
    _, nb = cKDTree(graph.rest).query(graph.nodes, k=kk)
    return nb.reshape(len(graph.nodes), kk)


def node_transforms_from_points(graph: DeformationGraph, posed: np.ndarray, k: int = 12
                                ) -> tuple[np.ndarray, np.ndarray]:
    """Node transforms of Eq. 2 that carry the rest points to ``posed``: each node's rigid
    motion is the Kabsch fit of its ``k`` nearest rest points to their posed positions,
    written as ``y' = R (y - n) + n + T``.

    The fits run in the Rust batched Kabsch (``_core.cluster_fit``, the fit of step 2's
    Eq. 14), each node's neighbourhood a cluster; the neighbourhoods are found once for all
    frames.

    Parameters
    ----------
    graph
        The deformation graph (rest points and nodes, metres).
    posed
        ``(M, 3)`` positions of the rest points in one frame, or ``(F, M, 3)`` in ``F``
        frames, metres.
    k
        Rest points per node fit (at least 3, at most ``M``).

    Returns
    -------
    R, T
        ``(J, 3, 3)`` rotations and ``(J, 3)`` translations (metres) for one frame, or
        ``(F, J, 3, 3)`` and ``(F, J, 3)`` for ``F`` frames.

    Raises
    ------
    InputError
        If ``posed`` is not ``(M, 3)`` or ``(F, M, 3)`` for the graph's ``M`` rest points.
    """
    posed = np.asarray(posed, dtype=np.float64)
    one = posed.ndim == 2
    seq = posed[None] if one else posed
    m = len(graph.rest)
    if seq.ndim != 3 or seq.shape[1:] != (m, 3):
        raise InputError(f"node_transforms_from_points: posed must be ({m}, 3) or (F, {m}, 3), "
                         f"got {posed.shape}")
    nb = _node_neighbours(graph, k)  # (J, k')
    j, kk = nb.shape
    flat = nb.reshape(-1)
    labels = np.repeat(np.arange(j, dtype=np.int64), kk)
    rest = np.ascontiguousarray(graph.rest[flat])
    nodes = graph.nodes
    f = len(seq)
    r = np.empty((f, j, 3, 3))
    big_t = np.empty((f, j, 3))
    step = max(1, 4_000_000 // max(len(flat), 1))  # frames per call: at most ~4M points
    for a in range(0, f, step):
        pts = np.ascontiguousarray(seq[a:a + step][:, flat])
        ra, ta, _ = _core.cluster_fit(rest, pts, labels, j)  # y = R q + t
        r[a:a + step] = ra
        # y = R (q - n) + n + T  =>  T = R n + t - n
        big_t[a:a + step] = np.einsum("fjab,jb->fja", ra, nodes) + ta - nodes
    return (r[0], big_t[0]) if one else (r, big_t)


def refine_registration(
    seq: PointSequence,
    reg: RegistrationResult,
    posed: np.ndarray,
    config: RegistrationConfig | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> RegistrationResult:
    """Register every frame again, each on its own, starting from a posed template (our
    deviation from §4, ``RegistrationConfig.refine_rounds``; docs/registration.md).

    Step 1 registers each frame from its neighbour's result, so its errors (a limb lost behind
    the body, a template slid along a smooth part) carry on down the chain. Step 3's tracked
    skeleton explains the raw frames better (rigid bones held at their joints) but cannot bend
    inside a bone. Here each frame's deformation graph starts from the tracked pose (per-node
    Kabsch fits, :func:`node_transforms_from_points`) with sigma^2 from the start's own misfit
    (capped at ``sigma2_init``) and no rigid steps, and the usual EM (Eqs. 4-12) fits it to
    the frame: no chain, so nothing propagates from one frame to the next. The frames run on
    ``config.workers`` threads (the same result as one after the other). The pipeline then
    runs steps 2 and 3 again on the result.

    Parameters
    ----------
    seq
        The input frames (as given to :func:`register_sequence`), metres.
    reg
        Step 1's result: its rest points are kept.
    posed
        ``(F, M, 3)`` the rest points posed by the skeleton in every frame, metres.
    config
        The registration parameters (graph, EM); default :class:`RegistrationConfig`.
    progress
        Called as ``progress(done, F)`` after each frame.

    Returns
    -------
    RegistrationResult
        Same rest points, refined ``points``; ``params["refined"]`` is true and ``key`` is
        empty (it is not a step-1 checkpoint).

    Raises
    ------
    InputError
        If ``posed`` is not ``(F, M, 3)`` for the sequence's ``F`` frames and the ``M`` rest
        points, or is not finite.
    """
    config = config or RegistrationConfig()
    rest = np.ascontiguousarray(reg.rest_points, dtype=np.float64)
    f, m = seq.n_frames, len(rest)
    posed = np.asarray(posed, dtype=np.float64)
    if posed.shape != (f, m, 3) or not np.isfinite(posed).all():
        raise InputError(f"refine_registration: posed points must be finite ({f}, {m}, 3), "
                         f"got {posed.shape}")
    rf = reg.params.get("rest_frame_index")  # the cover search only for an old checkpoint
    rf = resolve_rest_frame(config, f, seq.frames) if rf is None else int(rf)
    graph, g, params, normal_radius = _frame_setup(rest, seq.frames[rf], config)
    r_start, t_start = node_transforms_from_points(graph, posed)  # (F, J, 3, 3), (F, J, 3)
    points = posed.copy()
    sigma2 = np.zeros(f)
    iters = np.zeros(f, dtype=np.int64)
    energy = np.zeros(f)
    matched = np.zeros(f)

    def one(t: int) -> dict[str, Any] | None:
        x = np.ascontiguousarray(seq.frames[t], dtype=np.float64)
        if not len(x):
            return None
        r0, t0 = r_start[t], t_start[t]
        x_normals = estimate_normals(x, normal_radius) if config.normal_kappa > 0 else None
        s2 = min(max(_residual_sigma2(g.deform(r0, t0), x), config.sigma2_min),
                 config.sigma2_init)
        return g.register_frame(x, r0, t0, params, sigma2_start=s2, rigid_iters=0,
                                x_normals=x_normals)

    # every frame starts from its own posed points, so the frames are independent: they run
    # side by side (the native calls and the nearest-distance queries release the GIL), each
    # with the same arithmetic as alone. On an error or Ctrl-C the frames not yet started are
    # dropped.
    pool = ThreadPoolExecutor(max_workers=pool_size(config.workers, f))
    try:
        for t, res in enumerate(pool.map(one, range(f))):
            if res is not None:
                points[t] = res["points"]
                sigma2[t] = res["sigma2"]
                iters[t] = res["iterations"]
                energy[t] = res["energy"]
                matched[t] = res["n_p"] / max(res["n_data"], 1)
            if progress is not None:
                progress(t + 1, f)
    finally:
        pool.shutdown(cancel_futures=True)
    return RegistrationResult(
        rest_points=rest, points=points, sigma2=sigma2, iterations=iters, energy=energy,
        params={**dataclasses.asdict(config), "rest_frame_index": rf, "refined": True},
        matched=matched, key="",
    )
