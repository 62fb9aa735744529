"""Background removal speed on room scenes (640x480 frames, ~300k points each).

For each scene (``pointrig.synth`` figures with floor and back wall, and the greenman glTF
rig when it is in :data:`benchmarks.sets.MODELS`) the static planes are found once, then per
frame the connected-piece search of :func:`pointrig.preprocess.remove_background` runs twice
on the same points: the cell-representative graph the pipeline uses (``_connected_pieces``)
and the reference, the exact point graph (every pair within the radius), measured in the same
run. Prints the time per frame of each, their ratio, and how many points the two leave in a
different largest piece; then the whole ``remove_background`` per frame::

    python -m benchmarks.bench_background [--frames 6]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from benchmarks.sets import MODELS
from pointrig.background import _band_distance, find_background_planes, remove_background
from pointrig.geometry import _connected_pieces, connected_pieces_exact, median_spacing
from pointrig.synth import NoiseConfig, synthesize

_GREENMAN = MODELS / "greenman.glb"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=6)
    a = ap.parse_args(argv)
    if a.frames < 2:
        ap.error("--frames must be >= 2: the static planes are found across frames")
    print(f"{'scene':<12} {'points':>7} {'off-plane':>9} {'exact ms':>9} {'cells ms':>9} "
          f"{'ratio':>6} {'differ':>7} {'remove_background ms/frame':>27}")
    scenes: list[tuple[str, dict]] = [(f, {}) for f in ("human", "quadruped", "upper_body")]
    if _GREENMAN.exists():  # a large subject close to the camera: 150k points off the planes
        scenes.append((str(_GREENMAN), {"clip": "2_move"}))
    for fig, kw in scenes:
        syn = synthesize(fig, n_frames=a.frames, seed=3,
                         noise=NoiseConfig(seed=1, floor=True, background=True), **kw)
        seq = syn.to_point_sequence()
        planes, _ = find_background_planes(seq.frames, seed=0)
        te, tc, differ, npts, nsub = [], [], 0, [], []
        for pts in seq.frames:
            sub = pts[_band_distance(planes, pts) >= 1.0] if planes else pts
            r = 10.0 * median_spacing(sub)
            t0 = time.perf_counter()
            ce = connected_pieces_exact(sub, r)
            te.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            cc = _connected_pieces(sub, r)
            tc.append(time.perf_counter() - t0)
            differ += int(np.sum((ce == np.bincount(ce).argmax())
                                 != (cc == np.bincount(cc).argmax())))
            npts.append(len(pts))
            nsub.append(len(sub))
        t0 = time.perf_counter()
        remove_background(seq, seed=0)
        tb = (time.perf_counter() - t0) / len(seq.frames)
        print(f"{Path(fig).stem:<12} {int(np.mean(npts)):>7} {int(np.mean(nsub)):>9} "
              f"{1e3 * np.mean(te):>9.0f} "
              f"{1e3 * np.mean(tc):>9.0f} {np.mean(te) / np.mean(tc):>5.1f}x {differ:>7} "
              f"{1e3 * tb:>27.0f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
