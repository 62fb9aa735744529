"""Run time and peak memory of the whole pipeline against the number of frames and the points
per frame.

A synthetic human (moderate Kinect noise, 2 % outliers) is rendered with as many frames as
asked and a camera of Kinect v1's field of view whose resolution gives about the points per
frame asked (about 10k at 640x480; the points grow about with the pixels, and one probe frame
corrects the first guess). Each size runs in a
fresh process: one renders the sequence into a temporary file, another reads it and runs
``extract`` (no output folder), so that the peak resident memory (``ru_maxrss``) is the
pipeline's with its input, not the renderer's. Printed per size: the frames, the median
points per frame, the input's size in memory (MB), wall and CPU seconds, CPU seconds per
frame, peak memory (MB) and the wall seconds of the main stages (:mod:`benchmarks.stages`),
so that a stage worse than linear in frames shows as a growing per-frame figure::

    python -m benchmarks.bench_scaling                  # frames 50-1600 at 10k, points 5k-300k
    python -m benchmarks.bench_scaling --quick          # frames 50, 100 at 5k; points 5k, 10k
    python -m benchmarks.bench_scaling --frames 50,100 --points 10000

The full table takes hours on two cores (1,600 frames; 300k points a frame); run it on an
otherwise idle machine.
"""

from __future__ import annotations

import argparse
import json
import math
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
#: points per frame of the human at 640x480
POINTS_AT_640 = 10_400
#: stage columns of the table (names of :data:`benchmarks.stages.STAGES`)
COLUMNS = ("step 1 registration", "step 2 structure", "step 3 tracking", "step 3 joints",
           "refinement")
SHORT = {"step 1 registration": "step 1", "step 2 structure": "step 2",
         "step 3 tracking": "tracking", "step 3 joints": "step 3", "refinement": "refine"}


def camera_width(points: int) -> int:
    """The camera width (pixels, Kinect v1's field of view) that gives about ``points``
    points a frame on the synthetic human: the points grow with the pixel count."""
    return max(16, int(round(640 * math.sqrt(points / POINTS_AT_640))))


def render(frames: int, points: int, path: Path, seed: int = 5) -> None:
    """Render the sequence into ``path`` (``.npz``: the frames' points concatenated,
    ``(sum N_t, 3)`` metres, and their ``counts (F,)``)."""
    import dataclasses

    from pointrig.synth import Camera, NoiseConfig, synthesize

    noise = dataclasses.replace(NoiseConfig(), outliers=0.02)
    width = camera_width(points)
    # the points do not grow exactly with the pixels (edges, dropout): one correction from a
    # frame rendered at the first guess
    probe = synthesize("human", n_frames=1, seed=seed, camera=Camera.kinect_fov(width),
                       noise=noise)
    width = max(16, int(round(width * math.sqrt(points / max(len(probe.frames[0]), 1)))))
    s = synthesize("human", n_frames=frames, seed=seed, camera=Camera.kinect_fov(width),
                   noise=noise)
    np.savez(path, points=np.concatenate(s.frames), counts=np.array([len(f) for f in s.frames]))


def measure(path: Path) -> dict[str, object]:
    """Read ``path`` (:func:`render`), run :func:`pointrig.pipeline.extract` and return its
    seconds, per-stage wall seconds and the process's peak resident memory (MB)."""
    from benchmarks.stages import StageProfile
    from pointrig.config import PipelineConfig
    from pointrig.pipeline import extract
    from pointrig.sequence import PointSequence

    with np.load(path) as z:
        pts, counts = z["points"], z["counts"]
    seq = PointSequence(np.split(pts, np.cumsum(counts)[:-1]))
    del pts
    prof = StageProfile()
    with prof.recording():
        extract(seq, PipelineConfig(), None, pictures=False)
    return {"frames": len(counts), "points": int(np.median(counts)),
            "input_mb": float(counts.sum() * 24 / 2**20), "wall": prof.total.wall,
            "cpu": prof.total.cpu,
            "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
            "stages": {name: prof.times[name].wall for name in COLUMNS}}


def run_size(frames: int, points: int) -> dict[str, object]:
    """One size in fresh processes (render, then measure)."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "seq.npz"
        for args in (["--render", str(frames), str(points), str(path)],
                     ["--measure", str(path)]):
            res = subprocess.run([sys.executable, "-m", "benchmarks.bench_scaling", *args],
                                 cwd=ROOT, capture_output=True, text=True)
            if res.returncode != 0:
                raise RuntimeError(f"{frames} frames x {points} points: {res.stderr.strip()}")
        return json.loads(res.stdout.strip().splitlines()[-1])


def header() -> str:
    return (f"{'frames':>7}{'points':>9}{'input MB':>10}{'wall s':>9}{'CPU s':>9}"
            f"{'CPU s/frame':>13}{'peak MB':>9}" + "".join(f"{SHORT[c]:>10}" for c in COLUMNS))


def row(r: dict[str, object]) -> str:
    st = r["stages"]
    assert isinstance(st, dict)
    return (f"{r['frames']:>7}{r['points']:>9}{r['input_mb']:>10.1f}{r['wall']:>9.1f}"
            f"{r['cpu']:>9.1f}{float(r['cpu']) / int(r['frames']):>13.3f}{r['peak_mb']:>9.0f}"  # type: ignore[arg-type]
            + "".join(f"{st[c]:>10.1f}" for c in COLUMNS))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", default="50,100,200,400,800,1600",
                    help="frame counts of the first table (comma-separated)")
    ap.add_argument("--points", default="5000,10000,30000,100000,300000",
                    help="points per frame of the second table (comma-separated)")
    ap.add_argument("--base-points", type=int, default=10_000,
                    help="points per frame of the frames table")
    ap.add_argument("--base-frames", type=int, default=100,
                    help="frames of the points table")
    ap.add_argument("--quick", action="store_true",
                    help="a small subset: 50 and 100 frames at 5k points, 5k and 10k points "
                         "at 50 frames")
    ap.add_argument("--render", nargs=3, help=argparse.SUPPRESS)
    ap.add_argument("--measure", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.render:
        render(int(a.render[0]), int(a.render[1]), Path(a.render[2]))
        return 0
    if a.measure:
        print(json.dumps(measure(Path(a.measure))))
        return 0
    if a.quick:
        a.frames, a.points, a.base_points, a.base_frames = "50,100", "5000,10000", 5000, 50
    try:
        frames = [int(v) for v in a.frames.split(",") if v]
        points = [int(v) for v in a.points.split(",") if v]
    except ValueError:
        ap.error("--frames and --points are comma-separated integers")
    if any(v < 2 for v in frames) or any(v < 100 for v in points):
        ap.error("at least 2 frames and 100 points a frame")
    t0 = time.perf_counter()
    print(f"Frames, about {a.base_points} points a frame", flush=True)
    print(header(), flush=True)
    for f in frames:
        print(row(run_size(f, a.base_points)), flush=True)
    print(f"\nPoints per frame, {a.base_frames} frames", flush=True)
    print(header(), flush=True)
    for p in points:
        print(row(run_size(a.base_frames, p)), flush=True)
    print(f"\n{time.perf_counter() - t0:.0f} s in all")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
