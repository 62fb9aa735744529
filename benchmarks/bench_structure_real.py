"""Step 2 on exact and on registered motion of the same sequences (where step 2 loses joints).

For each sequence of ``bench_registration_downstream.py`` (the ``pointrig.synth`` figures and,
when present, the glTF rigs of ``../shared/data/models``; 40 frames, seed 0, moderate Kinect
noise, 2 % outliers) step 2 runs twice:

* **exact**: 2000 ground-truth surface samples (both sides, no noise) and their exact motion,
  i.e. what step 2 does with a perfect step 1 (``single_view="no"``: no depth correction);
* **reg**: the default step-1 registration of the depth frames (cached in ``--cache``).

Prints recall / precision / bone count per sequence and mode, then the means (recall,
precision, normalised error in cm, bones per scorable ground-truth joint) per variant. With
``--joints`` step 3 (default :class:`~pointrig.config.JointsConfig`) also runs on each
registered step-2 result (mode **reg+3**, joints only: the bone count is step 2's).
Variants are JSON overrides of :class:`~pointrig.config.StructureConfig`::

    PYTHONPATH=python python benchmarks/bench_structure_real.py --cache /tmp/reg40 \
        '{}' '{"band_ratio": 0.5}'
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import pickle
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "python"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_registration_downstream import FIGURES, score_joints, score_step2  # noqa: E402

from pointrig.config import PipelineConfig, StructureConfig  # noqa: E402
from pointrig.joints import learn_joints  # noqa: E402
from pointrig.pipeline import build_skeleton  # noqa: E402
from pointrig.registration import register_sequence  # noqa: E402
from pointrig.synth import NoiseConfig, synthesize  # noqa: E402


def _load(fig: str, frames: int, cache: Path | None) -> dict:
    name = f"{Path(fig).stem[:14]}-{frames}-0.pkl"
    if cache is not None and (cache / name).exists():
        with open(cache / name, "rb") as fh:
            return pickle.load(fh)
    syn = synthesize(fig, n_frames=frames, seed=0, noise=NoiseConfig(seed=0))
    reg = register_sequence(syn.to_point_sequence(), PipelineConfig().registration)
    d = {"syn": syn, "rest": reg.rest_points, "pts": reg.points}
    if cache is not None:
        cache.mkdir(parents=True, exist_ok=True)
        with open(cache / name, "wb") as fh:
            pickle.dump(d, fh)
    return d


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("variants", nargs="*", default=["{}"], help="StructureConfig overrides (JSON)")
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--cache", type=Path, default=None, help="directory for registrations")
    ap.add_argument("--joints", action="store_true", help="also run step 3 on the registered "
                    "sequences (mode reg+3)")
    a = ap.parse_args(argv)
    variants = [json.loads(v) for v in a.variants]
    rows: dict[tuple[str, str], list[tuple[float, ...]]] = {}
    for fig in FIGURES:
        d = _load(fig, a.frames, a.cache)
        syn = d["syn"]
        s = syn.surface
        idx = np.random.default_rng(0).choice(s.shape[1], min(2000, s.shape[1]), replace=False)
        inputs = {"exact": (s[0, idx], s[:, idx]), "reg": (d["rest"], d["pts"])}
        frames = syn.to_point_sequence().frames if a.joints else None
        line = []
        for v in variants:
            for mode, (q, y) in inputs.items():
                # the exact samples cover both sides of the surface: not one depth view
                cfg = dataclasses.replace(StructureConfig(), **{
                    **({"single_view": "no"} if mode == "exact" else {}), **v})
                r, st = score_step2(q, np.ascontiguousarray(y), syn, cfg)
                rows.setdefault((json.dumps(v), mode), []).append(
                    (r.recall, r.precision, 100 * r.normalized_error,
                     st.n_bones / max(r.n_scorable, 1), 100 * r.raw_error))
                line.append(f"{mode} {r.recall:.2f}/{r.precision:.2f}/{st.n_bones}")
                if a.joints and mode == "reg":
                    jr = learn_joints(frames, q, y, st, PipelineConfig().joints)
                    sk = build_skeleton(q, st.bone_parent, jr.joints_rest, jr.R, jr.T,
                                        jr.weights, None)
                    r3 = score_joints(sk.joint_positions, syn)
                    rows.setdefault((json.dumps(v), "reg+3"), []).append(
                        (r3.recall, r3.precision, 100 * r3.normalized_error,
                         st.n_bones / max(r3.n_scorable, 1), 100 * r3.raw_error))
                    line.append(f"reg+3 {r3.recall:.2f}/{r3.precision:.2f}")
        print(f"{Path(fig).stem[:14]:<14} scorable {r.n_scorable:2d}  " + " | ".join(line),
              flush=True)
    print(f"\n{'variant':<44} {'mode':<6} {'recall':>6} {'prec':>5} {'norm cm':>7} "
          f"{'raw cm':>6} {'bones/scorable':>14}")
    for (v, mode), vals in rows.items():
        m = np.array(vals)
        print(f"{v:<44} {mode:<6} {m[:, 0].mean():6.3f} {m[:, 1].mean():5.3f} "
              f"{np.nanmean(m[:, 2]):7.2f} {np.nanmean(m[:, 4]):6.2f} {m[:, 3].mean():14.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
