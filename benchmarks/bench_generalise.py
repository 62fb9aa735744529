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

Means: recall, precision, joints out, the far share and seconds over every sequence (a run
that fails counts as recall 0 and no joints); the normalised error over the sequences where the
run matched a joint.
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
from pointrig.config import PipelineConfig, RegistrationConfig, apply_overrides
from pointrig.errors import PointrigError
from pointrig.evaluate import evaluate, scorable_joints, subject_size
from pointrig.pipeline import extract
from pointrig.sequence import PointSequence

DEFAULT_CACHE = Path.home() / ".cache" / "pointrig-corpus"
#: Columns of the CSV, one row per run.
CSV_FIELDS = ("variant", "set", "sequence", "subject", "category", "group", "camera", "distance",
              "frames", "recall", "precision", "n_pred", "n_scorable", "n_matched",
              "normalized_error_cm", "raw_error_cm", "far_fraction", "n_far", "subject_size_m",
              "seconds", "cpu_seconds", "error")


def _sha1_files(paths: list[Path]) -> str:
    h = hashlib.sha1()
    for p in sorted(paths):
        h.update(p.name.encode())
        h.update(p.read_bytes())
    return h.hexdigest()


def code_fingerprint() -> str:
    """SHA-1 of the pipeline's code: pointrig's Python files and compiled core, less the
    scoring (evaluate.py) and the synthesis (synth/), which do not change its output (runs are
    cached under it; scores are computed afresh each time)."""
    root = Path(pointrig.__file__).resolve().parent
    files = [p for p in root.rglob("*.py")
             if p.name != "evaluate.py" and "synth" not in p.relative_to(root).parts]
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


def make_config(variant: str) -> PipelineConfig:
    """The :class:`PipelineConfig` of a variant (JSON overrides or ``paper``)."""
    if variant.strip() == "paper":
        if hasattr(PipelineConfig, "paper"):
            return PipelineConfig.paper()
        return dataclasses.replace(PipelineConfig(), registration=RegistrationConfig.paper())
    data = json.loads(variant)
    if not isinstance(data, dict):
        raise TypeError("a variant is a JSON object of per-stage overrides")
    return apply_overrides(data, where=f"variant {variant}")


def run_pipeline(name: str, seq_path: str, variant: str, out_path: str) -> dict[str, Any]:
    """Run the pipeline on one cached sequence and save its joints ``(F, P, 3)`` (or its
    error) with the seconds it took to ``out_path`` (an ``.npz``); returns what was saved."""
    data = load_cached(Path(seq_path))
    cfg = make_config(variant)
    ps = PointSequence(data["frames"], f"corpus:{name}",
                       [f"frame_{t:04d}" for t in range(len(data["frames"]))], "memory")
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
    op = Path(out_path)
    op.parent.mkdir(parents=True, exist_ok=True)
    tmp = op.with_suffix(".tmp.npz")
    np.savez(tmp, **out)
    tmp.replace(op)
    return out


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
                    "far_fraction": float("nan"), "n_far": 0,
                    "subject_size_m": subject_size(data["gt_joints"], ev["surface"])})
        return row
    rep = evaluate(pred, data["gt_joints"], data["parents"], **ev)
    row.update({"recall": rep.recall, "precision": rep.precision, "n_pred": rep.n_pred,
                "n_scorable": rep.n_scorable, "n_matched": rep.n_matched,
                "normalized_error_cm": 100 * rep.normalized_error,
                "raw_error_cm": 100 * rep.raw_error, "far_fraction": rep.far_fraction,
                "n_far": rep.n_far, "subject_size_m": rep.subject_size})
    return row


def _task(args: tuple[str, str, str, str]) -> tuple[str, str]:
    name, seq_path, variant, pred_path = args
    try:
        out = run_pipeline(name, seq_path, variant, pred_path)
    except Exception:  # noqa: BLE001 - a bug, not a pipeline error: report it, run the rest
        return name, traceback.format_exc(limit=3).strip().splitlines()[-1]
    return name, str(out["error"])


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
    return (f"{row['recall']:.2f}/{prec_s} {row['n_pred']:>2}/{row['n_scorable']:<2} {ne_s} "
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
        "seconds": float(np.sum([r["seconds"] for r in ok])),
        "cpu_seconds": float(np.sum([r.get("cpu_seconds", np.nan) for r in ok])),
        "failed": sum(bool(r.get("error")) for r in ok),
    }


def _summary_line(label: str, s: dict[str, float]) -> str:
    if not s:
        return f"{label:<30} -"
    return (f"{label:<30} n {s['n']:>2}  recall {s['recall']:.3f}  precision {s['precision']:.3f}"
            f"  out/scored {s['n_pred']:5.1f}/{s['n_scorable']:4.1f}  norm "
            f"{s['normalized_error_cm']:4.2f} cm  far {100 * s['far_fraction']:4.1f} %  "
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
    a = ap.parse_args(argv)
    if a.frames < 2 or a.jobs < 1:
        ap.error("--frames must be >= 2 and --jobs >= 1")
    try:
        for v in a.variants:
            make_config(v)
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
    rows: dict[tuple[int, str], dict[str, Any]] = {}
    tasks = []
    pred_paths: dict[tuple[int, str], str] = {}
    for v, var in enumerate(a.variants):
        vkey = hashlib.sha1(json.dumps({"v": var.strip(), "code": code}).encode()).hexdigest()
        for n in names:
            rp = a.cache / "runs" / vkey[:16] / f"{Path(paths[n]).stem}.npz"
            pred_paths[(v, n)] = str(rp)
            if not rp.exists() or a.rerun:
                tasks.append((v, (n, paths[n], var, str(rp))))
    pending = {(v, t[0]) for v, t in tasks}
    print(f"{'sequence':<24} {'set':<6} {'cat':<10}" +
          "".join(f"{'v' + str(v) + ': rec/prec out/sc  cm far  time':>34}"
                  for v in range(len(a.variants))), flush=True)
    shown: set[str] = set()
    failures: list[str] = []

    def show_ready() -> None:
        for n in names:
            if n in shown:
                continue
            if any((v, n) in pending for v in range(len(a.variants))):
                return
            for v in range(len(a.variants)):
                if Path(pred_paths[(v, n)]).exists():
                    rows[(v, n)] = score(n, paths[n], pred_paths[(v, n)])
            q = corpus.SEQUENCES[n]
            print(f"{n:<24} {q.set:<6} {q.category[:10]:<10}" +
                  "".join(f"{_fmt(rows.get((v, n))):>34}" for v in range(len(a.variants))),
                  flush=True)
            shown.add(n)

    def finished(v: int, name: str, err: str) -> None:
        pending.discard((v, name))
        if err and not Path(pred_paths[(v, name)]).exists():
            failures.append(f"variant {v} {name}: {err}")
        show_ready()

    show_ready()
    if a.jobs > 1 and tasks:
        with ProcessPoolExecutor(a.jobs) as ex:
            futs = [(v, ex.submit(_task, t)) for v, t in tasks]
            for v, f in futs:
                finished(v, *f.result())
    else:
        for v, t in tasks:
            finished(v, *_task(t))
    for msg in failures:
        print(msg)
    errors = [(v, n, r["error"]) for (v, n), r in rows.items() if r.get("error")]
    for v, n, e in errors:
        print(f"variant {v} {n}: {e}")
    print()
    for v, var in enumerate(a.variants):
        print(f"variant {v}: {var}")
        for s in ("tuning", "check"):
            # a run that crashed (a bug: no saved result) is listed above and left out here
            rs = [rows[(v, n)] for n in names
                  if corpus.SEQUENCES[n].set == s and (v, n) in rows]
            if not rs:
                continue
            print(_summary_line(f"  {s}", summarise(rs)))
            for g in corpus.GROUPS:
                sub = [r for r in rs if r.get("group") == g]
                if sub:
                    print(_summary_line(f"    {g}", summarise(sub)))
            for c in corpus.CATEGORIES:
                sub = [r for r in rs if r.get("category") == c]
                if sub:
                    print(_summary_line(f"      {c}", summarise(sub)))
    print(f"\n{len(names)} sequences x {len(a.variants)} variants, {a.frames} frames, "
          f"{len(tasks)} runs now; wall {time.perf_counter() - t_start:.0f} s")
    if a.csv:
        with open(a.csv, "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=CSV_FIELDS, extrasaction="ignore")
            w.writeheader()
            for (v, n), r in sorted(rows.items(), key=lambda x: (x[0][0], names.index(x[0][1]))):
                w.writerow({"variant": a.variants[v], **r})
        print(f"wrote {a.csv}")
    return 1 if failures else 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
