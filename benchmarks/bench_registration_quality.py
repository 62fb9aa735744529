"""Registration speed and quality on synthetic sequences with ground truth (step 1, §4).

Prints, per sequence: total and median ms/frame, mean EM iterations, nearest-observed-point
distance (mean, worst-frame mean, worst-frame p90) and the correspondence error against the
exact surface correspondences (``SynthSequence.surface``), in cm. Not a timed test.

Sequences: ``human`` = ``synthesize("human", 60)``; ``hard`` = fast arm
(``synthesize("arm", 30, speed=4, seed=2)``) and walk (``synthesize("human", 30, walk=2.5,
seed=1)``).

Usage::

    PYTHONPATH=python python benchmarks/bench_registration_quality.py \\
        [--overrides '{"subsample": 0.0, "motion_tol": 0.0, "cutoff": 5.0}'] [--set all]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))


def run(name: str, n: int, cfg, **kw) -> None:
    from registration_helpers import correspondence_error, nearest_observed

    from pointrig.registration import register_sequence
    from pointrig.synth import synthesize

    s = synthesize(name, n, **kw)
    seq = s.to_point_sequence()
    times: list[float] = []
    last = [time.perf_counter()]

    def prog(done: int, total: int) -> None:
        now = time.perf_counter()
        times.append(now - last[0])
        last[0] = now

    t0 = time.perf_counter()
    res = register_sequence(seq, cfg, progress=prog)
    tot = time.perf_counter() - t0
    clean = [f[lab >= 0] for f, lab in zip(s.frames, s.point_labels)]
    no = nearest_observed(res.points, clean)
    ce = correspondence_error(res.rest_points, res.points, s.surface)
    npts = np.mean([len(f) for f in s.frames])
    print(
        f"{name:6s} {json.dumps(kw):28s} N~{npts:5.0f} total {tot:6.1f} s  "
        f"median {1e3 * np.median(times[1:]):6.0f} ms/frame  iters {res.iterations.mean():4.1f}  "
        f"NO mean {100 * no.mean():.2f} worst-frame mean {100 * no.mean(1).max():.2f} "
        f"worst-frame p90 {100 * np.percentile(no, 90, axis=1).max():.2f}  "
        f"corr mean {100 * ce.mean():.2f} last frame {100 * ce[-1].mean():.2f} cm",
        flush=True,
    )


def main(argv: list[str] | None = None) -> int:
    from pointrig.config import RegistrationConfig

    ap = argparse.ArgumentParser()
    ap.add_argument("--overrides", default="{}", help="RegistrationConfig fields as JSON")
    ap.add_argument("--set", choices=["human", "hard", "all"], default="all")
    args = ap.parse_args(argv)
    cfg = RegistrationConfig(**json.loads(args.overrides))
    if args.set in ("human", "all"):
        run("human", 60, cfg)
    if args.set in ("hard", "all"):
        run("arm", 30, cfg, speed=4, seed=2)
        run("human", 30, cfg, walk=2.5, seed=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
