"""Step 3 alone on cached inputs: variants of ``[joints]`` without rerunning steps 1-2.

The default pipeline runs once per sequence of :data:`bench_refine.SEQUENCES` and its inputs
to the final step 3 (the cleaned frames, the refined registration's rest and registered points,
the final step-2 structure, the rest frame) are pickled to ``--cache DIR``; later runs load
them. Each variant (a JSON object of :class:`pointrig.config.JointsConfig` overrides, ``{}`` =
the defaults) then runs :func:`pointrig.joints.learn_joints` alone, 10-20 s a sequence instead
of 50-120 s for the whole pipeline, followed by the pipeline's own output stage
(:func:`pointrig.pipeline.output_skeleton`: output tree, joint-depth pass, bone rolls; before
session 52 the joint-depth pass was missing here). The skeleton (bones, tree) is the same for
every variant, so recall and precision change only through the matching. The default variant
reproduces the pipeline's cached output; the largest joint difference is printed as a check.

Prints per sequence and variant recall / precision, raw / normalised error (cm) and the *depth
bias*: the matched joints' mean signed offset from the truth along the camera ray (cm,
negative = in front of the truth, towards the camera) and the *lateral recall* (the recall with
the offsets along the ray left out, :func:`lateral_recall`), then the means per variant
(errors over the sequences where every variant matches a joint)::

    PYTHONPATH=python python benchmarks/bench_step3.py --cache /tmp/step3 '{}' \\
        '{"joint_prior": 0.3}'
    PYTHONPATH=python python benchmarks/bench_step3.py --cache /tmp/step3 --only human,girl_run
    PYTHONPATH=python python benchmarks/bench_step3.py --cache /tmp/step3 --set validation
    PYTHONPATH=python python benchmarks/bench_step3.py --cache /tmp/step3 --only girl_run --joints
    PYTHONPATH=python python benchmarks/bench_step3.py --cache /tmp/step3 '{}' \\
        '{"structure": {"leaf_split_angle_deg": 0}}'

``--joints`` adds each matched joint's normalised error over tenths of the frames
(:func:`error_over_time`, the first variant).

A variant's ``"structure"`` key overrides ``[structure]``; with the cached step 2 fixed, only
the output stage reads it (the output tree, the leaf split of session 57).

A cache is valid for the code and defaults that wrote it; delete it after changing steps 1-2.
The whole-pipeline effect of a change is measured by ``bench_suite.py`` (step 3 runs twice
there, and the refinement between the runs starts from the first one).
"""

from __future__ import annotations

import argparse
import json
import pickle
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "python"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_refine import add_cache_options, chosen, suite  # noqa: E402
from bench_registration_downstream import score_joints  # noqa: E402

from pointrig.config import (  # noqa: E402
    JointsConfig,
    PipelineConfig,
    StructureConfig,
    apply_overrides,
)
from pointrig.evaluate import match_pairs, normalized_offsets  # noqa: E402
from pointrig.joints import learn_joints  # noqa: E402
from pointrig.pipeline import extract, output_skeleton, retrack_structure  # noqa: E402
from pointrig.skeleton import Skeleton  # noqa: E402


def cached_inputs(name: str, syn: Any, cache: Path) -> dict[str, Any]:
    """The default pipeline's inputs to its final step 3 for ``syn``, from ``cache`` or computed
    (and written there): ``frames`` (``F`` clouds ``(N_t, 3)``, m), ``rest`` ``(M, 3)``,
    ``regpts`` ``(F, M, 3)``, ``structure``, ``rest_index``, ``default_P`` ``(F, J, 3)``."""
    path = cache / f"{name}.pkl"
    if path.exists():
        with open(path, "rb") as f:
            return pickle.load(f)
    cfg = PipelineConfig()
    seq = syn.to_point_sequence()
    out = extract(seq, cfg, None, pictures=False)
    reg = out.refined_registration or out.registration
    data = dict(frames=out.frames, rest=reg.rest_points, regpts=reg.points,
                structure=out.structure, rest_index=out.registration.params.get(
                    "rest_frame_index"), default_P=out.skeleton.joint_positions)
    cache.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    with open(tmp, "wb") as f:
        pickle.dump(data, f)
    tmp.replace(path)
    return data


def step3_skeleton(d: dict[str, Any], structure: Any, joints_cfg: JointsConfig,
                   structure_cfg: StructureConfig) -> tuple[Skeleton, float]:
    """Step 3 on the cached inputs ``d`` (:func:`cached_inputs`) with ``structure`` (twice with
    ``[joints] retrack``, :func:`pointrig.pipeline.retrack_structure`), and the skeleton as the
    pipeline outputs it (:func:`pointrig.pipeline.output_skeleton`: the output
    tree, the joint-depth pass on the cached frames and registration, the bones' rolls);
    returns it and step 3's seconds."""
    t0 = time.perf_counter()
    jr = learn_joints(d["frames"], d["rest"], d["regpts"], structure, joints_cfg,
                      rest_index=d["rest_index"])
    cfg = PipelineConfig(structure=structure_cfg, joints=joints_cfg)
    pivots = retrack_structure(structure, jr, d["frames"], d["regpts"], cfg)
    if pivots is not None:  # the pipeline's second final step 3 ([joints] retrack)
        jr = learn_joints(d["frames"], d["rest"], d["regpts"], pivots, joints_cfg,
                          rest_index=d["rest_index"])
    secs = time.perf_counter() - t0
    labels = np.argmax(jr.weights, 1)
    return output_skeleton(d["rest"], labels, structure.bone_parent, jr.joints_rest, jr.R,
                           jr.T, jr.weights, cfg, structure.view_camera,
                           observed=(d["frames"], d["regpts"])), secs


def summary(rows: dict[Any, list[tuple[float, ...]]], what: str
            ) -> tuple[dict[Any, np.ndarray], np.ndarray]:
    """Print the header of the means and return ``rows`` (per key, one tuple per sequence:
    recall, precision, raw cm, normalised cm, ...) as arrays with the mask of the sequences
    where every ``what`` matched a joint (finite normalised error)."""
    arr = {k: np.array(v) for k, v in rows.items()}
    ok = np.all([np.isfinite(v[:, 3]) for v in arr.values()], axis=0)
    print(f"\nmeans over {len(ok)} sequences (errors over the {int(ok.sum())} where every "
          f"{what} matches a joint):")
    return arr, ok


def pipeline_gap(joint_positions: np.ndarray, pipeline_positions: np.ndarray) -> float:
    """Largest distance (metres) between the joints ``(F, J, 3)`` of a rerun and those the
    whole pipeline wrote (``default_P`` of the cache); ``inf`` if the skeletons differ in
    shape. A default-config rerun of step 3 on the cached inputs reproduces the pipeline's
    output, so anything above rounding means the cache is stale or the output stage differs."""
    if joint_positions.shape != pipeline_positions.shape:
        return float("inf")
    return float(np.linalg.norm(joint_positions - pipeline_positions, axis=-1).max())


def depth_bias(joint_positions: np.ndarray, syn: Any, report: Any) -> float:
    """Mean over matched joints and frames of ``(p - g) . u`` (metres), ``u`` the unit ray from
    the camera (the origin of the synthetic frames) to the true joint ``g``; nan if none."""
    vals = []
    for i, row in enumerate(report.rows):
        if row.matched < 0:
            continue
        g = syn.gt_joints[:, i]
        u = g / np.linalg.norm(g, axis=1, keepdims=True)
        vals.append(float(np.einsum("fi,fi->f", joint_positions[:, row.matched] - g, u).mean()))
    return float(np.mean(vals)) if vals else float("nan")


def lateral_recall(joint_positions: np.ndarray, syn: Any, report: Any) -> float:
    """Recall with the depth along the camera ray left out: the evaluation's matching (one
    prediction per scorable true joint, ``report.threshold``, the optimal assignment) on the
    mean over frames of ``|(p - g) - ((p - g) . u) u|`` (metres), ``u`` the unit ray from the
    camera (the origin of the synthetic frames) to the true joint ``g``. The gap to the recall
    is what a perfect depth placement of the same joints would gain (session 53: the glTF
    rigs' largest loss); nan without scorable joints."""
    cols = np.flatnonzero(report.scorable)
    if not len(cols):
        return float("nan")
    cost = lateral_costs(joint_positions, syn.gt_joints[:, cols])
    return len(match_pairs(cost, report.threshold)) / len(cols)


def lateral_costs(joint_positions: np.ndarray, gt_joints: np.ndarray) -> np.ndarray:
    """``(P, J)`` mean over frames of ``|(p - g) - ((p - g) . u) u|`` (metres) for every pair
    of output joint ``p`` (``joint_positions`` ``(F, P, 3)``) and true joint ``g``
    (``gt_joints`` ``(F, J, 3)``), ``u`` the unit ray from the camera (the origin) to ``g``:
    the distance with the offset along the ray left out."""
    u = gt_joints / np.linalg.norm(gt_joints, axis=2, keepdims=True)
    diff = joint_positions[:, :, None] - gt_joints[:, None]  # (F, P, J, 3)
    along = np.einsum("fpjk,fjk->fpj", diff, u)
    return np.linalg.norm(diff - along[..., None] * u[:, None], axis=3).mean(axis=0)


def error_over_time(joint_positions: np.ndarray, syn: Any, report: Any, bins: int = 10
                    ) -> dict[str, np.ndarray]:
    """Each matched scorable joint's normalised error over ``bins`` consecutive stretches of
    the frames: ``{true joint name: (bins,) metres}``: the evaluation's per-frame offsets
    (:func:`pointrig.evaluate.normalized_offsets`, the pair's mean offset taken out) averaged
    within each stretch (``numpy.array_split`` of the frames). With ``F`` divisible by ``bins``, the mean
    of the stretches is the joint's normalised error. A loss that grows away from the rest
    frame and one that comes back with every stride (docs/joints.md "Session 60") look the
    same in the total and differ here."""
    out: dict[str, np.ndarray] = {}
    for i, row in enumerate(report.rows):
        if not row.scorable or row.matched < 0:
            continue
        n = normalized_offsets(joint_positions[:, row.matched], syn.gt_joints[:, i])
        out[row.name] = np.array([c.mean() for c in np.array_split(n, bins)])
    return out


#: Subject sizes (metres, the evaluation's bounding-box diagonal of the true surface) of the
#: "human-sized figures" the issue's targets are set on. Inside: the procedural human (2.39 m),
#: upper body (1.64), quadruped (1.40) and snake (1.47), the girl (1.74 running) and
#: rigged_figure (1.74); outside: the hand (0.24 m) and greenman (3.72 m, a giant).
HUMAN_SIZED = (1.0, 3.0)


def human_sized(size: float) -> bool:
    """Whether a subject of ``size`` metres (:func:`pointrig.evaluate.subject_size`) is one of
    the human-sized figures of the issue's targets (:data:`HUMAN_SIZED`, bounds included)."""
    return bool(HUMAN_SIZED[0] <= size <= HUMAN_SIZED[1])


def variant_configs(variants: list[dict[str, Any]]
                    ) -> tuple[list[JointsConfig], list[StructureConfig]]:
    """Each variant's ``[joints]`` and ``[structure]`` parameters: its keys override
    ``[joints]``, except ``"structure"``, whose object overrides ``[structure]``. With the
    cached step 2 fixed, only the output stage reads ``[structure]`` here (the output tree, the
    leaf split of session 57)."""
    joints = [apply_overrides({"joints": {k: x for k, x in v.items() if k != "structure"}}).joints
              for v in variants]
    structure = [apply_overrides({"structure": v.get("structure", {})}).structure
                 for v in variants]
    return joints, structure


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_cache_options(ap)
    ap.add_argument("--joints", action="store_true",
                    help="also print each matched joint's normalised error over tenths of the "
                         "frames (the first variant)")
    ap.add_argument("variants", nargs="*", help="JSON [joints] overrides per variant")
    a = ap.parse_args(argv)
    sequences, only = chosen(ap, a)
    variants = [json.loads(v) for v in a.variants] or [{}]
    cfgs, structure_cfgs = variant_configs(variants)
    rows: dict[int, list[tuple[float, ...]]] = {k: [] for k in range(len(variants))}
    print(f"{'sequence':<24} " + " | ".join(
        f"variant {k}: rec/prec raw norm depth lateral-rec (s)" for k in range(len(variants))))
    gap: list[float] = []
    for name, syn in suite(a.frames, only, sequences):
        d = cached_inputs(name, syn, Path(a.cache))
        st = d["structure"]
        cells = []
        per_joint: dict[str, np.ndarray] = {}
        for k, cfg in enumerate(cfgs):
            sk, secs = step3_skeleton(d, st, cfg, structure_cfgs[k])
            r = score_joints(sk.joint_positions, syn)
            db = depth_bias(sk.joint_positions, syn, r)
            lr = lateral_recall(sk.joint_positions, syn, r)
            rows[k].append((r.recall, r.precision, 100 * r.raw_error, 100 * r.normalized_error,
                            100 * db, lr, r.subject_size))
            cells.append(f"{r.recall:.2f}/{r.precision:.2f} {100 * r.raw_error:5.2f} "
                         f"{100 * r.normalized_error:5.2f} {100 * db:+5.2f} {lr:.2f} "
                         f"({secs:3.0f})")
            if cfg == JointsConfig() and structure_cfgs[k] == StructureConfig():
                gap.append(pipeline_gap(sk.joint_positions, d["default_P"]))
            if a.joints and k == 0:
                per_joint = error_over_time(sk.joint_positions, syn, r)
        print(f"{name:<24} " + " | ".join(cells), flush=True)
        if a.joints:
            print(f"  (rest frame {d['rest_index']}; normalised cm: mean of the tenths | "
                  "each tenth)")
            for jn, v in per_joint.items():
                print(f"  {jn:<20} {100 * v.mean():5.1f} | "
                      + " ".join(f"{100 * x:4.1f}" for x in v))
    if not rows[0]:
        return 0
    if gap:
        print(f"\nthe default variant against the pipeline's cached output: largest joint "
              f"difference {1000 * max(gap):.3f} mm over {len(gap)} sequences")
    arr, ok = summary(rows, "variant")
    for k, v in arr.items():
        print(f"variant {k}: recall {v[:, 0].mean():.3f} precision {v[:, 1].mean():.3f} "
              f"raw {v[ok, 2].mean():.2f} cm normalised {v[ok, 3].mean():.2f} cm depth bias "
              f"{np.nanmean(v[:, 4]):+.2f} cm lateral recall {np.nanmean(v[:, 5]):.3f}  "
              f"{json.dumps(variants[k])}")
    hs = np.array([human_sized(x) for x in arr[0][:, 6]])
    if hs.any():
        print(f"\nhuman-sized figures (subject size {HUMAN_SIZED[0]}-{HUMAN_SIZED[1]} m, the "
              f"targets' figures): {int(hs.sum())} of {len(hs)} sequences")
        for k, v in arr.items():
            print(f"variant {k}: recall {v[hs, 0].mean():.3f} precision {v[hs, 1].mean():.3f} "
                  f"raw {v[hs & ok, 2].mean():.2f} cm normalised {v[hs & ok, 3].mean():.2f} cm")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
