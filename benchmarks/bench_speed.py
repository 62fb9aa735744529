"""Run time of the whole pipeline against its serial form, measured in the same run.

The reference (serial) form runs the same arithmetic one thing at a time and without the Rust
nearest-neighbour grid (``rust/core/nearest.rs``): a tracked frame's two hypotheses fitted one
after the other, the refinement's frames registered one after the other, step 1's forward and
backward chains one after the other and step 2's ensemble seeds one after the other (``workers
= 1`` in ``[registration]``, ``[structure]`` and ``[joints]``, :func:`serial_config`), the chamfer
misfit on scipy k-d trees searching every nearest neighbour to the end, farthest-point sampling
as a numpy loop, and the sparse-point filter and step 1's nearest distances (its start sigma^2)
on scipy k-d trees (a tracked frame's fit, in Rust, always uses the grid). Both forms give the same skeleton, which the
benchmark checks. Prints per sequence the seconds of each stage for both, the largest
difference between their joints, and the ratio serial / default::

    python -m benchmarks.bench_speed                              # the 100-frame human
    python -m benchmarks.bench_speed --only human,girl_run,hand --repeats 2

Each form runs ``--repeats`` times, alternating, and the fastest run of each is reported.

``--stages`` prints instead the profile of one run per sequence (:mod:`benchmarks.stages`):
per stage the wall and CPU seconds, CPU / wall, and the CPU seconds spent in Python code with
their share of the stage's wall time (a second, profiled run; ``--no-python`` leaves it out),
writing the outputs (without pictures) as ``pointrig extract --no-pictures`` does;
``--unshared`` adds the seconds of the pipeline without its run-wide sharing (each step
estimating its own normals, the BLAS on its default threads; :func:`unshared`) and the CPU
ratio::

    python -m benchmarks.bench_speed --stages [--unshared] [--no-python]   # human, 100 frames

``--preset fast`` times the defaults against that preset instead (:meth:`PipelineConfig.preset`;
its skeletons differ, so the last column counts each form's joints; with ``--stages`` it
profiles the preset)::

    python -m benchmarks.bench_speed --preset fast --only human,girl_run,hand
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager, nullcontext

import numpy as np
from scipy.spatial import cKDTree

import pointrig.joints as joints_mod
import pointrig.pipeline as pipeline_mod
import pointrig.preprocess as pre_mod
import pointrig.registration as reg_mod
from benchmarks.sets import add_sequence_options, chosen, suite
from benchmarks.stages import StageProfile, table
from pointrig.config import PRESETS, PipelineConfig
from pointrig.pipeline import extract
from pointrig.sequence import PointSequence

STAGES = ("clean-up", "registration", "structure", "joints", "refinement")
#: the module functions the serial form replaces by its reference forms (and restores)
FUNCTIONS = ((joints_mod, "chamfer_misfit"), (reg_mod, "chamfer_misfit"),
             (pre_mod, "farthest_point_sampling"), (reg_mod, "farthest_point_sampling"),
             (pre_mod, "remove_sparse_points"), (reg_mod, "nearest_distances"))
#: everything the serial form changes (and restores)
PATCHED = FUNCTIONS


def chamfer_full_search(template: np.ndarray, data: np.ndarray, trunc: float) -> float:
    """Reference form of :func:`pointrig.geometry.chamfer_misfit` (metres) between
    ``template (M, 3)`` and ``data (N, 3)``: scipy k-d trees, every nearest-neighbour search
    run to the end and the distances capped at ``trunc`` afterwards."""
    tree = cKDTree(data)
    d_td = np.minimum(tree.query(template)[0], trunc).mean()
    d_dt = np.minimum(cKDTree(template).query(data)[0], trunc).mean()
    return float(d_td + d_dt)


def fps_numpy(points: np.ndarray, n: int, seed: int = 0) -> np.ndarray:
    """Reference form of :func:`pointrig.geometry.farthest_point_sampling`, a numpy loop:
    ``(min(n, m),)`` indices of ``points (m, 3)``."""
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
    """Reference form of :func:`pointrig.geometry.remove_sparse_points` on a scipy k-d
    tree: the points of ``(N, 3)`` whose ``k``-th neighbour is within ``ratio`` medians."""
    if ratio <= 0 or len(points) <= k + 1:
        return points.copy()
    dk = cKDTree(points).query(points, k=k + 1, workers=-1)[0][:, -1]
    return points[dk <= ratio * np.median(dk)]


def nearest_kd(queries: np.ndarray, points: np.ndarray, cap: float | None = None) -> np.ndarray:
    """:func:`pointrig.geometry.nearest_distances` on a scipy k-d tree, ``(n,)`` metres."""
    d = cKDTree(points).query(queries)[0]
    return d if cap is None else np.minimum(d, cap)


#: the reference form of each function of :data:`FUNCTIONS`, by name
REFERENCE = {"chamfer_misfit": chamfer_full_search, "farthest_point_sampling": fps_numpy,
             "remove_sparse_points": remove_sparse_kd, "nearest_distances": nearest_kd}


@contextmanager
def serial() -> Iterator[None]:
    """The reference form's functions: those of :data:`FUNCTIONS` in their :data:`REFERENCE`
    forms (run it with :func:`serial_config`)."""
    saved = {(mod, name): getattr(mod, name) for mod, name in PATCHED}
    for mod, name in FUNCTIONS:
        setattr(mod, name, REFERENCE[name])
    try:
        yield
    finally:
        for (mod, name), value in saved.items():
            setattr(mod, name, value)


def serial_config(cfg: PipelineConfig) -> PipelineConfig:
    """``cfg`` with one worker in every stage that has a pool."""
    return cfg.with_workers(1)


def timed(seq: PointSequence, cfg: PipelineConfig) -> tuple[dict[str, float], np.ndarray]:
    """Stage seconds (plus ``total``) and the ``(F, J, 3)`` joint positions of one run."""
    t0 = time.perf_counter()
    out = extract(seq, cfg, None, pictures=False)
    secs = dict(out.timings) | {"total": time.perf_counter() - t0}
    return secs, np.asarray(out.skeleton.joint_positions)


def profile_run(seq: PointSequence, cfg: PipelineConfig, python: bool = False
                ) -> StageProfile:
    """The per-stage seconds of one :func:`extract` of ``seq`` writing its outputs (no
    pictures) into a temporary folder; with ``python`` under the profiler."""
    prof = StageProfile(python=python)
    with tempfile.TemporaryDirectory() as tmp, prof.recording():
        extract(seq, cfg, tmp, pictures=False)
    return prof


@contextmanager
def unshared() -> Iterator[None]:
    """The pipeline without its run-wide settings (``pipeline._compute_once``): every step
    estimates its own normals, and numpy's and scipy's BLAS run on their default threads."""
    saved = pipeline_mod._compute_once
    pipeline_mod._compute_once = nullcontext
    try:
        yield
    finally:
        pipeline_mod._compute_once = saved


def print_stages(name: str, seq: PointSequence, cfg: PipelineConfig, python: bool,
                 reference: bool = False) -> None:
    """The per-stage table of ``seq`` (:func:`benchmarks.stages.table`), with ``reference``
    beside the :func:`unshared` form's seconds (run first)."""
    ref = None
    if reference:
        with unshared():
            ref = profile_run(seq, cfg)
    timed = profile_run(seq, cfg)
    profiled = profile_run(seq, cfg, python=True) if python else None
    counts = np.asarray(seq.counts)
    print(f"\n{name}: {len(seq)} frames, {int(np.median(counts))} points a frame (median); "
          f"{timed.total.wall:.2f} s wall, {timed.total.cpu:.2f} CPU-s; "
          f"{1e3 * timed.times['step 1 registration'].wall / max(len(seq), 1):.1f} ms a frame "
          "in step 1")
    print(table(timed, profiled, ref, "unshared"), flush=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_sequence_options(ap, only="human")
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--stages", action="store_true",
                    help="the per-stage profile of the default form instead")
    ap.add_argument("--no-python", action="store_true",
                    help="with --stages: leave out the profiled run (the Python share)")
    ap.add_argument("--preset", choices=PRESETS[1:], default=None,
                    help="time the defaults against this preset instead of the serial form "
                    "(with --stages: profile the preset)")
    ap.add_argument("--unshared", action="store_true",
                    help="with --stages: also the pipeline without its run-wide sharing")
    a = ap.parse_args(argv)
    if a.repeats < 1:
        ap.error("--repeats must be >= 1")
    sequences, only = chosen(ap, a)
    cfg = PipelineConfig()
    if a.stages:
        for name, syn in suite(a.frames, only, sequences):
            print_stages(name, syn.to_point_sequence(),
                         PipelineConfig.preset(a.preset) if a.preset else cfg,
                         not a.no_python, a.unshared)
        return 0
    cols = (*STAGES, "total")
    if a.preset:  # the defaults against a preset: the preset's speed-up, its joints counted
        forms = {"default": (cfg, nullcontext), a.preset: (PipelineConfig.preset(a.preset),
                                                           nullcontext)}
        last = "joints"
    else:
        forms = {"serial": (serial_config(cfg), serial), "default": (cfg, nullcontext)}
        last = "joints differ (m)"
    ref, new = forms
    print(f"{'sequence':<16} {'form':<10}" + "".join(f"{c:>14}" for c in cols) + f"{last:>19}")
    for name, syn in suite(a.frames, only, sequences):
        seq = syn.to_point_sequence()
        best: dict[str, dict[str, float]] = {}
        poses: dict[str, np.ndarray] = {}
        for _ in range(a.repeats):
            for form, (form_cfg, context) in forms.items():
                with context():
                    secs, P = timed(seq, form_cfg)
                poses[form] = P
                if form not in best or secs["total"] < best[form]["total"]:
                    best[form] = secs
        for form in forms:
            cells = "".join(f"{best[form].get(c, 0.0):>13.2f}s" for c in cols)
            if a.preset:
                tail = f"{poses[form].shape[1]:>19d}"
            elif form == new:
                diff = (float(np.abs(poses[ref] - poses[new]).max())
                        if poses[ref].shape == poses[new].shape else float("inf"))
                tail = f"{diff:>19.1e}"
            else:
                tail = ""
            print(f"{name:<16} {form:<10}{cells}{tail}")
        ratio = "".join(f"{best[ref].get(c, 0.0) / best[new][c]:>13.2f}x"
                        if best[new].get(c, 0.0) > 0 else f"{'-':>14}" for c in cols)
        print(f"{name:<16} {'speed-up':<10}{ratio}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
