"""Step 3's temporal rotation term (``[joints] rotation_smoothing``): joint accuracy and how
much the output bones turn from frame to frame, against the truth's bones.

Without the term, step 3 leaves the rotations of small, near-planar bones (a hand, a foot, a
blend piece at a joint: tens of points) to data that hardly determine them; they turn by tens
of degrees per frame, up to 180, where the rig's bones turn by at most 10-25 (docs/joints.md,
"Session 28"). An animation viewer (the exported ``skeleton.glb`` / ``.bvh``) shows them as
spinning bones. The term ``lambda/2 sum_t |R_j^(t-1) - 2 R_j^t + R_j^(t+1)|_F^2`` (``lambda
= rotation_smoothing x mean(a) x size^2``, docs/joints.md "Session 29") lets the data decide
where they can.

For each of the 14 sequences of ``bench_refine.py`` (100 frames; the glTF rigs need
``../shared/data/models``) the default pipeline runs once per value of ``--values``; the
first run writes the step-1 checkpoint in a temporary folder and the others reuse it
(``rotation_smoothing`` is not part of its key). Prints recall / precision / raw / normalised
error (cm) and the bones' per-frame rotation change (degrees; per bone the 90th percentile
over the frame pairs, then the median and the largest over the bones) of the output and of
the truth's skinned bones, then the means::

    PYTHONPATH=python python benchmarks/bench_bone_spin.py            # ~25 min
    PYTHONPATH=python python benchmarks/bench_bone_spin.py --frames 40 --only human,hand
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

from bench_refine import selected, suite  # noqa: E402
from bench_registration_downstream import score_joints  # noqa: E402

from pointrig.config import PipelineConfig  # noqa: E402
from pointrig.pipeline import extract  # noqa: E402


def frame_turn(R: np.ndarray, percentile: float = 90.0) -> np.ndarray:
    """Per bone, the ``percentile`` over the frame pairs of the angle (degrees) between its
    rotations in consecutive frames.

    Parameters
    ----------
    R
        ``(F, B, 3, 3)`` bone rotations (``T_frame_rest``), ``F >= 2``.

    Returns
    -------
    ``(B,)`` degrees.
    """
    rel = np.einsum("fbji,fbjk->fbik", R[:-1], R[1:])  # R_t^T R_(t+1)
    cos = (np.trace(rel, axis1=2, axis2=3) - 1.0) / 2.0
    return np.percentile(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))), percentile, axis=0)


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--only", default="", help="comma-separated sequence names")
    ap.add_argument("--values", default="0,0.01",
                    help="comma-separated rotation_smoothing values (the first writes the "
                         "step-1 checkpoint the others reuse)")
    a = ap.parse_args(argv)
    only = selected(ap, a.only)
    try:
        values = [float(v) for v in a.values.split(",") if v]
    except ValueError:
        ap.error(f"--values: not numbers: {a.values}")
    if not values or min(values) < 0:
        ap.error("--values: at least one value, all >= 0")
    base = PipelineConfig()
    cfgs = [dataclasses.replace(base, joints=dataclasses.replace(
        base.joints, rotation_smoothing=v)) for v in values]
    print("per value of rotation_smoothing: recall/precision raw normalised (cm), the output "
          "bones' per-frame turn (deg, p90 over frames: median / max over bones); truth's turn")
    print(f"{'sequence':<16} " + " ".join(f"{'smoothing ' + str(v):<34}" for v in values)
          + " truth")
    rows: list[list[tuple[float, ...]]] = [[] for _ in values]
    truth = []
    for name, syn in suite(a.frames, only):
        seq = syn.to_point_sequence()
        line = f"{name:<16}"
        with tempfile.TemporaryDirectory() as tmp:
            for i, cfg in enumerate(cfgs):
                res = extract(seq, cfg, tmp, pictures=False)
                rep = score_joints(res.skeleton.joint_positions, syn)
                turn = frame_turn(res.skeleton.bone_rotations)  # the output bones
                rows[i].append((rep.recall, rep.precision, 100 * rep.raw_error,
                                100 * rep.normalized_error, float(np.median(turn)),
                                float(turn.max())))
                r = rows[i][-1]
                line += (f" {r[0]:.2f}/{r[1]:.2f} {r[2]:5.2f} {r[3]:5.2f} "
                         f"{r[4]:5.1f}/{r[5]:5.1f}").ljust(35)
        gt = frame_turn(syn.bone_rotations[:, np.asarray(syn.skinned, bool)])
        truth.append((float(np.median(gt)), float(gt.max())))
        print(line + f" {truth[-1][0]:5.1f}/{truth[-1][1]:5.1f}", flush=True)
    if not truth:
        return 0
    print(f"\nmeans over {len(truth)} sequences of {a.frames} frames (errors over the sequences "
          "where every value matches a joint):")
    both = np.all([np.isfinite(np.array(r)[:, 3]) for r in rows], axis=0)
    for v, r in zip(values, rows):
        m = np.array(r)
        print(f"rotation_smoothing {v}: recall {m[:, 0].mean():.3f} precision {m[:, 1].mean():.3f} "
              f"raw {m[both, 2].mean():.2f} cm normalised {m[both, 3].mean():.2f} cm; turn "
              f"median {m[:, 4].mean():.1f} max {m[:, 5].mean():.1f} deg")
    t = np.array(truth)
    print(f"truth: turn median {t[:, 0].mean():.1f} max {t[:, 1].mean():.1f} deg")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
