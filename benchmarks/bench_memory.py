"""Peak memory (resident set) of ``pointrig extract`` against the number of frames.

A synthetic 640x480 depth capture is written frame by frame as 16-bit PNGs (millimetres) with
its ``intrinsics.json`` (:func:`write_depth_sequence`): a back wall 3 m away fills every pixel,
so each frame reads as 307,200 points (7.4 MB of float64), and a two-link arm of spheres in
front of it swings its two joints. ``--far 2.5`` keeps the arm (about 10,500 points a frame),
as a user isolates a subject. Each run is a fresh ``pointrig extract`` process whose peak
resident set is read from the kernel when it ends (``os.wait4``, ``ru_maxrss``)::

    python -m benchmarks.bench_memory                          # 100, 300 frames
    python -m benchmarks.bench_memory --frames 100,300,900,1800 --step1-only-above 100 \
        --one-chain-above 300

Prints, per frame count, the peak resident set of step 1 alone (``--stop-after
registration``: reading, clean-up and registration) and of the whole pipeline (up to
``--step1-only-above`` frames), in MB, with the run's seconds, and what holding every frame as
read would take (frames x 7.4 MB), the reference a bounded reader stays far below.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

WIDTH, HEIGHT = 640, 480
#: Kinect-like pinhole intrinsics of the synthetic capture (pixels; depth in millimetres)
INTRINSICS = {"fx": 525.0, "fy": 525.0, "cx": 319.5, "cy": 239.5, "depth_scale": 0.001,
              "width": WIDTH, "height": HEIGHT}
WALL_M = 3.0  # the back wall's depth, metres
FAR_M = 2.5  # the depth range that isolates the arm


def arm_spheres(t: int) -> tuple[np.ndarray, np.ndarray]:
    """The arm of frame ``t``: sphere centres ``(S, 3)`` and radii ``(S,)``, metres, camera
    frame. Two links of 0.45 m from a shoulder at (-0.3, 0, 1.8) m, bending in the image plane:
    the shoulder and the elbow swing with periods of 60 and 45 frames."""
    a = 0.7 * np.sin(2 * np.pi * t / 60.0)
    b = 0.6 + 0.7 * np.sin(2 * np.pi * t / 45.0 + 1.0)
    shoulder = np.array([-0.3, 0.0, 1.8])
    d1 = np.array([np.cos(a), np.sin(a), 0.0])
    elbow = shoulder + 0.45 * d1
    d2 = np.array([np.cos(a + b), np.sin(a + b), 0.0])
    s = np.linspace(0.0, 0.45, 10)
    centres = np.concatenate([shoulder + s[:, None] * d1, elbow + s[1:, None] * d2])
    radii = np.concatenate([np.full(10, 0.07), np.full(9, 0.055)])
    return centres, radii


def render_depth(t: int) -> np.ndarray:
    """Depth image ``(HEIGHT, WIDTH)`` uint16 millimetres of frame ``t``: the nearest of the
    wall and the arm's spheres along each pixel's ray (each sphere tested on the pixel box
    its outline projects into)."""
    k = INTRINSICS
    z = np.full((HEIGHT, WIDTH), WALL_M)
    for c, r in zip(*arm_spheres(t)):
        # the sphere's outline lies within r / (c_z - r) of its centre's ray (tangent plane)
        reach = r / (c[2] - r)
        u0, u1 = (k["cx"] + k["fx"] * (c[0] / c[2] + np.array([-reach, reach]) * 1.5)).round()
        v0, v1 = (k["cy"] + k["fy"] * (c[1] / c[2] + np.array([-reach, reach]) * 1.5)).round()
        u0, v0 = max(int(u0), 0), max(int(v0), 0)
        u1, v1 = min(int(u1) + 1, WIDTH), min(int(v1) + 1, HEIGHT)
        if u0 >= u1 or v0 >= v1:
            continue
        v, u = np.mgrid[v0:v1, u0:u1]
        rays = np.stack([(u - k["cx"]) / k["fx"], (v - k["cy"]) / k["fy"],
                         np.ones(u.shape)], axis=-1)  # z = 1 per ray
        # |s ray - c|^2 = r^2: the nearer root s is the depth
        rr = np.einsum("...i,...i->...", rays, rays)
        bq = rays @ c
        disc = bq * bq - rr * (c @ c - r * r)
        hit = disc > 0
        s = (bq[hit] - np.sqrt(disc[hit])) / rr[hit]
        box = z[v0:v1, u0:u1]
        box[hit] = np.minimum(box[hit], s)
    return np.rint(z * 1000.0).astype(np.uint16)


def write_depth_sequence(folder: str | Path, n_frames: int, first: int = 0) -> Path:
    """Write depth PNGs ``frame_{first:05d}.png`` ... up to frame ``n_frames - 1`` and
    ``intrinsics.json`` into ``folder`` (created), one frame at a time; returns the folder."""
    from PIL import Image

    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    (out / "intrinsics.json").write_text(json.dumps(INTRINSICS))
    for t in range(first, n_frames):
        Image.fromarray(render_depth(t)).save(out / f"frame_{t:05d}.png",
                                                        compress_level=1)
    return out


def peak_rss_mb(cmd: list[str]) -> tuple[float, float, int]:
    """Run ``cmd``; its peak resident set (MB), seconds and exit code."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    err = proc.stderr.read().decode(errors="replace") if proc.stderr else ""
    if proc.returncode != 0:
        print(err[-2000:], file=sys.stderr)
    return usage.ru_maxrss / 1024.0, time.perf_counter() - t0, proc.returncode


def extract_command(frames: Path, out: Path, step1_only: bool, one_chain: bool = False
                    ) -> list[str]:
    """The ``pointrig extract`` command measured (``one_chain``: step 1 from frame 0 only,
    ``--rest-frame 0``, instead of the best of three rest frames)."""
    cmd = [sys.executable, "-m", "pointrig", "extract", str(frames), "-o", str(out), "-q",
           "--no-pictures", "--far", str(FAR_M), "--no-resume"]
    return (cmd + (["--stop-after", "registration"] if step1_only else [])
            + (["--rest-frame", "0"] if one_chain else []))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", default="100,300", help="frame counts, comma-separated")
    ap.add_argument("--step1-only-above", type=int, default=10**9, metavar="F",
                    help="above F frames measure step 1 only (the whole pipeline takes long)")
    ap.add_argument("--one-chain-above", type=int, default=10**9, metavar="F",
                    help="above F frames register from frame 0 only (--rest-frame 0), a third "
                         "of the default's step 1 time")
    ap.add_argument("--workdir", default=None, help="where the captures are written "
                    "(default: a temporary folder, removed afterwards)")
    a = ap.parse_args(argv)
    counts = [int(c) for c in a.frames.split(",")]
    full_frame_mb = WIDTH * HEIGHT * 3 * 8 / 1e6
    print(f"{'frames':>6} {'all frames as read MB':>21} {'rest frame':>10} "
          f"{'step 1 peak MB':>14} {'s':>6} {'pipeline peak MB':>16} {'s':>6}", flush=True)
    with tempfile.TemporaryDirectory(dir=a.workdir) as tmp:
        frames = Path(tmp) / "depth"
        written = 0
        for n in sorted(counts):
            # one capture, extended as the counts grow; each run reads its first n frames
            write_depth_sequence(frames, n, first=written)
            written = n
            run = Path(tmp) / f"run{n}"
            run.mkdir()
            for t in range(n):
                os.link(frames / f"frame_{t:05d}.png", run / f"frame_{t:05d}.png")
            os.link(frames / "intrinsics.json", run / "intrinsics.json")
            one = n > a.one_chain_above
            rss1, s1, rc1 = peak_rss_mb(extract_command(run, Path(tmp) / f"out1_{n}", True, one))
            row = (f"{n:>6} {n * full_frame_mb:>21.0f} {'0' if one else 'fit':>10} "
                   f"{rss1 if rc1 == 0 else float('nan'):>14.0f} {s1:>6.0f}")
            if n <= a.step1_only_above:
                rss, s, rc = peak_rss_mb(extract_command(run, Path(tmp) / f"out_{n}", False,
                                                         one))
                row += f" {rss if rc == 0 else float('nan'):>16.0f} {s:>6.0f}"
            else:
                row += f" {'-':>16} {'-':>6}"
            print(row, flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
