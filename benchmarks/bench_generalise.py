"""Generalisation benchmark: the pipeline on the subject-split corpus (:mod:`corpus`), its tuning
set and its check set, scored per sequence, per set and per category.

Each variant is a JSON object of per-stage overrides of :class:`pointrig.config.PipelineConfig`
(``{}`` = the defaults) or the word ``paper`` (``PipelineConfig.paper()`` where it exists, else
the defaults with ``RegistrationConfig.paper()``). Per sequence and variant it prints recall /
precision, joints out / scored ground-truth joints, the normalised error (cm, Helten et al.),
the share of output joints far (at least 10 % of the subject's size) from EVERY joint of the
source rig, scored or not (:attr:`pointrig.evaluate.EvalReport.far_fraction`), and the seconds
the pipeline took (wall; the CSV also has the CPU seconds of its process, all threads); then
means per set, and per set and group (human-sized, animal, other) and
category::

    python -m benchmarks.bench_generalise                 # both sets
    python -m benchmarks.bench_generalise --set tuning '{}' \\
        '{"structure": {"max_joints": 15}}' --jobs 2 --csv runs.csv
    python -m benchmarks.bench_generalise paper --only robot_0,cmu_60

Synthesized sequences are cached in ``--cache`` (default ``~/.cache/pointrig-corpus``, outside
the tree; points rounded to float32 on the first run so every variant and re-run sees the
same points), keyed by the take, the frame count, the model file and pointrig.synth's code.
Each run's output joints are cached there too, keyed by the sequence, the variant and the
pipeline's code (pointrig's Python files and compiled core, less evaluate.py and synth/): a
re-run of an unchanged variant costs nothing (``--rerun`` runs again), and every run is scored
afresh, so a change of the scoring needs no run.

Means: recall, precision, joints out, the far share, the duplicates and near misses a sequence
(:attr:`pointrig.evaluate.EvalReport.duplicate`, ``near_miss``: extra joints at a matched
joint, joints missed whose own output joint lies within 1.5 times the threshold) and seconds
over every sequence (a run that fails counts as recall 0 and no joints); the normalised error
over the sequences where the run matched a joint.

A single run is noisy: a last-bit change upstream (another CPU's vector code, a reordered sum)
flips discrete choices (a cluster boundary, a merge) and moves a set's means by a few
hundredths. ``--seeds K`` runs every variant with ``K`` seeds (``[registration] seed`` and
``[structure] seed`` raised by ``0 .. K-1``: other rest points, other k-means starts), scores
each sequence by its mean over the seeds and prints the spread of each set's means over the
seeds. With two or more variants it prints each one's difference from variant 0 per set, with
the paired sign-flip p-value over the sequences (:func:`benchmarks.bench_suite.sign_flip_p`)::

    python -m benchmarks.bench_generalise --set check '{}' '{"joints": {"track_sweeps": 1}}' \\
        --seeds 2

``--output-stage`` studies the output stage alone (the joint selection, the output tree, the
depth pass: the parameters of :data:`OUTPUT_STAGE_FIELDS`; a variant that changes anything
else is refused). Steps 1-3 run once per sequence and seed with the defaults, their outputs
(:func:`output_stage_inputs`, about 20 MB a run) are cached in ``--cache``/stage-inputs under
the code of steps 1-3 (all but :data:`OUTPUT_STAGE_MODULES`, so a change of the output stage
reuses them), and each variant reruns the output stage only, about 2 s a run instead of
about a minute, with the joints a whole run of that variant gives (tests/test_bench_generalise.py)::

    python -m benchmarks.bench_generalise --output-stage --seeds 2 '{}' \\
        '{"structure": {"joint_penalty": 1}}'
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import hashlib
import json
import sys
import time
import traceback
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

import pointrig
from benchmarks import corpus
from benchmarks.bench_suite import sign_flip_p
from pointrig.config import PipelineConfig, RegistrationConfig, apply_overrides
from pointrig.errors import PointrigError
from pointrig.evaluate import EvalReport, evaluate, scorable_joints, subject_size
from pointrig.pipeline import ExtractResult, extract, output_skeleton
from pointrig.sequence import PointSequence

DEFAULT_CACHE = Path.home() / ".cache" / "pointrig-corpus"
#: Columns of the CSV, one row per run.
CSV_FIELDS = ("variant", "seed", "set", "sequence", "subject", "category", "group", "camera",
              "distance", "frames", "recall", "precision", "n_pred", "n_scorable", "n_matched",
              "normalized_error_cm", "raw_error_cm", "far_fraction", "n_far", "n_duplicate",
              "n_near_miss", "subject_size_m", "seconds", "cpu_seconds", "error")


def _sha1_files(paths: list[Path]) -> str:
    h = hashlib.sha1()
    for p in sorted(paths):
        h.update(p.name.encode())
        h.update(p.read_bytes())
    return h.hexdigest()


#: The modules only the output stage runs (:func:`pointrig.pipeline.output_skeleton`): the
#: cached steps 1-3 of ``--output-stage`` do not depend on them.
OUTPUT_STAGE_MODULES = ("output.py", "selection.py")


def code_fingerprint(steps_1_to_3: bool = False) -> str:
    """SHA-1 of the pipeline's code: pointrig's Python files and compiled core, less the
    scoring (evaluate.py) and the synthesis (synth/), which do not change its output (runs are
    cached under it; scores are computed afresh each time). ``steps_1_to_3``: also less
    :data:`OUTPUT_STAGE_MODULES` (the key of ``--output-stage``'s cached steps 1-3)."""
    root = Path(pointrig.__file__).resolve().parent
    skip = {"evaluate.py"} | (set(OUTPUT_STAGE_MODULES) if steps_1_to_3 else set())
    files = [p for p in root.rglob("*.py")
             if p.name not in skip and "synth" not in p.relative_to(root).parts]
    files += list(root.glob("_core*.so")) + list(root.glob("_core*.pyd"))
    return _sha1_files(files)


def synth_fingerprint() -> str:
    """SHA-1 of pointrig.synth's code (synthesized sequences are cached under it)."""
    root = Path(pointrig.__file__).resolve().parent / "synth"
    return _sha1_files(list(root.glob("*.py")))


def sequence_key(seq: corpus.Sequence, frames: int, synth_code: str) -> str:
    """The cache key of a synthesized sequence."""
    kw = corpus.synth_kwargs(seq, frames) if not seq.take.once else \
        {"take": dataclasses.asdict(seq.take), "frames": frames}
    kw = {k: (dataclasses.asdict(v) if dataclasses.is_dataclass(v) else v)
          for k, v in kw.items()}
    src = Path(seq.source)
    blob = json.dumps({"name": seq.name, "size": seq.size, "kw": kw, "code": synth_code,
                       "file": hashlib.sha1(src.read_bytes()).hexdigest() if src.exists()
                       else seq.source}, sort_keys=True, default=str)
    return f"{seq.name}-{frames}-{hashlib.sha1(blob.encode()).hexdigest()[:12]}"


def _save(path: Path, syn) -> None:
    frames = [np.asarray(f, dtype=np.float32) for f in syn.frames]
    arrays = {
        "points": np.concatenate(frames), "counts": np.array([len(f) for f in frames]),
        "gt_joints": syn.gt_joints, "parents": syn.joint_parents,
        "names": np.array(syn.joint_names, dtype=str), "skinned": syn.skinned,
        "surface": syn.surface, "surface_labels": syn.surface_labels,
        "bone_rotations": syn.bone_rotations, "bone_translations": syn.bone_translations,
        "rest_surface": syn.rest_surface,
        "intrinsics": np.array([syn.camera.fx, syn.camera.fy, syn.camera.cx, syn.camera.cy,
                                syn.camera.width, syn.camera.height]),
        "params": np.array(json.dumps(syn.params, default=str)),
    }
    tmp = path.with_suffix(".tmp.npz")
    np.savez(tmp, **arrays)
    tmp.replace(path)


def load_cached(path: Path) -> dict[str, Any]:
    """A cached sequence: ``frames`` (list of ``(N_t, 3)`` float64, from float32), the ground
    truth and ``eval`` (the keywords of :func:`pointrig.evaluate.evaluate`)."""
    with np.load(path, allow_pickle=False) as z:
        d = {k: z[k] for k in z.files}
    cuts = np.cumsum(d["counts"])[:-1]
    frames = [np.asarray(f, dtype=np.float64) for f in np.split(d["points"], cuts)]
    names = [str(n) for n in d["names"]]
    return {"frames": frames, "gt_joints": d["gt_joints"], "parents": d["parents"],
            "params": json.loads(str(d["params"])), "intrinsics": d["intrinsics"],
            "eval": {"gt_names": names, "skinned": d["skinned"], "surface": d["surface"],
                     "surface_labels": d["surface_labels"],
                     "bone_rotations": d["bone_rotations"],
                     "bone_translations": d["bone_translations"],
                     "rest_surface": d["rest_surface"]}}


def ensure_sequence(name: str, frames: int, cache: Path, synth_code: str) -> tuple[str, float]:
    """Synthesize ``name`` into the cache unless it is there; returns its path and the seconds
    spent synthesizing (0 if cached)."""
    seq = corpus.SEQUENCES[name]
    path = cache / "sequences" / f"{sequence_key(seq, frames, synth_code)}.npz"
    if path.exists():
        return str(path), 0.0
    path.parent.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    syn = corpus.synthesize_sequence(seq, frames)
    _save(path, syn)
    return str(path), time.perf_counter() - t0


def make_config(variant: str, seed: int = 0) -> PipelineConfig:
    """The :class:`PipelineConfig` of a variant (JSON overrides or ``paper``), its
    ``[registration]`` and ``[structure]`` seeds raised by ``seed``."""
    if variant.strip() == "paper":
        if hasattr(PipelineConfig, "paper"):
            cfg = PipelineConfig.paper()
        else:
            cfg = dataclasses.replace(PipelineConfig(), registration=RegistrationConfig.paper())
    else:
        data = json.loads(variant)
        if not isinstance(data, dict):
            raise TypeError("a variant is a JSON object of per-stage overrides")
        cfg = apply_overrides(data, where=f"variant {variant}")
    if seed:
        cfg = dataclasses.replace(
            cfg, registration=dataclasses.replace(cfg.registration,
                                                  seed=cfg.registration.seed + seed),
            structure=dataclasses.replace(cfg.structure, seed=cfg.structure.seed + seed))
    return cfg


def _sequence(name: str, data: dict[str, Any]) -> PointSequence:
    """A cached sequence's frames as the in-memory :class:`PointSequence` the runs read."""
    return PointSequence(data["frames"], f"corpus:{name}",
                         [f"frame_{t:04d}" for t in range(len(data["frames"]))], "memory")


def _save_npz(path: Path, arrays: dict[str, Any]) -> None:
    """``arrays`` to ``path`` through a temporary file (no half-written file is left)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npz")
    np.savez(tmp, **arrays)
    tmp.replace(path)


def run_pipeline(name: str, seq_path: str, variant: str, out_path: str, seed: int = 0
                 ) -> dict[str, Any]:
    """Run the pipeline on one cached sequence (with the variant's seeds raised by ``seed``,
    :func:`make_config`) and save its joints ``(F, P, 3)`` (or its error) with the seconds it
    took to ``out_path`` (an ``.npz``); returns what was saved."""
    data = load_cached(Path(seq_path))
    cfg = make_config(variant, seed)
    ps = _sequence(name, data)
    t0, c0 = time.perf_counter(), time.process_time()
    joints = np.zeros((len(data["frames"]), 0, 3))
    error = ""
    try:
        joints = extract(ps, cfg, None, pictures=False).skeleton.joint_positions
    except PointrigError as exc:
        error = f"{type(exc).__name__}: {exc}"
    out = {"joints": np.asarray(joints, dtype=np.float64), "error": np.array(error),
           "seconds": np.float64(time.perf_counter() - t0),
           "cpu_seconds": np.float64(time.process_time() - c0)}
    _save_npz(Path(out_path), out)
    return out


#: The parameters that only the output stage reads (:func:`pointrig.pipeline.output_skeleton`):
#: with ``--output-stage`` a variant may change these and nothing else.
OUTPUT_STAGE_FIELDS = {
    "structure": ("joint_penalty", "joint_frames", "leaf_root", "centre_tolerance"),
    "joints": ("joint_depth", "depth_frames", "bone_twist", "twist_min_elongation",
               "twist_min_roll_deg"),
}


def check_output_stage_variant(variant: str) -> None:
    """Raise ``ValueError`` unless ``variant`` differs from the defaults only in
    :data:`OUTPUT_STAGE_FIELDS` (so steps 1-3 of the defaults are its steps 1-3 too)."""
    cfg, base = make_config(variant), make_config("{}")
    for f in dataclasses.fields(PipelineConfig):
        got, ref = getattr(cfg, f.name), getattr(base, f.name)
        free = set(OUTPUT_STAGE_FIELDS.get(f.name, ()))
        if not dataclasses.is_dataclass(got):
            if got != ref:
                raise ValueError(f"{f.name} is not an output-stage parameter")
            continue
        for g in dataclasses.fields(got):
            if g.name not in free and getattr(got, g.name) != getattr(ref, g.name):
                raise ValueError(f"[{f.name}] {g.name} is not an output-stage parameter "
                                 "(without --output-stage the variant runs whole)")


def output_stage_inputs(res: ExtractResult) -> dict[str, np.ndarray]:
    """What :func:`pointrig.pipeline.extract` passed to its output stage, from its result:
    rest points ``(M, 3)``, labels ``(M,)``, bone tree ``(B,)``, rest joints ``(B, 3)``,
    ``R (F, B, 3, 3)``, ``T (F, B, 3)``, weights ``(M, B)``, camera ``(3,)`` (``(0,)`` without
    one), the cleaned frames stacked ``(sum N_t, 3)`` with their counts ``(F,)`` and the final
    registration ``(F, M, 3)`` (metres)."""
    jr, st = res.joints, res.structure
    final = res.refined_registration or res.registration
    cam = st.view_camera
    return {"rest_points": res.registration.rest_points,
            "labels": np.argmax(jr.weights, axis=1), "bone_parent": st.bone_parent,
            "joints_rest": jr.joints_rest, "R": jr.R, "T": jr.T, "weights": jr.weights,
            "view_camera": np.zeros(0) if cam is None else np.asarray(cam, dtype=float),
            "frames": np.concatenate([np.asarray(f, dtype=np.float64) for f in res.frames]),
            "counts": np.array([len(f) for f in res.frames], dtype=np.int64),
            "registered": final.points}


def rerun_output_stage(inputs: dict[str, np.ndarray], config: PipelineConfig) -> np.ndarray:
    """The output joints ``(F, P, 3)`` (metres) of the output stage run with ``config`` on
    :func:`output_stage_inputs` (the same as a whole run's when ``config`` changes only
    :data:`OUTPUT_STAGE_FIELDS`)."""
    frames = np.split(inputs["frames"], np.cumsum(inputs["counts"])[:-1])
    cam = inputs["view_camera"]
    sk = output_skeleton(inputs["rest_points"], inputs["labels"], inputs["bone_parent"],
                         inputs["joints_rest"], inputs["R"], inputs["T"], inputs["weights"],
                         config, cam if len(cam) else None,
                         observed=(frames, inputs["registered"]))
    return sk.joint_positions


def stage_inputs_path(cache: Path, seq_path: str, seed: int, code_1_3: str) -> Path:
    """Where ``--output-stage`` caches the output-stage inputs of one cached sequence and seed,
    under the code of steps 1-3 (:func:`code_fingerprint` with ``steps_1_to_3``)."""
    key = hashlib.sha1(json.dumps({"code": code_1_3, "seed": seed}).encode()).hexdigest()[:16]
    return cache / "stage-inputs" / key / f"{Path(seq_path).stem}.npz"


def run_output_stage(name: str, seq_path: str, seed: int, inputs_path: str,
                     runs: list[tuple[str, str]]) -> list[str]:
    """``--output-stage``: steps 1-3 of the defaults (seeds raised by ``seed``) on one cached
    sequence, their output-stage inputs saved to ``inputs_path`` (reused when there), then the
    output stage of every ``(variant, out_path)`` in ``runs``, saved as
    :func:`run_pipeline` saves a run (its seconds those of the output stage). Returns each
    run's error (``""`` if none)."""
    ip = Path(inputs_path)
    inputs: dict[str, np.ndarray] | None = None
    error = ""
    if ip.exists():
        with np.load(ip) as z:
            inputs = {k: z[k] for k in z.files}
        n_frames = len(inputs["counts"])
    else:
        data = load_cached(Path(seq_path))
        n_frames = len(data["frames"])
        try:
            inputs = output_stage_inputs(extract(_sequence(name, data), make_config("{}", seed),
                                                 None, pictures=False))
            _save_npz(ip, inputs)
        except PointrigError as exc:
            error = f"{type(exc).__name__}: {exc}"
    errors = []
    for variant, out_path in runs:
        t0, c0 = time.perf_counter(), time.process_time()
        err = error
        joints = np.zeros((n_frames, 0, 3))  # no joints when a run fails, as run_pipeline
        if inputs is not None:
            try:
                joints = rerun_output_stage(inputs, make_config(variant, seed))
            except PointrigError as exc:
                err = f"{type(exc).__name__}: {exc}"
        _save_npz(Path(out_path), {"joints": np.asarray(joints, dtype=np.float64),
                                   "error": np.array(err),
                                   "seconds": np.float64(time.perf_counter() - t0),
                                   "cpu_seconds": np.float64(time.process_time() - c0)})
        errors.append(err)
    return errors


def score(name: str, seq_path: str, pred_path: str) -> dict[str, Any]:
    """Score a saved run against its sequence's ground truth (a row of the CSV, less the
    variant label)."""
    seq = corpus.SEQUENCES[name]
    data = load_cached(Path(seq_path))
    with np.load(pred_path, allow_pickle=False) as z:
        pred, error = z["joints"], str(z["error"])
        secs, cpu = float(z["seconds"]), float(z["cpu_seconds"])
    row: dict[str, Any] = {"sequence": name, "subject": seq.subject, "camera": seq.take.camera,
                           "distance": corpus.distance(seq), "frames": len(data["frames"]),
                           "seconds": secs, "cpu_seconds": cpu, "error": error} | _tags(name)
    ev = data["eval"]
    if pred.shape[1] == 0:
        mask, _, _ = scorable_joints(data["gt_joints"], data["parents"],
                                     surface=ev["surface"], surface_labels=ev["surface_labels"],
                                     skinned=ev["skinned"],
                                     bone_rotations=ev["bone_rotations"],
                                     bone_translations=ev["bone_translations"],
                                     rest_surface=ev["rest_surface"])
        row.update({"recall": 0.0, "precision": float("nan"), "n_pred": 0,
                    "n_scorable": int(mask.sum()), "n_matched": 0,
                    "normalized_error_cm": float("nan"), "raw_error_cm": float("nan"),
                    "far_fraction": float("nan"), "n_far": 0, "n_duplicate": 0,
                    "n_near_miss": 0, "subject_size_m": subject_size(data["gt_joints"], ev["surface"])})
        return row
    row.update(report_scores(evaluate(pred, data["gt_joints"], data["parents"], **ev)))
    return row


def report_scores(rep: EvalReport) -> dict[str, float]:
    """The numbers of a score row from an :class:`~pointrig.evaluate.EvalReport` (errors in
    cm, the subject's size in metres)."""
    return {"recall": rep.recall, "precision": rep.precision, "n_pred": rep.n_pred,
            "n_scorable": rep.n_scorable, "n_matched": rep.n_matched,
            "normalized_error_cm": 100 * rep.normalized_error,
            "raw_error_cm": 100 * rep.raw_error, "far_fraction": rep.far_fraction,
            "n_far": rep.n_far, "n_duplicate": rep.n_duplicate,
            "n_near_miss": rep.n_near_miss, "subject_size_m": rep.subject_size}


def _task(args: tuple[str, str, str, str, int]) -> tuple[str, str]:
    name, seq_path, variant, pred_path, seed = args
    try:
        out = run_pipeline(name, seq_path, variant, pred_path, seed)
    except Exception:  # noqa: BLE001 - a bug, not a pipeline error: report it, run the rest
        return name, traceback.format_exc(limit=3).strip().splitlines()[-1]
    return name, str(out["error"])


def _output_task(args: tuple[str, str, int, str, list[tuple[str, str]]]) -> list[str]:
    try:
        return run_output_stage(*args)
    except Exception:  # noqa: BLE001 - a bug, not a pipeline error: report it, run the rest
        return [traceback.format_exc(limit=3).strip().splitlines()[-1]] * len(args[4])


def _synth_task(args: tuple[str, int, str, str]) -> tuple[str, str, float]:
    name, frames, cache, code = args
    path, secs = ensure_sequence(name, frames, Path(cache), code)
    return name, path, secs


def _tags(name: str) -> dict[str, str]:
    """The corpus's current set, category and group of a sequence (cached scores keep the
    ones of their run)."""
    q = corpus.SEQUENCES[name]
    return {"set": q.set, "category": q.category, "group": q.group}


def _fmt(row: dict[str, Any] | None) -> str:
    if row is None or "recall" not in row:
        return f"{'failed':>30}"
    ne = row["normalized_error_cm"]
    ne_s = f"{ne:4.1f}" if np.isfinite(ne) else "   -"
    far = row["far_fraction"]
    far_s = f"{100 * far:3.0f}%" if np.isfinite(far) else "   -"
    prec = row["precision"]
    prec_s = f"{prec:.2f}" if np.isfinite(prec) else "   -"
    return (f"{row['recall']:.2f}/{prec_s} {row['n_pred']:>2.0f}/{row['n_scorable']:<2.0f} {ne_s} "
            f"{far_s} {row['seconds']:3.0f}s")


def summarise(rows: list[dict[str, Any]]) -> dict[str, float]:
    """Means over ``rows`` (module docstring)."""
    ok = [r for r in rows if "recall" in r]
    if not ok:
        return {}
    ne = [r["normalized_error_cm"] for r in ok if np.isfinite(r["normalized_error_cm"])]
    return {
        "n": len(ok),
        "recall": float(np.mean([r["recall"] for r in ok])),
        "precision": float(np.mean([r["precision"] if np.isfinite(r["precision"]) else 0.0
                                    for r in ok])),
        "n_pred": float(np.mean([r["n_pred"] for r in ok])),
        "n_scorable": float(np.mean([r["n_scorable"] for r in ok])),
        "normalized_error_cm": float(np.mean(ne)) if ne else float("nan"),
        "far_fraction": float(np.mean([r["far_fraction"] if np.isfinite(r["far_fraction"])
                                       else 0.0 for r in ok])),
        "n_duplicate": float(np.mean([r["n_duplicate"] for r in ok])),
        "n_near_miss": float(np.mean([r["n_near_miss"] for r in ok])),
        "seconds": float(np.sum([r["seconds"] for r in ok])),
        "cpu_seconds": float(np.sum([r.get("cpu_seconds", np.nan) for r in ok])),
        "failed": sum(bool(r.get("error")) for r in ok),
    }


NUMERIC = ("recall", "precision", "n_pred", "n_scorable", "n_matched", "normalized_error_cm",
           "raw_error_cm", "far_fraction", "n_far", "n_duplicate", "n_near_miss",
           "subject_size_m", "seconds", "cpu_seconds")


def seed_mean(rows: list[dict[str, Any] | None]) -> dict[str, Any] | None:
    """One sequence's runs (one per seed; ``None`` for a crashed run) as one row: the mean of
    each number over the scored runs (errors and precision over the runs that have one), the
    runs' pipeline errors joined. ``None`` if no run was scored."""
    ok = [r for r in rows if r is not None and "recall" in r]
    if not ok:
        return None
    out = dict(ok[0])
    for k in NUMERIC:
        vals = np.array([r[k] for r in ok], dtype=float)
        out[k] = float(np.nanmean(vals)) if np.isfinite(vals).any() else float("nan")
    out["error"] = "; ".join(r["error"] for r in ok if r.get("error"))
    return out


def f1_score(row: dict[str, Any]) -> float:
    """Harmonic mean of a row's recall and precision (0 without a prediction)."""
    r, p = row["recall"], row["precision"]
    return 2 * r * p / (r + p) if np.isfinite(p) and r + p > 0 else 0.0


def seed_spread(per_seed: list[dict[str, float]]) -> str:
    """The spread over seeds of a set's means (:func:`summarise` per seed): the standard
    deviation of recall, precision, F1 of the means, and normalised error."""
    per_seed = [s for s in per_seed if s]
    if len(per_seed) < 2:
        return "spread over seeds: -"
    sd = {k: float(np.std([s[k] for s in per_seed], ddof=1))
          for k in ("recall", "precision", "normalized_error_cm")}
    f1 = [f1_score(s) for s in per_seed]
    return (f"spread over {len(per_seed)} seeds (sd): recall {sd['recall']:.3f}  precision "
            f"{sd['precision']:.3f}  F1 {float(np.std(f1, ddof=1)):.3f}  norm "
            f"{sd['normalized_error_cm']:.2f} cm")


def paired_line(base: list[dict[str, Any]], run: list[dict[str, Any]]) -> str:
    """Per-sequence differences ``run - base`` (rows of the same sequences in the same order):
    the mean difference of F1, recall, precision, joints out and normalised error (over the
    sequences where both matched a joint), each with its paired sign-flip p-value, and how many
    sequences' F1 rose and fell."""
    parts = []
    for what, get, fmt in (("F1", f1_score, "+.3f"),
                           ("recall", lambda r: r["recall"], "+.3f"),
                           ("precision", lambda r: r["precision"] if np.isfinite(r["precision"])
                            else 0.0, "+.3f"),
                           ("joints", lambda r: r["n_pred"], "+.1f"),
                           ("norm cm", lambda r: r["normalized_error_cm"], "+.2f")):
        d = [get(y) - get(x) for x, y in zip(base, run)]
        d = [x for x in d if np.isfinite(x)]
        mean = float(np.mean(d)) if d else float("nan")
        parts.append(f"{what} {mean:{fmt}} (p {sign_flip_p(d):.2f})")
    df1 = [f1_score(y) - f1_score(x) for x, y in zip(base, run)]
    up, down = sum(d > 1e-9 for d in df1), sum(d < -1e-9 for d in df1)
    return ", ".join(parts) + f"; F1 up on {up}, down on {down} of {len(df1)}"


def _summary_line(label: str, s: dict[str, float]) -> str:
    if not s:
        return f"{label:<30} -"
    return (f"{label:<30} n {s['n']:>2}  recall {s['recall']:.3f}  precision {s['precision']:.3f}"
            f"  out/scored {s['n_pred']:5.1f}/{s['n_scorable']:4.1f}  norm "
            f"{s['normalized_error_cm']:4.2f} cm  far {100 * s['far_fraction']:4.1f} %  "
            f"dup {s['n_duplicate']:3.1f}  near miss {s['n_near_miss']:3.1f}  "
            f"{s['seconds']:5.0f} s ({s['cpu_seconds']:5.0f} s CPU)"
            + (f"  failed {s['failed']}" if s["failed"] else ""))


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("variants", nargs="*", default=["{}"],
                    help="JSON overrides per variant, or 'paper'")
    ap.add_argument("--set", default="both", choices=("tuning", "check", "both"))
    ap.add_argument("--only", default="",
                    help="comma-separated sequence names, subject ids or categories")
    ap.add_argument("--frames", type=int, default=corpus.FRAMES)
    ap.add_argument("--jobs", type=int, default=1, help="processes (pointrig uses 2 threads)")
    ap.add_argument("--cache", type=Path, default=DEFAULT_CACHE)
    ap.add_argument("--csv", type=Path, default=None, help="write one row per run here")
    ap.add_argument("--rerun", action="store_true", help="ignore cached scores")
    ap.add_argument("--seeds", type=int, default=1,
                    help="runs per variant and sequence, seeds raised by 0 .. K-1")
    ap.add_argument("--output-stage", action="store_true",
                    help="steps 1-3 of the defaults once per sequence and seed (inputs cached), "
                         "then each variant's output stage only")
    a = ap.parse_args(argv)
    if a.frames < 2 or a.jobs < 1 or a.seeds < 1:
        ap.error("--frames must be >= 2, --jobs and --seeds >= 1")
    try:
        for v in a.variants:
            make_config(v)
            if a.output_stage:
                check_output_stage_variant(v)
    except (ValueError, TypeError, PointrigError) as exc:
        ap.error(f"bad variant: {exc}")
    pool = {"tuning": corpus.TUNING, "check": corpus.CHECK,
            "both": corpus.SEQUENCES}[a.set]
    only = {x.strip() for x in a.only.split(",") if x.strip()}
    names = [n for n, q in pool.items()
             if not only or n in only or q.subject in only or q.category in only]
    unknown = only - set(corpus.SEQUENCES) - {q.subject for q in corpus.SEQUENCES.values()} \
        - set(corpus.CATEGORIES)
    if unknown:
        ap.error(f"unknown sequence, subject or category: {', '.join(sorted(unknown))}")
    # tuning first, then check
    names.sort(key=lambda n: (corpus.SEQUENCES[n].set != "tuning",
                              list(corpus.SEQUENCES).index(n)))
    if not names:
        return 0
    synth_code, code = synth_fingerprint(), code_fingerprint()
    code_1_3 = code_fingerprint(steps_1_to_3=True)
    t_start = time.perf_counter()
    paths: dict[str, str] = {}
    synth_secs = 0.0
    jobs = [(n, a.frames, str(a.cache), synth_code) for n in names]
    if a.jobs > 1:
        with ProcessPoolExecutor(a.jobs) as ex:
            done = list(ex.map(_synth_task, jobs))
    else:
        done = [_synth_task(j) for j in jobs]
    for n, p, s in done:
        paths[n] = p
        synth_secs += s
    if synth_secs:
        print(f"synthesized {sum(s > 0 for _, _, s in done)} sequences in {synth_secs:.0f} s "
              f"(cached in {a.cache})", flush=True)
    # runs: saved joints or tasks; every run is scored afresh
    seeds = range(a.seeds)
    rows: dict[tuple[int, int, str], dict[str, Any]] = {}
    tasks = []
    pred_paths: dict[tuple[int, int, str], str] = {}
    keys = [(v, sd) for v in range(len(a.variants)) for sd in seeds]
    run_dirs = {}
    for v, sd in keys:
        key: dict[str, Any] = {"v": a.variants[v].strip(), "code": code}
        if sd:
            key["seed"] = sd
        if a.output_stage:
            key["stage"] = "output"
        run_dirs[(v, sd)] = a.cache / "runs" / hashlib.sha1(
            json.dumps(key).encode()).hexdigest()[:16]
    # sequence by sequence, so that each one's line is printed as soon as its runs are done
    # --output-stage: one task per sequence and seed, its variants' output stages together
    stage_tasks: list[tuple[int, list[int], tuple[str, str, int, str, list[tuple[str, str]]]]] = []
    for n in names:
        for v, sd in keys:
            rp = run_dirs[(v, sd)] / f"{Path(paths[n]).stem}.npz"
            pred_paths[(v, sd, n)] = str(rp)
            if (not rp.exists() or a.rerun) and not a.output_stage:
                tasks.append(((v, sd), (n, paths[n], a.variants[v], str(rp), sd)))
        for sd in seeds if a.output_stage else ():
            todo = [v for v in range(len(a.variants))
                    if not Path(pred_paths[(v, sd, n)]).exists() or a.rerun]
            if todo:
                stage_tasks.append((sd, todo, (
                    n, paths[n], sd, str(stage_inputs_path(a.cache, paths[n], sd, code_1_3)),
                    [(a.variants[v], pred_paths[(v, sd, n)]) for v in todo])))
                tasks.extend(((v, sd), (n,)) for v in todo)
    pending = {(v, sd, t[0]) for (v, sd), t in tasks}
    print(f"{'sequence':<24} {'set':<6} {'cat':<10}" +
          "".join(f"{'v' + str(v) + ': rec/prec out/sc  cm far  time':>34}"
                  for v in range(len(a.variants))), flush=True)
    shown: set[str] = set()
    failures: list[str] = []
    # per variant and sequence: the mean over the seeds (a run that crashed, a bug with no
    # saved result, is listed below and left out)
    means: dict[tuple[int, str], dict[str, Any]] = {}

    def show_ready() -> None:
        for n in names:
            if n in shown:
                continue
            if any((v, sd, n) in pending for v, sd in keys):
                return
            for v, sd in keys:
                if Path(pred_paths[(v, sd, n)]).exists():
                    rows[(v, sd, n)] = score(n, paths[n], pred_paths[(v, sd, n)])
            for v in range(len(a.variants)):
                m = seed_mean([rows.get((v, sd, n)) for sd in seeds])
                if m is not None:
                    means[(v, n)] = m
            q = corpus.SEQUENCES[n]
            print(f"{n:<24} {q.set:<6} {q.category[:10]:<10}" +
                  "".join(f"{_fmt(means.get((v, n))):>34}" for v in range(len(a.variants))),
                  flush=True)
            shown.add(n)

    def finished(v: int, sd: int, name: str, err: str) -> None:
        pending.discard((v, sd, name))
        if err and not Path(pred_paths[(v, sd, name)]).exists():
            failures.append(f"variant {v} seed {sd} {name}: {err}")
        show_ready()

    show_ready()
    if a.output_stage:
        with ProcessPoolExecutor(a.jobs) as ex:
            sfuts = [(sd, todo, t[0], ex.submit(_output_task, t)) for sd, todo, t in stage_tasks]
            for sd, todo, n, f in sfuts:
                for v, err in zip(todo, f.result()):
                    finished(v, sd, n, err)
    elif a.jobs > 1 and tasks:
        with ProcessPoolExecutor(a.jobs) as ex:
            futs = [(k, ex.submit(_task, t)) for k, t in tasks]
            for (v, sd), f in futs:
                finished(v, sd, *f.result())
    else:
        for (v, sd), t in tasks:
            finished(v, sd, *_task(t))
    for msg in failures:
        print(msg)
    errors = [(v, sd, n, r["error"]) for (v, sd, n), r in rows.items() if r.get("error")]
    for v, sd, n, e in errors:
        print(f"variant {v} seed {sd} {n}: {e}")
    print()
    for v, var in enumerate(a.variants):
        print(f"variant {v}: {var}" + (f" ({a.seeds} seeds, sequences scored by their mean)"
                                       if a.seeds > 1 else ""))
        for s in ("tuning", "check"):
            rs = [means[(v, n)] for n in names
                  if corpus.SEQUENCES[n].set == s and (v, n) in means]
            if not rs:
                continue
            print(_summary_line(f"  {s}", summarise(rs)))
            if a.seeds > 1:
                print(f"  {'':<28}" + seed_spread([
                    summarise([rows[(v, sd, n)] for n in names
                               if corpus.SEQUENCES[n].set == s and (v, sd, n) in rows])
                    for sd in seeds]))
            for g in corpus.GROUPS:
                sub = [r for r in rs if r.get("group") == g]
                if sub:
                    print(_summary_line(f"    {g}", summarise(sub)))
            for c in corpus.CATEGORIES:
                sub = [r for r in rs if r.get("category") == c]
                if sub:
                    print(_summary_line(f"      {c}", summarise(sub)))
    if len(a.variants) > 1:
        print("\ndifference from variant 0 (per sequence; p: paired sign-flip test over the "
              "sequences)")
        for v in range(1, len(a.variants)):
            for s in ("tuning", "check"):
                both = [n for n in names if corpus.SEQUENCES[n].set == s
                        and (0, n) in means and (v, n) in means]
                if both:
                    print(f"  variant {v}, {s:<6} " + paired_line(
                        [means[(0, n)] for n in both], [means[(v, n)] for n in both]))
    print(f"\n{len(names)} sequences x {len(a.variants)} variants x {a.seeds} seeds, "
          f"{a.frames} frames, "
          f"{len(tasks)} runs now; wall {time.perf_counter() - t_start:.0f} s")
    if a.csv:
        with open(a.csv, "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=CSV_FIELDS, extrasaction="ignore")
            w.writeheader()
            for (v, sd, n), r in sorted(rows.items(),
                                        key=lambda x: (x[0][0], x[0][1], names.index(x[0][2]))):
                w.writerow({"variant": a.variants[v], "seed": sd, **r})
        print(f"wrote {a.csv}")
    return 1 if failures else 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
