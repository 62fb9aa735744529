"""Registration variants judged downstream: correspondence error and step-2 joints.

For each sequence (the ``pointrig.synth`` figures plus, when present, the CC0/CC-BY glTF rigs of
``../shared/data/models``; 40 frames, seed 0, moderate Kinect noise, 2 % outliers) and each
registration variant (JSON overrides of :class:`~pointrig.config.RegistrationConfig`), prints
step-2 recall / precision / normalised error / bone count, the mean correspondence error
against the exact surface, and a mean row per variant. Run::

    PYTHONPATH=python python benchmarks/bench_registration_downstream.py \
        '{}' '{"sigma2_start": "residual"}' '{"beta_smooth_rel": 1.0, "smooth_robust": 0.1}'
"""

from __future__ import annotations

import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from pointrig.config import PipelineConfig
from pointrig.evaluate import evaluate
from pointrig.pipeline import build_skeleton
from pointrig.registration import register_sequence
from pointrig.structure import extract_structure
from pointrig.synth import NoiseConfig, synthesize

MODELS = Path(__file__).resolve().parents[2] / "shared" / "data" / "models"
FIGURES = ["human", "upper_body", "arm", "hand", "quadruped", "snake"] + [
    str(p) for p in sorted(MODELS.glob("*.glb"))
]


def score_joints(joint_positions: np.ndarray, syn, swing_source: str = "auto"):
    """``EvalReport`` of predicted joints ``(F, J, 3)`` (metres) against ``syn``'s ground truth
    (``swing_source``: the articulation test's motions, :func:`pointrig.evaluate.evaluate`)."""
    return evaluate(joint_positions, syn.gt_joints, syn.joint_parents, **syn.eval_kwargs(),
                    swing_source=swing_source)


def score_step2(rest: np.ndarray, points: np.ndarray, syn, config, swing_source: str = "auto"):
    """Step 2 on ``rest (M, 3)`` / ``points (F, M, 3)`` scored against ``syn``'s ground truth;
    returns ``(EvalReport, StructureResult)``."""
    st = extract_structure(rest, points, config)
    sk = build_skeleton(rest, st.bone_parent, st.joints_rest, st.R, st.T, None, st.labels)
    return score_joints(sk.joint_positions, syn, swing_source), st


def main(argv: list[str]) -> int:
    variants = [json.loads(a) for a in argv] or [{}]
    cfg = PipelineConfig()
    rows: dict[str, list[tuple[float, ...]]] = {json.dumps(v): [] for v in variants}
    for fig in FIGURES:
        syn = synthesize(fig, n_frames=40, seed=0, noise=NoiseConfig(seed=0))
        seq = syn.to_point_sequence()
        out = []
        for v in variants:
            t0 = time.perf_counter()
            reg = register_sequence(seq, dataclasses.replace(cfg.registration, **v))
            ms = 1000 * (time.perf_counter() - t0) / seq.n_frames
            # rest points come from the rest frame (the middle one by default)
            nn = cKDTree(syn.surface[reg.params["rest_frame_index"]]).query(reg.rest_points)[1]
            corr = 100 * float(np.linalg.norm(reg.points - syn.surface[:, nn], axis=2).mean())
            r, st = score_step2(reg.rest_points, reg.points, syn, cfg.structure)
            n_gt = syn.gt_joints.shape[1]
            rows[json.dumps(v)].append((r.recall, r.precision, 100 * r.normalized_error,
                                        len(st.bone_parent) / n_gt, corr, ms))
            out.append(f"{r.recall:.2f}/{r.precision:.2f}/{100 * r.normalized_error:.2f}/"
                       f"{len(st.bone_parent)} corr {corr:.1f}")
        print(f"{Path(fig).stem[:14]:<14} gt {syn.gt_joints.shape[1]:2d}  " + " | ".join(out),
              flush=True)
    print(f"\n{'variant':<50} {'recall':>6} {'prec':>5} {'norm cm':>7} {'bones/gt':>8} "
          f"{'corr cm':>7} {'ms/frame':>8}")
    for k, v in rows.items():
        a = np.array(v)
        print(f"{k:<50} {a[:, 0].mean():6.3f} {a[:, 1].mean():5.3f} {np.nanmean(a[:, 2]):7.2f} "
              f"{a[:, 3].mean():8.2f} {a[:, 4].mean():7.2f} {np.median(a[:, 5]):8.0f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
