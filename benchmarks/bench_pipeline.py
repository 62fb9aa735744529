"""End-to-end accuracy and run time on the synthetic suite, with the paper's ablations.

For each figure, a depth-camera sequence is synthesised (moderate Kinect noise, 2% outliers),
the pipeline runs once for registration (reused by every variant), and step 2 / step 3
variants are scored against the ground-truth joints with ``pointrig.evaluate``:

- ``step2``      joints after the skeletal structure step only;
- ``step3``      the full pipeline (pointrig defaults);
- ``no_track``   the default step 3 started from step 2's bone motions (``init="structure"``)
  instead of step 2's skeleton tracked through the raw frames;
- ``prev``       the previous step-3 default (Eq. 22 in the loop, zeta = 1e4, weak prior);
- ``fit_w``      the default with Eq. 22 weight updates inside the EM loop;
- ``paper``      step 3 as Algorithm 2 with Table 1 values (no pointrig deviations);
- ``no_reg``     the paper's step 3 without E_Register (zeta = 0);
- ``no_alpha``   the paper's step 3 without the alpha growth (alpha_growth = 1).

Prints a table; ``--json FILE`` also writes the rows. Run:
``python benchmarks/bench_pipeline.py --frames 100``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time

import numpy as np

from pointrig.config import PipelineConfig
from pointrig.evaluate import evaluate
from pointrig.pipeline import build_skeleton, extract
from pointrig.synth import NoiseConfig, synthesize

SUITE = ["human", "upper_body", "arm", "hand", "quadruped", "snake"]


def variants(cfg: PipelineConfig) -> dict[str, PipelineConfig]:
    """Step-3 variants: pointrig's default, the previous default, the paper's Algorithm 2, and
    the paper's ablations (all paper variants with Table 1 values spelled out)."""
    j = cfg.joints
    paper = dataclasses.replace(j, mode="paper", gmm_density_normalize=False,
                                weight_candidates="all", prior_from_weights=False,
                                joint_tolerance=0.0, update_weights=True, zeta_scale=1.0,
                                tau_init_relative=False, init="structure", bone_twist="fit")
    prev = dataclasses.replace(j, update_weights=True, zeta_scale=1.0, joint_prior=0.01,
                               tau_init_relative=False, init="structure")
    return {
        "step3": cfg,
        "no_track": dataclasses.replace(cfg, joints=dataclasses.replace(j, init="structure")),
        "prev": dataclasses.replace(cfg, joints=prev),
        "fit_w": dataclasses.replace(cfg, joints=dataclasses.replace(j, update_weights=True)),
        "paper": dataclasses.replace(cfg, joints=paper),
        "no_reg": dataclasses.replace(cfg, joints=dataclasses.replace(paper, zeta=0.0)),
        "no_alpha": dataclasses.replace(cfg, joints=dataclasses.replace(paper, alpha_growth=1.0)),
    }


def score(pred: np.ndarray, synth) -> dict:
    rep = evaluate(pred, synth.gt_joints, synth.joint_parents, **synth.eval_kwargs())
    return {"recall": rep.recall, "precision": rep.precision, "raw_cm": 100 * rep.raw_error,
            "norm_cm": 100 * rep.normalized_error, "pred": int(pred.shape[1])}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--figures", nargs="*", default=SUITE)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-ablations", action="store_true")
    ap.add_argument("--json", default=None)
    ap.add_argument("--cache", default=None,
                    help="folder for per-figure registration checkpoints (reused if present)")
    args = ap.parse_args(argv)

    rows = []
    cfg = PipelineConfig()
    for fig in args.figures:
        syn = synthesize(fig, n_frames=args.frames, seed=args.seed,
                         noise=NoiseConfig(seed=args.seed))
        seq = syn.to_point_sequence()
        t0 = time.perf_counter()
        out = None if args.cache is None else f"{args.cache}/{fig}-{args.frames}-{args.seed}"
        res = extract(seq, cfg, out, stop_after="structure", pictures=False)
        st = res.structure
        t_struct = time.perf_counter() - t0
        sk2 = build_skeleton(res.registration.rest_points, st.bone_parent, st.joints_rest,
                             st.R, st.T, None, st.labels)
        rows.append({"figure": fig, "variant": "step2", "seconds": t_struct, "step3_s": 0.0,
                     **score(sk2.joint_positions, syn)})
        todo = variants(cfg) if not args.no_ablations else {"step3": cfg}
        for name, vcfg in todo.items():
            from pointrig.joints import learn_joints

            t1 = time.perf_counter()
            jr = learn_joints(seq.frames, res.registration.rest_points, res.registration.points,
                              st, vcfg.joints)
            t_j = time.perf_counter() - t1
            sk = build_skeleton(res.registration.rest_points, st.bone_parent, jr.joints_rest,
                                jr.R, jr.T, jr.weights, None)
            rows.append({"figure": fig, "variant": name, "seconds": t_struct + t_j, "step3_s": t_j,
                         **score(sk.joint_positions, syn)})
        for r in rows[-(len(todo) + 1):]:
            print(f"{r['figure']:<11} {r['variant']:<9} recall {r['recall']:.2f} "
                  f"prec {r['precision']:.2f} raw {r['raw_cm']:5.2f} cm "
                  f"norm {r['norm_cm']:5.2f} cm  joints {r['pred']:2d}  step3 {r['step3_s']:5.1f} s",
                  file=sys.stderr, flush=True)

    print(f"\n{'figure':<11} {'variant':<9} {'recall':>6} {'prec':>5} {'raw cm':>7} "
          f"{'norm cm':>8} {'joints':>6} {'step3 s':>7}")
    for r in rows:
        print(f"{r['figure']:<11} {r['variant']:<9} {r['recall']:6.2f} {r['precision']:5.2f} "
              f"{r['raw_cm']:7.2f} {r['norm_cm']:8.2f} {r['pred']:6d} {r['step3_s']:7.1f}")
    for v in sorted({r["variant"] for r in rows}):
        sel = [r for r in rows if r["variant"] == v]
        # figures where nothing matched have nan errors: mean over the others
        print(f"{'mean':<11} {v:<9} {np.mean([r['recall'] for r in sel]):6.2f} "
              f"{np.mean([r['precision'] for r in sel]):5.2f} "
              f"{np.nanmean([r['raw_cm'] for r in sel]):7.2f} "
              f"{np.nanmean([r['norm_cm'] for r in sel]):8.2f} {'':6} "
              f"{np.mean([r['step3_s'] for r in sel]):7.1f}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
