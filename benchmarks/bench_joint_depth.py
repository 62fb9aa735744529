"""The output joints' depth along the camera ray: each reading of the chord rule against none.

``[joints] joint_depth = "chord"`` (docs/joints.md "Session 47") moves each output joint along
its rest-frame camera ray to the front depth at its pixel plus the half-width of the
silhouette's shortest chord through that pixel (:func:`pointrig.view.view_depth_joints`). The
pass runs after everything else, so one pipeline run per sequence (with the pass off and the
fitted bone rolls, whose joint trajectories the default's ``bone_twist = "minimal"`` keeps
exactly) serves every reading: the silhouette of all observed points, of the joint's two bones,
of its own bone, their consensus (session 47), each moving joints both ways or only away from
the camera, and the whole view where it is neither occluded nor flat, else the consensus
("visible", the default since session 48). Prints per sequence the recall of each variant,
then per variant the means of recall / precision / normalised / raw error (cm) over the glTF
rigs and over the procedural figures::

    PYTHONPATH=python python benchmarks/bench_joint_depth.py     # suite + validation, ~25 min
    PYTHONPATH=python python benchmarks/bench_joint_depth.py --sets suite --only human,girl_run
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "python"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_refine import SETS, selected, suite  # noqa: E402
from bench_registration_downstream import score_joints  # noqa: E402

from pointrig.config import PipelineConfig, apply_overrides  # noqa: E402
from pointrig.kinematics import joint_trajectories  # noqa: E402
from pointrig.pipeline import extract  # noqa: E402
from pointrig.view import view_depth_joints  # noqa: E402

#: (label, points, direction) of each variant; ``None`` = the joints as step 3 left them
VARIANTS: list[tuple[str, str | None, str]] = [
    ("off", None, "both"),
    ("all", "all", "both"),
    ("adjacent", "adjacent", "both"),
    ("child", "child", "both"),
    ("all, back only", "all", "back"),
    ("consensus", "consensus", "both"),
    ("consensus, back only", "consensus", "back"),
    ("visible", "visible", "both"),
]


def is_gltf(source: str) -> bool:
    """True for a sequence rendered from a glTF rig (an artist's mesh), not a procedural
    figure."""
    return source.endswith(".glb")


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sets", default="suite,validation",
                    help=f"comma-separated sets among {', '.join(sorted(SETS))}")
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--only", default="", help="comma-separated sequence names")
    ap.add_argument("--depth-frames", type=int, default=PipelineConfig().joints.depth_frames)
    a = ap.parse_args(argv)
    sets = [s for s in a.sets.split(",") if s]
    if not sets or set(sets) - set(SETS):
        ap.error(f"--sets: choose among {', '.join(sorted(SETS))}")
    sequences = {k: v for s in sets for k, v in SETS[s].items()}
    only = selected(ap, a.only, sequences)
    print(f"{'sequence':<24} " + " ".join(f"{v[0][:12]:>12}" for v in VARIANTS)
          + "   (recall; pass seconds)")
    rows = run(sequences, only, a.frames, a.depth_frames)
    gltf = {n for n in rows["off"] if is_gltf(sequences[n][0])}
    print(f"\n{'variant':<22} {'glTF rigs: rec / prec / norm / raw cm':<40} "
          f"{'procedural: rec / prec / norm / raw cm':<40}")
    for label, *_ in VARIANTS:
        out = f"{label:<22}"
        for sel in (True, False):
            R = np.array([v for n, v in rows[label].items() if (n in gltf) == sel])
            if len(R) == 0:
                out += f" {'-':<40}"
                continue
            out += (f" {R[:, 0].mean():.3f} / {R[:, 1].mean():.3f} / "
                    f"{100 * np.nanmean(R[:, 2]):.2f} / {100 * np.nanmean(R[:, 3]):.2f} "
                    f"({len(R)})".ljust(41))
        print(out)
    return 0


def run(sequences: dict[str, tuple[str, dict]], only: set[str], frames: int,
        depth_frames: int) -> dict[str, dict[str, tuple[float, float, float, float]]]:
    """Score every variant of :data:`VARIANTS` on ``sequences`` (those in ``only``, all if
    empty) of ``frames`` frames, reading ``depth_frames`` frames; prints a line per sequence.

    Returns
    -------
    dict
        ``rows[label][name] = (recall, precision, normalised error m, raw error m)``.
    """
    cfg = apply_overrides({"joints": {"joint_depth": "off", "bone_twist": "fit"}})
    rows: dict[str, dict[str, tuple[float, float, float, float]]] = {v[0]: {} for v in VARIANTS}
    for name, syn in suite(frames, only, sequences):
        seq = syn.to_point_sequence()
        res = extract(seq, cfg, None, pictures=False)
        sk, st = res.skeleton, res.structure
        final = res.refined_registration or res.registration
        observed = res.frames  # the frames the pipeline read, after its clean-up
        line, secs = f"{name:<24} ", []
        for label, points, direction in VARIANTS:
            P = sk.joint_positions
            if points is not None and st.view_camera is not None:
                t0 = time.perf_counter()
                J, _ = view_depth_joints(observed, final.points, sk.labels, sk.parents,
                                         sk.rest_positions, sk.bone_rotations,
                                         sk.bone_translations, st.view_camera,
                                         n_frames=depth_frames, points=points,
                                         direction=direction)
                secs.append(time.perf_counter() - t0)
                P = joint_trajectories(J, sk.bone_rotations, sk.bone_translations, sk.parents)
            r = score_joints(P, syn)
            rows[label][name] = (r.recall, r.precision, r.normalized_error, r.raw_error)
            line += f" {r.recall:12.2f}"
        print(line + f"   ({', '.join(f'{s:.1f}' for s in secs)})", flush=True)
    return rows


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
