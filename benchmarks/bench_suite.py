"""The accuracy suite: the whole pipeline on a sequence set, scored against ground truth.

Each variant is a JSON object of per-stage overrides of :class:`pointrig.config.PipelineConfig`
(``{}`` = the defaults) or the word ``paper`` (:func:`benchmarks.sets.paper_config`, the
paper's pipeline). Every sequence of the set (:data:`benchmarks.sets.SETS`) runs
``--repeats`` times per variant, repeat ``k > 0`` on the input moved by at most 1e-9 m
(:func:`benchmarks.sets.jittered`: the spread over repeats is the rounding noise a difference
must beat). Prints per sequence and variant recall / precision / raw / normalised error (cm,
means over the repeats) and seconds, then per variant and repeat the set's means (errors over
the sequences where every run matches a joint) with the recall of the procedural figures and
of the glTF rigs, then each variant's difference from variant 0, the reference measured in the
same run, with a paired sign-flip p-value over the sequences::

    python -m benchmarks.bench_suite                           # the suite, ~9 min
    python -m benchmarks.bench_suite '{}' paper                # against the paper's pipeline
    python -m benchmarks.bench_suite --repeats 2 '{}' '{"structure": {"joint_penalty": 0}}'
    python -m benchmarks.bench_suite --set validation          # the held-back set
    python -m benchmarks.bench_suite --frames 40 --only human,hand

A variant may carry the benchmark-only key ``"max_joints_from": "skinned"``: each sequence then
runs with ``[structure] max_joints`` set to its rig's number of skinned joints (what a user who
knows the subject would pass as ``--max-joints``).

``--json FILE`` writes every run's report; ``--compare`` puts saved runs side by side instead
of running anything (each ``FILE[:VARIANT][@REPEAT]``, default variant 0, repeat 0; the first
repeat is deterministic on one machine, so a saved default run can stand in for a new one)::

    python -m benchmarks.bench_suite --json default.json
    python -m benchmarks.bench_suite --compare default.json variant.json:1
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import math
import random
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.sets import (
    add_sequence_options,
    chosen,
    jittered,
    paper_config,
    score_joints,
    suite,
)
from pointrig.config import PipelineConfig, apply_overrides
from pointrig.errors import ConfigError
from pointrig.pipeline import extract

__all__ = ["Run", "run_from_reports", "load_run", "common_means", "sign_flip_p", "variant_config",
           "main"]

#: The benchmark-only variant key (not a config key) that caps each sequence's joints at its
#: rig's skinned joint count.
CAP_KEY = "max_joints_from"


@dataclass(frozen=True)
class Run:
    """One variant and repeat of a suite run.

    Attributes
    ----------
    label
        What names it (``FILE[:VARIANT][@REPEAT]`` or ``VARIANT/REPEAT``).
    rows
        Sequence name -> ``(recall, precision, raw m, normalised m)``; the errors are ``nan``
        where no joint was matched.
    """

    label: str
    rows: dict[str, tuple[float, float, float, float]]


def _parse(spec: str) -> tuple[Path, int, int]:
    """``FILE[:VARIANT][@REPEAT]`` -> ``(path, variant, repeat)``."""
    rest, repeat = spec, 0
    if "@" in rest:
        rest, r = rest.rsplit("@", 1)
        repeat = int(r)
    variant = 0
    head, sep, tail = rest.rpartition(":")
    if sep and tail.isdigit():
        rest, variant = head, int(tail)
    return Path(rest), variant, repeat


def _error(report: dict[str, Any], name: str) -> float:
    v = report.get(name)
    return float("nan") if v is None else float(v)


def run_from_reports(reports: dict[str, dict[str, Any]], variant: int, repeat: int,
                     label: str) -> Run:
    """The run of ``variant`` and ``repeat`` out of the reports of a suite run
    (``"VARIANT/REPEAT/NAME"`` -> an :class:`pointrig.evaluate.EvalReport` as a dict, errors in
    metres, ``None`` where nothing matched), named ``label``; empty if it holds none."""
    prefix = f"{variant}/{repeat}/"
    rows = {key[len(prefix):]: (float(rep["recall"]), float(rep["precision"]),
                                _error(rep, "raw_error"), _error(rep, "normalized_error"))
            for key, rep in reports.items() if key.startswith(prefix)}
    return Run(label, rows)


def load_run(spec: str) -> Run:
    """The run named by ``spec`` (``FILE[:VARIANT][@REPEAT]``) in a ``--json`` file.

    Raises
    ------
    ValueError
        If the file is not a ``--json`` file of this benchmark or holds no sequence of that
        variant and repeat (the message names the file and what it holds).
    """
    path, variant, repeat = _parse(spec)
    try:
        runs = json.loads(path.read_text())["runs"]
        run = run_from_reports(runs, variant, repeat, spec)
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"{path}: not a bench_suite --json file ({exc})") from exc
    if not run.rows:
        held = sorted({"/".join(k.split("/")[:2]) for k in runs})
        raise ValueError(f"{path}: no runs of variant {variant} repeat {repeat} "
                         f"(it holds variant/repeat {', '.join(held) or 'nothing'})")
    return run


def common_means(runs: list[Run]) -> tuple[list[str], list[str],
                                            list[tuple[float, float, float, float]]]:
    """The sequences every run holds (in the first run's order), those of them where every
    run matched a joint, and per run ``(recall, precision, raw m, normalised m)``: recall and
    precision averaged over the first list, the errors over the second (``nan`` if empty)."""
    names = [n for n in runs[0].rows if all(n in r.rows for r in runs)]
    matched = [n for n in names if all(math.isfinite(r.rows[n][3]) for r in runs)]

    def mean(xs: list[float]) -> float:
        return sum(xs) / len(xs) if xs else float("nan")

    means = [(mean([r.rows[n][0] for n in names]), mean([r.rows[n][1] for n in names]),
              mean([r.rows[n][2] for n in matched]), mean([r.rows[n][3] for n in matched]))
             for r in runs]
    return names, matched, means


def sign_flip_p(diffs: list[float], exact_up_to: int = 16, samples: int = 20000,
                seed: int = 0) -> float:
    """Two-sided p-value of the paired sign-flip (permutation) test that ``diffs``, per-sequence
    differences between two runs, are symmetric about 0: the share of the ``2^n`` sign
    patterns (all of them for ``n <= exact_up_to``, else ``samples`` random ones drawn with
    ``seed``) whose mean is at least ``|mean(diffs)|`` in size; 1.0 for no differences.
    Zero differences count as ties and are kept (their signs do not matter)."""
    n = len(diffs)
    if n == 0 or all(d == 0 for d in diffs):
        return 1.0
    target = abs(sum(diffs)) - 1e-12 * sum(abs(d) for d in diffs)
    if n <= exact_up_to:
        patterns = itertools.product((1.0, -1.0), repeat=n)
        total = 2 ** n
    else:
        rng = random.Random(seed)
        patterns = ([rng.choice((1.0, -1.0)) for _ in range(n)] for _ in range(samples))
        total = samples
    hits = sum(1 for sg in patterns if abs(sum(g * d for g, d in zip(sg, diffs))) >= target)
    return hits / total


def _differences(runs: list[Run], names: list[str], matched: list[str],
                 labels: list[str]) -> list[str]:
    """One line per run after the first, headed by its label: its difference from the first in
    the four means, with the sign-flip p-value over the sequences."""
    lines = []
    for k in range(1, len(runs)):
        parts = []
        for i, (what, seqs, scale, fmt) in enumerate((
                ("recall", names, 1.0, "+.3f"), ("precision", names, 1.0, "+.3f"),
                ("raw", matched, 100.0, "+.2f"), ("normalised", matched, 100.0, "+.2f"))):
            d = [runs[k].rows[n][i] - runs[0].rows[n][i] for n in seqs]
            mean = sum(d) / len(d) if d else float("nan")
            parts.append(f"{what} {scale * mean:{fmt}} (p {sign_flip_p(d):.2f})")
        lines.append(f"{labels[k]}: " + ", ".join(parts))
    return lines


def _cell(row: tuple[float, float, float, float]) -> str:
    return f"{row[0]:.2f}/{row[1]:.2f} {100 * row[2]:5.2f} {100 * row[3]:5.2f}"


def compare(specs: list[str]) -> int:
    """Print saved runs side by side (``--compare``): per sequence every run holds, recall /
    precision / raw / normalised cm (``*`` where it differs from the first run), the means, and
    each later run's difference from the first. Returns the exit status."""
    try:
        runs = [load_run(s) for s in specs]
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    names, matched, means = common_means(runs)
    if not names:
        print("error: no sequence is in every run", file=sys.stderr)
        return 1
    for k, r in enumerate(runs):
        print(f"run {k}: {r.label}")
    print(f"{'sequence':<26}" + "".join(f"{'run ' + str(k):>26}" for k in range(len(runs))))
    for n in names:
        first = _cell(runs[0].rows[n])
        cells = [_cell(r.rows[n]) for r in runs]
        print(f"{n:<26}" + "".join(f"{c + (' *' if c != first else '  '):>26}"
                                    for c in cells))
    left = sorted({n for r in runs for n in r.rows} - set(names))
    if left:
        print(f"left out (not in every run): {', '.join(left)}")
    print(f"\nmeans over {len(names)} sequences (recall / precision) and the {len(matched)} where "
          "every run matches a joint (raw / normalised cm):")
    for k, m in enumerate(means):
        print(f"run {k}: recall {m[0]:.3f} precision {m[1]:.3f} raw {100 * m[2]:.2f} "
              f"normalised {100 * m[3]:.2f}  {runs[k].label}")
    print("\ndifference from run 0 (p: paired sign-flip test over the sequences):")
    print("\n".join(_differences(runs, names, matched, [f"run {k}" for k in range(len(runs))])))
    return 0


def variant_config(spec: str, where: str) -> tuple[PipelineConfig, str | None]:
    """The configuration of one variant argument (a JSON object of per-stage overrides, or
    ``paper``) and its :data:`CAP_KEY` value (``None`` or ``"skinned"``).

    Raises
    ------
    ValueError
        On bad JSON, a value that is not an object, an unknown stage or parameter
        (:class:`pointrig.errors.ConfigError` is a ``ValueError``) or a bad cap.
    """
    if spec.strip() == "paper":
        return paper_config(), None
    over = json.loads(spec)
    if not isinstance(over, dict):
        raise ValueError(f"{where}: a JSON object or 'paper', got {spec!r}")
    cap = over.get(CAP_KEY)
    if cap not in (None, "skinned"):
        raise ValueError(f"{where}: {CAP_KEY} must be \"skinned\"")
    try:
        cfg = apply_overrides({k: x for k, x in over.items() if k != CAP_KEY}, where=where)
    except ConfigError as exc:
        msg = str(exc)
        raise ConfigError(msg if msg.startswith(where) else f"{where}: {msg}") from None
    return cfg, cap


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("variants", nargs="*", default=["{}"],
                    help="JSON per-stage overrides, or 'paper', per variant (default: {})")
    add_sequence_options(ap)
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--json", type=Path, default=None, help="write every run's report here")
    ap.add_argument("--compare", nargs="+", metavar="FILE[:VARIANT][@REPEAT]",
                    help="compare saved --json runs instead of running")
    a = ap.parse_args(argv)
    if a.compare is not None:
        if len(a.compare) < 2:
            ap.error("--compare: give at least two runs")
        return compare(a.compare)
    if a.repeats < 1:
        ap.error("--repeats must be >= 1")
    sequences, only = chosen(ap, a)
    procedural = {n for n, (src, _) in sequences.items() if not src.endswith(".glb")}
    try:
        pairs = [variant_config(v, f"variant {i}") for i, v in enumerate(a.variants)]
    except (ValueError, AttributeError) as exc:
        ap.error(f"bad variant: {exc}")
    # every run's report (errors in metres) and seconds, keyed "variant/repeat/name"
    reports: dict[str, dict[str, Any]] = {}
    print(f"{'sequence':<24}" + "".join(f"{'variant ' + str(v):>34}" for v in range(len(pairs))))
    for name, syn in suite(a.frames, only, sequences):
        seq0 = syn.to_point_sequence()
        cells = []
        for v, (cfg, cap) in enumerate(pairs):
            if cap == "skinned":
                cfg = dataclasses.replace(cfg, structure=dataclasses.replace(
                    cfg.structure, max_joints=int(np.sum(syn.skinned))))
            rows = []  # per repeat: recall, precision, raw cm, normalised cm, seconds
            for k in range(a.repeats):
                seq = seq0 if k == 0 else jittered(seq0, k)
                t0 = time.perf_counter()
                out = extract(seq, cfg, None, pictures=False)
                secs = time.perf_counter() - t0
                rep = score_joints(out.skeleton.joint_positions, syn)
                rows.append((rep.recall, rep.precision, 100 * rep.raw_error,
                             100 * rep.normalized_error, secs))
                reports[f"{v}/{k}/{name}"] = rep.to_dict() | {"seconds": secs}
            g = np.array(rows)
            m = np.nanmean(g, axis=0) if np.isfinite(g[:, 3]).any() else g.mean(axis=0)
            cells.append(f"{m[0]:.2f}/{m[1]:.2f} {m[2]:5.2f} {m[3]:5.2f} ({m[4]:3.0f} s)")
        print(f"{name:<24}" + "".join(f"{c:>34}" for c in cells), flush=True)
        if a.json:
            a.json.write_text(json.dumps({"variants": a.variants, "runs": reports}, indent=1,
                                         default=str))
    if not reports:
        return 0
    keys = [(v, k) for v in range(len(pairs)) for k in range(a.repeats)]
    runs = [run_from_reports(reports, v, k, f"{v}/{k}") for v, k in keys]
    names, every, means = common_means(runs)
    print(f"\nmeans over {len(names)} sequences of {a.frames} frames (raw / normalised over the "
          f"{len(every)} where every run matches a joint); recall of the procedural figures / "
          "the glTF rigs:")
    for (v, k), run, m in zip(keys, runs, means):
        proc = [run.rows[n][0] for n in names if n in procedural]
        gl = [run.rows[n][0] for n in names if n not in procedural]
        f = lambda x: f"{np.mean(x):.3f}" if len(x) else "-"  # noqa: E731
        secs = sum(reports[f"{v}/{k}/{n}"]["seconds"] for n in names)
        print(f"variant {v} repeat {k}: recall {m[0]:.3f} precision {m[1]:.3f} raw "
              f"{100 * m[2]:.2f} cm normalised {100 * m[3]:.2f} cm; procedural {f(proc)} glTF "
              f"{f(gl)}; {secs:.0f} s  {a.variants[v]}")
    if len(runs) > 1:
        print("\ndifference from variant 0 repeat 0, the reference (p: paired sign-flip test "
              "over the sequences):")
        print("\n".join(_differences(runs, names, every,
                                      [f"variant {v} repeat {k}" for v, k in keys])))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
