"""Step 2 on exact and on registered motion of the same sequences (where step 2 loses joints).

For each sequence of ``bench_registration_downstream.py`` (the ``pointrig.synth`` figures and,
when present, the glTF rigs of ``../shared/data/models``; 40 frames, seed 0, moderate Kinect
noise, 2 % outliers) step 2 runs on two inputs (three with ``--visible``):

* **exact**: 2000 ground-truth surface samples (both sides, no noise) and their exact motion,
  i.e. what step 2 does with a perfect step 1 (``single_view="no"``: no depth correction);
* **reg**: the default step-1 registration of the depth frames (cached in ``--cache``);
* **visible** (with ``--visible``): the exact surface samples nearest the registration's rest
  points in the rest frame (the side one depth camera saw, no noise) with their exact motion,
  i.e. what step 2 does with a perfect step 1 on the points it really gets (single-view depth
  correction on).

Prints recall / precision / bone count per sequence and mode, then the means (recall,
precision, normalised error in cm, bones per scorable ground-truth joint) per variant. With
``--joints`` step 3 (default :class:`~pointrig.config.JointsConfig`) also runs on each
registered step-2 result (mode **reg+3**: the single pass, ``refine_rounds = 0``; joints
only, the bone count is step 2's); with ``--joints --refine`` also one round of the refinement
from the skeleton (mode **ref+3**: every frame registered again from step 3's tracked pose,
then steps 2-3 again, as ``extract`` does by default, ``RegistrationConfig.refine_rounds =
1``; its bone count, and the refined correspondence error on the sequence's line).
Variants are JSON overrides of :class:`~pointrig.config.StructureConfig`::

    PYTHONPATH=python python benchmarks/bench_structure_real.py --cache /tmp/reg40 \
        '{}' '{"band_ratio": 0.5}'

``--wide`` adds 16 sequences (:data:`WIDE`: other seeds, glTF clips, start times, yaw, a walk).
``--only human,girl_run_s05`` runs only the named sequences (add ``--wide`` for the WIDE ones).
``--swing-source surface`` scores with the articulation test before session 21 (Kabsch fits
of the surface parts instead of the rig's bone transforms).
``--registration JSON`` registers with :class:`~pointrig.config.RegistrationConfig` overrides
(a cache holds one registration variant, so give each its own ``--cache``); each sequence's
line ends with the mean correspondence error of the registration (cm, against the exact
surface), and the mean over sequences is printed before the table::

    PYTHONPATH=python python benchmarks/bench_structure_real.py --cache /tmp/reg40_nocheck \
        --wide --joints --registration '{"predict_check": 0}'
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import pickle
import sys
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "python"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_registration_downstream import FIGURES, score_joints, score_step2  # noqa: E402

from pointrig.config import PipelineConfig, StructureConfig  # noqa: E402
from pointrig.evaluate import SWING_SOURCES  # noqa: E402
from pointrig.joints import learn_joints, posed_rest_points  # noqa: E402
from pointrig.pipeline import build_skeleton  # noqa: E402
from pointrig.registration import (  # noqa: E402
    RegistrationResult,
    refine_registration,
    register_sequence,
)
from pointrig.structure import extract_structure  # noqa: E402
from pointrig.synth import NoiseConfig, synthesize  # noqa: E402


_MODELS = Path(__file__).resolve().parents[2] / "shared" / "data" / "models"
#: ``--wide``: 16 more sequences (other seeds, clips, start times, yaw, a walk), so that a
#: variant is judged on 25 sequences rather than 9 (one joint of the 3-joint arm moves the
#: 9-sequence mean recall by 0.037). Name -> (figure or glb, synthesize() keywords).
WIDE: dict[str, tuple[str, dict]] = {
    "girl_run_yaw40": (str(_MODELS / "girl.glb"), {"seed": 1, "clip": "RunTrack", "yaw": 40}),
    "girl_run_s05": (str(_MODELS / "girl.glb"),
                     {"seed": 2, "clip": "RunTrack", "start": 0.4, "yaw": -30}),
    "girl_idle": (str(_MODELS / "girl.glb"), {"seed": 3, "clip": "IdleTrack", "speed": 2.0}),
    "greenman_attack": (str(_MODELS / "greenman.glb"), {"seed": 1, "clip": "3_attack"}),
    "greenman_move": (str(_MODELS / "greenman.glb"), {"seed": 2, "clip": "2_move", "yaw": 30}),
    "rigged_yaw30": (str(_MODELS / "rigged_figure.glb"), {"seed": 1, "yaw": 30}),
    "rigged_start": (str(_MODELS / "rigged_figure.glb"), {"seed": 2, "start": 0.5, "yaw": -40}),
    "human_s1": ("human", {"seed": 1}),
    "human_s2_yaw": ("human", {"seed": 2, "yaw": 40}),
    "human_walk": ("human", {"seed": 3, "walk": 1.5}),
    "upper_s1": ("upper_body", {"seed": 1}),
    "arm_s1": ("arm", {"seed": 1}),
    "hand_s1": ("hand", {"seed": 1}),
    "quad_s1": ("quadruped", {"seed": 1}),
    "quad_s2_yaw": ("quadruped", {"seed": 2, "yaw": -35}),
    "snake_s1": ("snake", {"seed": 1}),
}


#: RegistrationConfig fields added after caches were written, with the value each had in
#: effect before it existed (session 23: normal agreement off).
_ADDED_LATER = {"normal_kappa": 0.0, "normal_radius": 1.5}


def _step1_params(params: dict) -> dict:
    """The parameters that change step 1's result (``refine_rounds`` acts after step 3)."""
    return {k: v for k, v in params.items() if k != "refine_rounds"}


def _load(fig: str, frames: int, cache: Path | None, registration: dict) -> dict:
    if fig in WIDE:
        src, kw = WIDE[fig]
        name = f"{fig}-{frames}.pkl"
    else:
        src, kw = fig, {"seed": 0}
        name = f"{Path(fig).stem[:14]}-{frames}-0.pkl"
    config = dataclasses.replace(PipelineConfig().registration, **registration)
    if cache is not None and (cache / name).exists():
        with open(cache / name, "rb") as fh:
            d = pickle.load(fh)
        if "registration" not in d:
            print(f"note: {cache / name} predates session 19 and does not record its "
                  "registration parameters", file=sys.stderr)
        # a field added after the cache was written holds the value that reproduces the
        # behaviour before it existed
        elif _step1_params({**_ADDED_LATER, **d["registration"]}) != \
                _step1_params(dataclasses.asdict(config)):
            raise SystemExit(f"{cache / name} was registered with other parameters than "
                             f"the defaults + {registration}: use another --cache")
        return d
    if fig in WIDE and not Path(src).exists() and src.endswith(".glb"):
        return {}
    syn = synthesize(src, n_frames=frames, noise=NoiseConfig(seed=kw["seed"]), **kw)
    reg = register_sequence(syn.to_point_sequence(), config)
    d = {"syn": syn, "rest": reg.rest_points, "pts": reg.points,
         "registration": dataclasses.asdict(config), "rest_frame": reg.params["rest_frame_index"]}
    if cache is not None:
        cache.mkdir(parents=True, exist_ok=True)
        with open(cache / name, "wb") as fh:
            pickle.dump(d, fh)
    return d


def _refined_run(seq, q, y, rf, st, jr, cfg, joints_cfg, reg_over, syn, swing_source, truth):
    """One round of the refinement from the skeleton (as ``pointrig.pipeline.extract`` with
    ``refine_rounds = 1``): every frame registered again from step 3's tracked pose, then
    steps 2 and 3 again. Returns (score, bones, correspondence error cm)."""
    reg_cfg = dataclasses.replace(PipelineConfig().registration, **reg_over)
    reg = RegistrationResult(q, y, np.zeros(len(y)), np.zeros(len(y), dtype=np.int64),
                             np.zeros(len(y)), {"rest_frame_index": int(rf)})
    posed = posed_rest_points(q, st.labels, jr.R, jr.T)
    y2 = refine_registration(seq, reg, posed, reg_cfg).points
    st2 = extract_structure(q, y2, cfg)
    jr2 = learn_joints(seq.frames, q, y2, st2, joints_cfg)
    sk = build_skeleton(q, st2.bone_parent, jr2.joints_rest, jr2.R, jr2.T, jr2.weights, None)
    corr = 100 * float(np.linalg.norm(y2 - truth, axis=2).mean())
    return score_joints(sk.joint_positions, syn, swing_source), st2.n_bones, corr


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("variants", nargs="*", default=["{}"], help="StructureConfig overrides (JSON)")
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--cache", type=Path, default=None, help="directory for registrations")
    ap.add_argument("--joints", action="store_true", help="also run step 3 on the registered "
                    "sequences (mode reg+3)")
    ap.add_argument("--wide", action="store_true", help="also the 16 sequences of WIDE")
    ap.add_argument("--registration", default="{}", help="RegistrationConfig overrides (JSON) "
                    "for the registered mode; a cache holds one registration variant")
    ap.add_argument("--joints-config", default="{}", help="JointsConfig overrides (JSON) for "
                    "step 3 (with --joints)")
    ap.add_argument("--visible", action="store_true", help="also step 2 on the exact motion "
                    "of the registration's single-view rest points (mode visible)")
    ap.add_argument("--refine", action="store_true", help="with --joints: also the "
                    "refinement from the skeleton (RegistrationConfig.refine_rounds = 1: every "
                    "frame registered again from step 3's tracked pose, then steps 2-3 again; "
                    "mode ref+3, and its correspondence error)")
    ap.add_argument("--only", default="", help="comma-separated sequence names (e.g. "
                    "human,girl_run_s05): run only these, for a quick look; means over a "
                    "subset are not comparable with the 25-sequence table")
    ap.add_argument("--swing-source", default="auto", choices=SWING_SOURCES,
                    help="the scorer's articulation test: the rig's bone transforms (auto) "
                    "or Kabsch fits of the surface parts (the rule before session 21)")
    a = ap.parse_args(argv)
    reg_over = json.loads(a.registration)
    joints_cfg = dataclasses.replace(PipelineConfig().joints, **json.loads(a.joints_config))
    variants = [json.loads(v) for v in a.variants]
    rows: dict[tuple[str, str], list[tuple[float, ...]]] = {}
    corr: list[float] = []
    only = {n for n in a.only.split(",") if n}
    names = [Path(f).stem for f in FIGURES + list(WIDE)]
    if only - set(names):
        ap.error(f"--only: unknown sequence(s) {', '.join(sorted(only - set(names)))}; "
                 f"known: {', '.join(names)}")
    for fig in FIGURES + (list(WIDE) if a.wide else []):
        if only and Path(fig).stem not in only:
            continue
        d = _load(fig, a.frames, a.cache, reg_over)
        if not d:
            continue
        syn = d["syn"]
        s = syn.surface
        # correspondence error: each rest point against its nearest exact sample of the rest
        # frame, followed through every frame (caches before session 19 lack "rest_frame")
        rf = d.get("rest_frame", s.shape[0] // 2)
        nn = cKDTree(s[rf]).query(d["rest"])[1]
        corr.append(100 * float(np.linalg.norm(d["pts"] - s[:, nn], axis=2).mean()))
        idx = np.random.default_rng(0).choice(s.shape[1], min(2000, s.shape[1]), replace=False)
        inputs = {"exact": (s[0, idx], s[:, idx]), "reg": (d["rest"], d["pts"])}
        if a.visible:
            inputs["visible"] = (s[rf, nn], s[:, nn])
        seq = syn.to_point_sequence() if a.joints else None
        frames = seq.frames if seq is not None else None
        line = []
        for v in variants:
            for mode, (q, y) in inputs.items():
                # the exact samples cover both sides of the surface: not one depth view
                cfg = dataclasses.replace(StructureConfig(), **{
                    **({"single_view": "no"} if mode == "exact" else {}), **v})
                r, st = score_step2(q, np.ascontiguousarray(y), syn, cfg, a.swing_source)
                rows.setdefault((json.dumps(v), mode), []).append(
                    (r.recall, r.precision, 100 * r.normalized_error,
                     st.n_bones / max(r.n_scorable, 1), 100 * r.raw_error))
                line.append(f"{mode} {r.recall:.2f}/{r.precision:.2f}/{st.n_bones}")
                if a.joints and mode == "reg":
                    jr = learn_joints(frames, q, y, st, joints_cfg)
                    sk = build_skeleton(q, st.bone_parent, jr.joints_rest, jr.R, jr.T,
                                        jr.weights, None)
                    r3 = score_joints(sk.joint_positions, syn, a.swing_source)
                    rows.setdefault((json.dumps(v), "reg+3"), []).append(
                        (r3.recall, r3.precision, 100 * r3.normalized_error,
                         st.n_bones / max(r3.n_scorable, 1), 100 * r3.raw_error))
                    line.append(f"reg+3 {r3.recall:.2f}/{r3.precision:.2f}")
                    if a.refine:
                        r4, n4, c4 = _refined_run(seq, q, y, rf, st, jr, cfg, joints_cfg,
                                                  reg_over, syn, a.swing_source, s[:, nn])
                        rows.setdefault((json.dumps(v), "ref+3"), []).append(
                            (r4.recall, r4.precision, 100 * r4.normalized_error,
                             n4 / max(r4.n_scorable, 1), 100 * r4.raw_error))
                        line.append(f"ref+3 {r4.recall:.2f}/{r4.precision:.2f}/{n4} "
                                    f"(corr {c4:.2f} cm)")
        print(f"{Path(fig).stem[:15]:<15} scorable {r.n_scorable:2d}  " + " | ".join(line)
              + f" | corr {corr[-1]:.2f} cm", flush=True)
    print(f"\nregistration {json.dumps(reg_over)}: mean correspondence error "
          f"{np.mean(corr):.3f} cm over {len(corr)} sequences")
    print(f"\n{'variant':<44} {'mode':<7} {'recall':>6} {'prec':>5} {'norm cm':>7} "
          f"{'raw cm':>6} {'bones/scorable':>14}")
    for (v, mode), vals in rows.items():
        m = np.array(vals)
        print(f"{v:<44} {mode:<7} {m[:, 0].mean():6.3f} {m[:, 1].mean():5.3f} "
              f"{np.nanmean(m[:, 2]):7.2f} {np.nanmean(m[:, 4]):6.2f} {m[:, 3].mean():14.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
