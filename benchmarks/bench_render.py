"""Rendering speed: one 640x480 depth frame of a ~7k-triangle skinned mesh.

Compares the vectorised z-buffer rasteriser (pointrig.synth.render.rasterize) with the
naive reference (a Python loop over triangles, same maths) measured in the same run, and
times a whole synthetic frame (skinning + render + Kinect noise + back-projection).

    python -m benchmarks.bench_render
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from pointrig.synth import Camera, NoiseConfig, make_figure, synthesize
from pointrig.synth.render import rasterize, rasterize_naive


def best_of(fn: Callable[[], object], repeat: int) -> float:
    """Fastest of ``repeat`` calls of ``fn``, seconds."""
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    rows = []
    for name in ("quadruped", "hand", "human"):
        fig = make_figure(name)
        cam = Camera.kinect(640).placed_for(fig.vertices.min(0), fig.vertices.max(0))
        v = cam.world_to_camera(fig.vertices)
        tris = fig.triangles
        d_fast, _ = rasterize(v, tris, cam)
        d_naive, _ = rasterize_naive(v, tris, cam)
        assert np.array_equal(d_fast > 0, d_naive > 0)
        assert np.abs(d_fast - d_naive).max() < 1e-9
        t_fast = best_of(lambda: rasterize(v, tris, cam), 5)
        t_naive = best_of(lambda: rasterize_naive(v, tris, cam), 1)
        rows.append((name, len(tris), int((d_fast > 0).sum()), t_fast, t_naive))
    n_frames = 10
    t0 = time.perf_counter()
    synthesize("quadruped", n_frames=n_frames, camera=Camera.kinect(640), noise=NoiseConfig())
    t_frame = (time.perf_counter() - t0) / n_frames
    print("| mesh | triangles | pixels hit | vectorised ms | naive loop ms | speed-up |")
    print("|---|---|---|---|---|---|")
    for name, nt, px, tf, tn in rows:
        print(f"| {name} | {nt} | {px} | {tf * 1e3:.1f} | {tn * 1e3:.0f} | {tn / tf:.1f}x |")
    print(f"\nfull synthetic frame (quadruped, 640x480, skin + render + noise + points): "
          f"{t_frame * 1e3:.0f} ms/frame (mean of {n_frames})")


if __name__ == "__main__":
    main()
