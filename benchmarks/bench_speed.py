"""Run time of the whole pipeline against its serial form, measured in the same run.

The reference is the pipeline as it ran before session 35: a tracked frame's two hypotheses
fitted one after the other (``pointrig.joints._TRACK_WORKERS = 1``), the refinement's frames
registered one after the other (``pointrig.registration._REFINE_WORKERS = 1``), step 1's
forward and backward chains one after the other (``pointrig.registration._CHAIN_WORKERS =
1``), step 2's ensemble seeds one after the other (``pointrig.structure._ENSEMBLE_WORKERS =
1``) and the chamfer misfit searching every nearest neighbour to the end (no
``distance_upper_bound``) on scipy k-d trees; and, as before session 66's Rust grid
(``rust/core/nearest.rs``), farthest-point sampling as a numpy loop, the sparse-point filter,
step 1's start sigma^2 and the tracker's start tau on scipy k-d trees. Both forms do the same arithmetic, so the
benchmark also checks that the skeletons agree. Prints per
sequence the seconds of each stage for both and their ratio::

    PYTHONPATH=python python benchmarks/bench_speed.py                  # 100-frame human
    PYTHONPATH=python python benchmarks/bench_speed.py --only human,girl_run --repeats 2

Each form runs ``--repeats`` times, alternating, and the fastest run of each is reported.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager, nullcontext
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "python"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_refine import selected, suite  # noqa: E402

import pointrig.joints as joints_mod  # noqa: E402
import pointrig.preprocess as pre_mod  # noqa: E402
import pointrig.registration as reg_mod  # noqa: E402
import pointrig.structure as structure_mod  # noqa: E402
from pointrig.config import PipelineConfig  # noqa: E402
from pointrig.pipeline import extract  # noqa: E402

STAGES = ("clean-up", "registration", "structure", "joints", "refinement")
#: the thread counts the serial form sets to 1
WORKERS = ((joints_mod, "_TRACK_WORKERS"), (reg_mod, "_REFINE_WORKERS"),
           (reg_mod, "_CHAIN_WORKERS"), (structure_mod, "_ENSEMBLE_WORKERS"))
#: the module functions the serial form replaces by its reference forms (and restores)
FUNCTIONS = ((joints_mod, "chamfer_misfit"), (reg_mod, "chamfer_misfit"),
             (pre_mod, "farthest_point_sampling"), (reg_mod, "farthest_point_sampling"),
             (pre_mod, "remove_sparse_points"), (reg_mod, "nearest_distances"),
             (joints_mod, "nearest_distances"))
#: everything the serial form changes (and restores)
PATCHED = WORKERS + FUNCTIONS


def chamfer_full_search(template: np.ndarray, data: np.ndarray, trunc: float) -> float:
    """:func:`pointrig.preprocess.chamfer_misfit` as before session 35: scipy k-d trees
    (session 66 moved it to a Rust grid), every nearest-neighbour search run to the end and
    the distances capped afterwards (metres)."""
    tree = cKDTree(data)
    d_td = np.minimum(tree.query(template)[0], trunc).mean()
    d_dt = np.minimum(cKDTree(template).query(data)[0], trunc).mean()
    return float(d_td + d_dt)


def fps_numpy(points: np.ndarray, n: int, seed: int = 0) -> np.ndarray:
    """:func:`pointrig.preprocess.farthest_point_sampling` as before session 66: the numpy
    loop, ``(min(n, m),)`` indices of ``points (m, 3)``."""
    m = len(points)
    if n >= m:
        return np.arange(m)
    idx = np.empty(n, dtype=np.int64)
    idx[0] = np.random.default_rng(seed).integers(m)
    d = np.sum((points - points[idx[0]]) ** 2, axis=1)
    for i in range(1, n):
        idx[i] = int(np.argmax(d))
        d = np.minimum(d, np.sum((points - points[idx[i]]) ** 2, axis=1))
    return idx


def remove_sparse_kd(points: np.ndarray, k: int = 10, ratio: float = 4.0) -> np.ndarray:
    """:func:`pointrig.preprocess.remove_sparse_points` as before session 66 (scipy k-d
    tree): the points of ``(N, 3)`` whose ``k``-th neighbour is within ``ratio`` medians."""
    if ratio <= 0 or len(points) <= k + 1:
        return points.copy()
    dk = cKDTree(points).query(points, k=k + 1, workers=-1)[0][:, -1]
    return points[dk <= ratio * np.median(dk)]


def nearest_kd(queries: np.ndarray, points: np.ndarray, cap: float | None = None) -> np.ndarray:
    """:func:`pointrig.preprocess.nearest_distances` on a scipy k-d tree, ``(n,)`` metres."""
    d = cKDTree(points).query(queries)[0]
    return d if cap is None else np.minimum(d, cap)


#: the reference form of each function of :data:`FUNCTIONS`, by name
REFERENCE = {"chamfer_misfit": chamfer_full_search, "farthest_point_sampling": fps_numpy,
             "remove_sparse_points": remove_sparse_kd, "nearest_distances": nearest_kd}


@contextmanager
def serial() -> Iterator[None]:
    """The reference form: every worker count of :data:`WORKERS` 1, the functions of
    :data:`FUNCTIONS` in their :data:`REFERENCE` forms."""
    saved = {(mod, name): getattr(mod, name) for mod, name in PATCHED}
    for mod, name in WORKERS:
        setattr(mod, name, 1)
    for mod, name in FUNCTIONS:
        setattr(mod, name, REFERENCE[name])
    try:
        yield
    finally:
        for (mod, name), value in saved.items():
            setattr(mod, name, value)


def timed(seq, cfg: PipelineConfig) -> tuple[dict[str, float], np.ndarray]:
    """Stage seconds (plus ``total``) and the ``(F, J, 3)`` joint positions of one run."""
    t0 = time.perf_counter()
    out = extract(seq, cfg, None, pictures=False)
    secs = dict(out.timings) | {"total": time.perf_counter() - t0}
    return secs, np.asarray(out.skeleton.joint_positions)


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default="human", help="comma-separated sequence names")
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--repeats", type=int, default=1)
    a = ap.parse_args(argv)
    if a.repeats < 1:
        ap.error("--repeats must be >= 1")
    only = selected(ap, a.only)
    cfg = PipelineConfig()
    cols = (*STAGES, "total")
    print(f"{'sequence':<16} {'form':<10}" + "".join(f"{c:>14}" for c in cols)
          + f"{'joints differ (m)':>19}")
    for name, syn in suite(a.frames, only):
        seq = syn.to_point_sequence()
        best: dict[str, dict[str, float]] = {}
        poses: dict[str, np.ndarray] = {}
        for _ in range(a.repeats):
            for form in ("serial", "default"):
                with serial() if form == "serial" else nullcontext():
                    secs, P = timed(seq, cfg)
                poses[form] = P
                if form not in best or secs["total"] < best[form]["total"]:
                    best[form] = secs
        diff = (float(np.abs(poses["serial"] - poses["default"]).max())
                if poses["serial"].shape == poses["default"].shape else float("inf"))
        for form in ("serial", "default"):
            cells = "".join(f"{best[form].get(c, 0.0):>13.2f}s" for c in cols)
            tail = f"{diff:>19.1e}" if form == "default" else ""
            print(f"{name:<16} {form:<10}{cells}{tail}")
        ratio = "".join(
            f"{best['serial'].get(c, 0.0) / max(best['default'].get(c, 0.0), 1e-9):>13.2f}x"
            for c in cols)
        print(f"{name:<16} {'speed-up':<10}{ratio}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
