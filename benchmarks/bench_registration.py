"""Step 1 (registration, §4): the E-step kernel, a whole sequence, and probreg's CPD.

Three tables, each with its reference measured in the same run:

1. The GMM E-step per iteration at M = 2000, N = 10000 (sigma = 1 cm): the Rust kernel, dense
   and truncated, float64 and float32, on 1 and 2 threads (each in a subprocess with
   ``RAYON_NUM_THREADS`` set), against a dense numpy E-step.
2. A 100-frame synthetic human registered with the default configuration and with the paper's
   (:func:`benchmarks.sets.paper_config`): milliseconds per frame, the distance of the
   registered points to the nearest observed point (mean, and the worst frame's 90th
   percentile) and the correspondence error against the exact surface motion, all in cm.
3. probreg's non-rigid CPD (Myronenko and Song) on one frame pair against pointrig's
   registration of the same pair: seconds and correspondence error (skipped with a note when
   probreg is not installed: ``pip install probreg``).

Run::

    python -m benchmarks.bench_registration [--frames 100] [--skip-seq]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from benchmarks.sets import paper_config
from pointrig.config import RegistrationConfig
from pointrig.registration import RegistrationResult, register_sequence
from pointrig.sequence import PointSequence
from pointrig.synth import synthesize

ROOT = Path(__file__).resolve().parents[1]


def rest_frame_index(result: RegistrationResult) -> int:
    """The frame whose surface gave ``result``'s rest points."""
    return int(result.params["rest_frame_index"])


def nearest_observed(points: np.ndarray, frames: list[np.ndarray]) -> np.ndarray:
    """``(F, M)`` distance (metres) of each registered point of ``points (F, M, 3)`` to the
    nearest observed point of its frame (``frames[t]``: ``(N_t, 3)``)."""
    return np.stack([cKDTree(x).query(y)[0] for y, x in zip(points, frames)])


def correspondence_error(rest_points: np.ndarray, points: np.ndarray, surface: np.ndarray,
                         rest_frame: int, max_offset: float = 0.01) -> np.ndarray:
    """``(F, M')`` displacement error (metres) against exact surface correspondences.

    Each rest point ``(M, 3)`` is tied to its nearest ground-truth surface sample of the rest
    frame ``surface[rest_frame]`` (only points within ``max_offset`` of one); the error at
    frame t is ``|(Y^t_m - Y^rest_m) - (S^t_s - S^rest_s)|`` with ``Y = points (F, M, 3)`` and
    ``S = surface (F, S, 3)``, which removes the fixed sampling offset.
    """
    d, s = cKDTree(surface[rest_frame]).query(rest_points)
    ok = d < max_offset
    dy = points[:, ok] - points[rest_frame][ok]
    ds = surface[:, s[ok]] - surface[rest_frame][s[ok]]
    return np.linalg.norm(dy - ds, axis=2)


def sequence_errors(result: RegistrationResult, frames: list[np.ndarray], surface: np.ndarray
                    ) -> tuple[float, float, float]:
    """Table 2's errors of a registration (metres): the mean distance of the registered points
    to the nearest observed point of their frame (``frames[t]``: ``(N_t, 3)``), the worst
    frame's 90th percentile of it, and the mean correspondence error against the exact surface
    motion ``surface (F, S, 3)``, measured from the rest frame ``result`` chose."""
    no = nearest_observed(result.points, frames)
    ce = correspondence_error(result.rest_points, result.points, surface,
                              rest_frame_index(result))
    return float(no.mean()), float(np.percentile(no, 90, axis=1).max()), float(ce.mean())


def _surface(n: int, rng: np.random.Generator) -> np.ndarray:
    """Points on a body-sized ellipsoid shell (0.25 x 0.15 x 0.9 m semi-axes) 2.5 m away."""
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    return v * [0.25, 0.15, 0.9] + [0.0, 0.0, 2.5]


def estep_child() -> None:
    """Runs in a subprocess: times the E-step variants, prints JSON."""
    from pointrig import _core

    rng = np.random.default_rng(0)
    y = _surface(2000, rng)
    x = _surface(10000, rng) + rng.normal(scale=0.003, size=(10000, 3))
    s2 = 1e-4  # sigma = 1 cm
    out = {}
    for name, kw in {
        "dense f64": dict(cutoff=None, single=False),
        "dense f32": dict(cutoff=None, single=True),
        "trunc f64 (5 sigma)": dict(cutoff=5.0, single=False),
        "trunc f32 (5 sigma)": dict(cutoff=5.0, single=True),
    }.items():
        _core.gmm_estep(y, x, s2, 0.01, **kw)
        reps = []
        # 25 repetitions: the 2-core machine is shared and single timings vary by 2x.
        for _ in range(25):
            t = time.perf_counter()
            _core.gmm_estep(y, x, s2, 0.01, **kw)
            reps.append(time.perf_counter() - t)
        out[name] = 1e3 * float(np.median(reps))
    print(json.dumps(out))


def numpy_estep(y: np.ndarray, x: np.ndarray, s2: float, omega: float
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Dense E-step in numpy (the reference): template ``y (M, 3)``, data ``x (N, 3)``,
    sigma^2 ``s2`` (m^2), outlier weight ``omega``; returns the posterior sums over the data
    ``(M,)`` and over the template ``(N,)``, and ``P @ x (M, 3)``."""
    m, n = len(y), len(x)
    d2 = (y * y).sum(1)[:, None] + (x * x).sum(1)[None] - 2 * y @ x.T
    e = np.exp(-d2 / (2 * s2))
    c0 = (2 * np.pi * s2) ** 1.5 * omega * m / ((1 - omega) * n)
    p = e / (e.sum(0) + c0)
    return p.sum(1), p.sum(0), p @ x


def bench_estep() -> None:
    """Table 1: the Rust E-step on 1 and 2 threads against the numpy one."""
    rng = np.random.default_rng(0)
    y = _surface(2000, rng)
    x = _surface(10000, rng)
    numpy_estep(y, x, 1e-4, 0.01)
    reps = []
    for _ in range(3):
        t = time.perf_counter()
        numpy_estep(y, x, 1e-4, 0.01)
        reps.append(time.perf_counter() - t)
    t_np = 1e3 * float(np.median(reps))
    rows = {}
    for threads in ("1", "2"):
        env = dict(os.environ, RAYON_NUM_THREADS=threads)
        res = subprocess.run([sys.executable, "-m", "benchmarks.bench_registration",
                              "--estep-child"], env=env, cwd=ROOT, capture_output=True,
                             text=True, check=True)
        rows[threads] = json.loads(res.stdout.strip().splitlines()[-1])
    print("\nE-step per iteration, M = 2000, N = 10000, sigma = 1 cm (median ms)")
    print(f"{'variant':24s} {'1 thread':>10s} {'2 threads':>10s} {'numpy/2thr':>11s}")
    for name in rows["1"]:
        a, b = rows["1"][name], rows["2"][name]
        print(f"{name:24s} {a:10.2f} {b:10.2f} {t_np / b:10.0f}x")
    print(f"{'numpy dense (reference)':24s} {t_np:10.1f}")


def bench_sequence(n_frames: int) -> None:
    """Table 2: the default and the paper's registration of one synthetic human."""
    s = synthesize("human", n_frames, seed=3, surface_points=8000)
    seq = s.to_point_sequence()
    print(f"\nSequence: human, {n_frames} frames, median {int(np.median(seq.counts))} points/frame")
    print(f"{'config':10s} {'ms/frame (median)':>18s} {'total s':>8s} {'NO mean cm':>11s} "
          f"{'NO p90 worst cm':>16s} {'corr cm':>8s}")
    clean = [f[lab >= 0] for f, lab in zip(s.frames, s.point_labels)]
    configs = {"default": RegistrationConfig(), "paper": paper_config().registration}
    rows = {}
    for name, cfg in configs.items():
        times: list[float] = []
        last = [time.perf_counter()]

        def tick(done: int, total: int) -> None:
            now = time.perf_counter()
            times.append(now - last[0])
            last[0] = now

        t0 = time.perf_counter()
        res = register_sequence(seq, cfg, progress=tick)
        total = time.perf_counter() - t0
        no_mean, no_p90, ce = sequence_errors(res, clean, s.surface)
        rows[name] = (1e3 * np.median(times[1:]), total, 100 * no_mean, 100 * no_p90, 100 * ce)
        print(f"{name:10s} {rows[name][0]:18.1f} {rows[name][1]:8.1f} {rows[name][2]:11.2f} "
              f"{rows[name][3]:16.2f} {rows[name][4]:8.2f}")
    r = np.array(rows["paper"]) / np.array(rows["default"])
    print(f"{'paper/def.':10s} {r[0]:17.2f}x {r[1]:7.2f}x {r[2]:10.2f}x {r[3]:15.2f}x {r[4]:7.2f}x")


def bench_cpd() -> None:
    """Table 3: probreg's non-rigid CPD against pointrig on one frame pair."""
    try:
        from probreg import cpd
    except ImportError:
        print("\nprobreg not installed (pip install probreg): CPD comparison skipped")
        return
    s = synthesize("human", 2, seed=4, surface_points=8000)
    seq = PointSequence(s.frames[:2])
    t0 = time.perf_counter()
    # both methods move frame 0's surface onto frame 1
    ours = register_sequence(seq, RegistrationConfig(rest_frame=0))
    t_ours = time.perf_counter() - t0
    e_ours = correspondence_error(ours.rest_points, ours.points, s.surface[:2],
                                  rest_frame_index(ours))[1].mean()
    src = ours.rest_points
    t0 = time.perf_counter()
    # CPD beta = 2 (Myronenko and Song) is probreg beta = 4: exp(-d^2 / (2 beta)).
    tf = cpd.registration_cpd(src, s.frames[1], tf_type_name="nonrigid", beta=4.0, lmd=2.0, w=0.01)
    t_cpd = time.perf_counter() - t0
    moved = np.stack([src, np.asarray(tf.transformation.transform(src))])
    e_cpd = correspondence_error(src, moved, s.surface[:2], 0)[1].mean()
    print("\nOne frame pair (frame 0's rest surface -> frame 1): time and mean correspondence "
          "error")
    print(f"{'method':22s} {'s':>7s} {'corr cm':>8s}")
    print(f"{'pointrig (2 frames)':22s} {t_ours:7.2f} {100 * e_ours:8.2f}")
    print(f"{'probreg CPD nonrigid':22s} {t_cpd:7.2f} {100 * e_cpd:8.2f}")
    print(f"{'CPD / pointrig':22s} {t_cpd / t_ours:6.1f}x {e_cpd / e_ours:7.1f}x")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--estep-child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--frames", type=int, default=100, help="frames of the sequence (table 2)")
    ap.add_argument("--skip-seq", action="store_true", help="leave out table 2")
    a = ap.parse_args(argv)
    if a.estep_child:
        estep_child()
        return 0
    bench_estep()
    if not a.skip_seq:
        bench_sequence(a.frames)
    bench_cpd()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
