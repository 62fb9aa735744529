"""The refinement from the skeleton on long sequences: the pipeline with ``refine_rounds`` 0
(the paper's single pass) and 1 (the default) on the same registration.

Step 1 registers each frame from its neighbour, so on a 100-frame sequence its chains are 50
frames long and a lost or slid part stays so. The refinement (``RegistrationConfig.
refine_rounds``, docs/registration.md "Session 26") registers every frame again from step 3's
tracked pose, with no chain, and runs steps 2 and 3 again.

For each of 14 sequences (the ``pointrig.synth`` figures and the glTF rigs of
``../shared/data/models``; moderate Kinect noise, 2 % outliers; one seed each) the pipeline
runs once with ``refine_rounds = 0`` (writing the step-1 checkpoint in a temporary folder) and
once with ``refine_rounds = 1`` (reusing it: ``refine_rounds`` is not part of its key). Prints
recall / precision / raw / normalised error (cm) and the whole pipeline's run time per
sequence and variant, then the means (the normalised and raw means over the
sequences where both variants match a joint)::

    PYTHONPATH=python python benchmarks/bench_refine.py            # 100 frames, ~12 min
    PYTHONPATH=python python benchmarks/bench_refine.py --frames 40 --only human,girl_run
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "python"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_registration_downstream import score_joints  # noqa: E402

from pointrig.config import PipelineConfig  # noqa: E402
from pointrig.pipeline import extract  # noqa: E402
from pointrig.synth import Camera, NoiseConfig, synthesize  # noqa: E402

_MODELS = Path(__file__).resolve().parents[2] / "shared" / "data" / "models"

#: name -> (figure or glb, synthesize() keywords); the glTF rigs need ../shared/data/models
SEQUENCES: dict[str, tuple[str, dict]] = {
    "human": ("human", {"seed": 5}),
    "human_s8": ("human", {"seed": 8}),
    "human_walk": ("human", {"seed": 7, "walk": 2.0}),
    "upper_body": ("upper_body", {"seed": 2}),
    "hand": ("hand", {"seed": 2}),
    "quadruped_320": ("quadruped", {"seed": 7, "camera": "320"}),
    "snake": ("snake", {"seed": 2}),
    "girl_run": (str(_MODELS / "girl.glb"), {"seed": 4, "clip": "RunTrack"}),
    "girl_run_s5": (str(_MODELS / "girl.glb"), {"seed": 5, "clip": "RunTrack", "yaw": -30}),
    "girl_idle": (str(_MODELS / "girl.glb"), {"seed": 5, "clip": "IdleTrack"}),
    "rigged_yaw20": (str(_MODELS / "rigged_figure.glb"), {"seed": 4, "yaw": 20}),
    "rigged_start": (str(_MODELS / "rigged_figure.glb"),
                     {"seed": 5, "yaw": -40, "start": 0.5}),
    "greenman_move": (str(_MODELS / "greenman.glb"), {"seed": 4, "clip": "2_move"}),
    "greenman_attack": (str(_MODELS / "greenman.glb"), {"seed": 5, "clip": "3_attack"}),
}


def _synth(source: str, kw: dict, frames: int):
    kw = dict(kw)
    camera = Camera.kinect(int(kw.pop("camera", "640")))
    return synthesize(source, n_frames=frames, camera=camera,
                      noise=dataclasses.replace(NoiseConfig(), outliers=0.02), **kw)


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--only", default="", help="comma-separated sequence names")
    a = ap.parse_args(argv)
    only = {n for n in a.only.split(",") if n}
    if only - set(SEQUENCES):
        ap.error(f"--only: unknown {', '.join(sorted(only - set(SEQUENCES)))}; "
                 f"known: {', '.join(SEQUENCES)}")
    base = PipelineConfig()
    cfgs = {r: dataclasses.replace(base, registration=dataclasses.replace(
        base.registration, refine_rounds=r)) for r in (0, 1)}
    rows: dict[int, list[tuple[float, float, float, float]]] = {0: [], 1: []}
    print(f"{'sequence':<16} {'refine_rounds 0: rec/prec raw norm (s)':<40} "
          f"{'refine_rounds 1: rec/prec raw norm (s)':<40}")
    for name, (source, kw) in SEQUENCES.items():
        if only and name not in only:
            continue
        if source.endswith(".glb") and not Path(source).exists():
            print(f"{name:<16} skipped: {source} not found")
            continue
        syn = _synth(source, kw, a.frames)
        seq = syn.to_point_sequence()
        line = f"{name:<16}"
        t_reg = 0.0
        with tempfile.TemporaryDirectory() as tmp:
            for r in (0, 1):
                res = extract(seq, cfgs[r], tmp, pictures=False)
                if r == 0:
                    t_reg = res.timings["registration"]
                # the whole pipeline's time (the second run reuses the first's registration)
                secs = t_reg + sum(v for k, v in res.timings.items() if k != "registration")
                rep = score_joints(res.skeleton.joint_positions, syn)
                rows[r].append((rep.recall, rep.precision, 100 * rep.raw_error,
                                100 * rep.normalized_error))
                line += (f" {rep.recall:.2f}/{rep.precision:.2f} {100 * rep.raw_error:6.2f} "
                         f"{100 * rep.normalized_error:5.2f} ({secs:5.1f} s)".ljust(41))
        print(line, flush=True)
    if not rows[0]:
        return 0
    m0, m1 = np.array(rows[0]), np.array(rows[1])
    both = np.isfinite(m0[:, 3]) & np.isfinite(m1[:, 3])
    print(f"\nmeans over {len(m0)} sequences of {a.frames} frames (errors over the {both.sum()} "
          "where both match a joint):")
    for r, m in ((0, m0), (1, m1)):
        print(f"refine_rounds {r}: recall {m[:, 0].mean():.3f} precision {m[:, 1].mean():.3f} "
              f"raw {m[both, 2].mean():.2f} cm normalised {m[both, 3].mean():.2f} cm")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
