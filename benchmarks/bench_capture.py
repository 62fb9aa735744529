"""The default pipeline on the same sequences captured otherwise: image size and frame rate.

The suite renders every sequence at 640x480 and 30 frames per second. A user's camera may give
more points per frame (a closer subject, a RealSense at 1280x720, an Azure Kinect) or another
frame rate (15 fps on a slow link, 60 fps), and the held-out rigs may be captured so. Each
condition ``WIDTH@FPS`` of ``--conditions`` renders the same motion, view and sensor noise:

- a pinhole camera of the suite's field of view (Kinect v1: 640x480, fx = fy = 525) ``WIDTH``
  pixels wide (height 3/4 of it, focal length scaled): 1280 holds 4x the points of 640. The
  depth noise (disparity quantisation, axial noise) is the sensor's and does not change; the
  lateral jitter is in pixels, so it shrinks in metres;
- ``FPS`` frames per second over the same stretch of motion: ``--frames`` at 30 fps, so 15
  fps has half the frames and twice the motion between two of them (the auto-placed camera
  frames the sampled poses, so it may sit a few millimetres elsewhere;
  ``tests/test_bench_capture.py`` checks that the poses are the same).

Prints per sequence and condition the median points per frame, frames, joints, recall /
precision, raw / normalised cm and the run time, the time also as a ratio to the first
condition's, measured in the same run; then the means per condition::

    PYTHONPATH=python python benchmarks/bench_capture.py                     # ~16 min
    PYTHONPATH=python python benchmarks/bench_capture.py --conditions 640@30,1280@30 --only human
    PYTHONPATH=python python benchmarks/bench_capture.py --repeat 1  # the rounding spread
    PYTHONPATH=python python benchmarks/bench_capture.py --variant \\
        '{"registration": {"sigma2_start": "data"}}'                       # another config

The sequences are names of :data:`bench_refine.SEQUENCES` or :data:`bench_refine.VALIDATION`;
a sequence's own camera setting (``quadruped_320``) is replaced by the conditions here.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "python"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_refine import SETS, _jittered  # noqa: E402
from bench_registration_downstream import score_joints  # noqa: E402

from pointrig.config import apply_overrides  # noqa: E402
from pointrig.pipeline import extract  # noqa: E402
from pointrig.synth import synthesize  # noqa: E402
from pointrig.synth.camera import Camera  # noqa: E402
from pointrig.synth.noise import NoiseConfig  # noqa: E402

DEFAULT_SEQUENCES = "human,human_walk,girl_run,v_girl_run_y30,quadruped_320"


def parse_conditions(text: str) -> list[tuple[int, float]]:
    """``"640@30,1280@15"`` -> ``[(640, 30.0), (1280, 15.0)]`` (width in pixels, frames per
    second); ``ValueError`` naming the problem otherwise."""
    conds = []
    for item in (c for c in text.split(",") if c):
        try:
            w, f = item.split("@")
            cond = (int(w), float(f))
        except ValueError:
            raise ValueError(f"expected WIDTH@FPS[,...], got {item!r}") from None
        if cond[0] < 16 or not 0 < cond[1] < float("inf"):
            raise ValueError(f"widths of 16 pixels or more and positive frame rates, got {item!r}")
        conds.append(cond)
    if not conds:
        raise ValueError("no condition given")
    return conds


def frames_at(fps: float, frames_at_30: int) -> int:
    """Frames covering the stretch of motion that ``frames_at_30`` frames cover at 30 fps."""
    return max(2, int(round(frames_at_30 * fps / 30)))


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--conditions", default="640@30,1280@30,640@15,640@60",
                    help="WIDTH@FPS, comma-separated; the first is the reference")
    ap.add_argument("--only", default=DEFAULT_SEQUENCES, help="sequences, comma-separated")
    ap.add_argument("--frames", type=int, default=100, help="frames at 30 fps (default 100)")
    ap.add_argument("--repeat", type=int, default=0,
                    help="0: the input as generated; k > 0: moved by at most 1e-9 m (seed k), "
                         "the rounding spread of bench_suite.py's repeat k")
    ap.add_argument("--variant", default="{}",
                    help="JSON per-stage overrides of the defaults, as bench_suite.py's variants")
    args = ap.parse_args(argv)
    try:
        conds = parse_conditions(args.conditions)
    except ValueError as exc:
        ap.error(f"--conditions: {exc}")
    try:
        overrides = json.loads(args.variant)
        if not isinstance(overrides, dict):
            raise ValueError("not a JSON object of {stage: {parameter: value}}")
        config = apply_overrides(overrides, where="--variant")
    except ValueError as exc:  # ConfigError is one
        ap.error(str(exc) if str(exc).startswith("--variant") else f"--variant: {exc}")
    known = {**SETS["suite"], **SETS["validation"]}
    names = [n for n in args.only.split(",") if n]
    unknown = [n for n in names if n not in known]
    if unknown:
        ap.error(f"--only: unknown {', '.join(unknown)}; known: {', '.join(known)}")
    print(f"{'sequence':16s} {'condition':>9s} {'pts/frame':>9s} {'frames':>6s} {'joints':>6s} "
          f"{'rec / prec':>11s} {'raw cm':>7s} {'norm cm':>7s} {'time s':>7s} {'x ref':>6s}",
          flush=True)
    rows: dict[tuple[int, float], list[tuple[float, ...]]] = {c: [] for c in conds}
    for name in names:
        source, kw = known[name]
        kw = {k: v for k, v in kw.items() if k != "camera"}
        ref_time = None
        for w, fps in conds:
            n_frames = frames_at(fps, args.frames)
            syn = synthesize(source, n_frames=n_frames, camera=Camera.kinect_fov(w), fps=fps,
                             noise=dataclasses.replace(NoiseConfig(), outliers=0.02), **kw)
            seq = syn.to_point_sequence()
            if args.repeat > 0:
                seq = _jittered(seq, args.repeat)
            t0 = time.perf_counter()
            out = extract(seq, config, None, pictures=False)
            seconds = time.perf_counter() - t0
            ref_time = seconds if ref_time is None else ref_time
            rep = score_joints(out.skeleton.joint_positions, syn)
            npts = int(np.median([len(f) for f in seq.frames]))
            rows[w, fps].append((rep.recall, rep.precision, rep.raw_error,
                                 rep.normalized_error, seconds))
            cond = f"{w}@{fps:g}"
            print(f"{name:16s} {cond:>9s} {npts:9d} {n_frames:6d} "
                  f"{out.skeleton.joint_positions.shape[1]:6d} "
                  f"{rep.recall:5.2f} / {rep.precision:4.2f} {100 * rep.raw_error:7.2f} "
                  f"{100 * rep.normalized_error:7.2f} {seconds:7.1f} {seconds / ref_time:6.2f}",
                  flush=True)
    print("\nmeans over the sequences (errors over those matching a joint):")
    ref_total = float(np.array(rows[conds[0]], dtype=float)[:, 4].sum())
    for w, fps in conds:
        a = np.array(rows[w, fps], dtype=float)
        print(f"  {w}@{fps:g}: recall {a[:, 0].mean():.3f} precision {a[:, 1].mean():.3f} "
              f"raw {100 * np.nanmean(a[:, 2]):.2f} cm normalised "
              f"{100 * np.nanmean(a[:, 3]):.2f} cm, time {a[:, 4].sum():.0f} s "
              f"({a[:, 4].sum() / ref_total:.2f} x the first condition)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
