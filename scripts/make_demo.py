"""Regenerate the bundled demo sequence in python/pointrig/data/demo/ (deterministic).

An upper body (11 joints) waving its arms and turning, 24 frames, seen by a Kinect v1 at
320x240 with the default sensor noise (axial noise, disparity quantisation, flying pixels,
dropout, outliers). Frames are float32 binary PLY; gt.npz holds the ground truth.

    PYTHONPATH=python python scripts/make_demo.py [OUT_DIR]
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

from pointrig.synth import Camera, NoiseConfig, synthesize

N_FRAMES = 24
SURFACE_POINTS = 1500


def make_demo(out: Path):
    """Synthesize the demo sequence and write it to ``out``."""
    seq = synthesize("upper_body", n_frames=N_FRAMES, seed=0, camera=Camera.kinect(320),
                     noise=NoiseConfig(seed=0), surface_points=SURFACE_POINTS)
    if (out / "frames").exists():
        shutil.rmtree(out / "frames")
    seq.write(out, float32=True)
    return seq


def main() -> None:
    root = Path(__file__).resolve().parents[1]
    out = Path(sys.argv[1]) if len(sys.argv) > 1 else root / "python" / "pointrig" / "data" / "demo"
    seq = make_demo(out)
    size = sum(f.stat().st_size for f in out.rglob("*") if f.is_file())
    pts = [len(f) for f in seq.frames]
    print(f"wrote {out}: {seq.n_frames} frames, {min(pts)}-{max(pts)} points, "
          f"{len(seq.joint_names)} joints, {size / 1e6:.2f} MB")


if __name__ == "__main__":
    main()
