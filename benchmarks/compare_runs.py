"""Compare runs of ``bench_suite.py --json`` saved at different times, sequence by sequence.

A variant measured in a later session is compared with the default's saved run instead of
running the default again: the first repeat of a sequence is deterministic on one machine
(``bench_suite.py``: repeat 0 runs the input as generated), so the same code gives the same
figures. Each argument is a JSON file written by ``bench_suite.py --json``, optionally with
``:VARIANT`` (default 0) and ``@REPEAT`` (default 0), e.g. ``old.json``, ``new.json:1@0``::

    PYTHONPATH=python python benchmarks/compare_runs.py default.json variant.json
    PYTHONPATH=python python benchmarks/compare_runs.py val.json val_a.json val_b.json

Prints, per sequence that every run holds, recall / precision / raw / normalised cm of each
run (``*`` where it differs from the first run), then per run the means over those sequences:
recall and precision over all of them, the two errors over the sequences where every run
matches a joint (a sequence where one run matches nothing would otherwise move the error
means by its absence). Sequences that only some runs hold are named and left out. Under
the means, each later run's difference from the first in each of the four means, with the
two-sided p-value of a paired sign-flip test over the sequences (:func:`sign_flip_p`): how
often flipping the signs of the per-sequence differences at random gives a mean difference at
least as large. A p-value near 1 says the run differs from the first no more consistently than
run-to-run noise would; it does not replace repeats (``bench_suite.py --repeats``).
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import random
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

__all__ = ["Run", "run_from_reports", "load_run", "common_means", "sign_flip_p", "main"]


@dataclass(frozen=True)
class Run:
    """One variant and repeat of a saved suite run.

    Attributes
    ----------
    label
        The argument that named it (``FILE[:VARIANT][@REPEAT]``).
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
    """The run of ``variant`` and ``repeat`` out of ``bench_suite.py``'s reports
    (``"VARIANT/REPEAT/NAME"`` -> an :class:`pointrig.evaluate.EvalReport` as a dict, errors in
    metres, ``None`` where nothing matched), named ``label``; empty if it holds none."""
    prefix = f"{variant}/{repeat}/"
    rows = {key[len(prefix):]: (float(rep["recall"]), float(rep["precision"]),
                                _error(rep, "raw_error"), _error(rep, "normalized_error"))
            for key, rep in reports.items() if key.startswith(prefix)}
    return Run(label, rows)


def load_run(spec: str) -> Run:
    """The run named by ``spec`` (``FILE[:VARIANT][@REPEAT]``).

    Raises
    ------
    ValueError
        If the file is not a ``bench_suite.py --json`` file or holds no sequence of that
        variant and repeat (the message names the file and what it holds).
    """
    path, variant, repeat = _parse(spec)
    try:
        runs = json.loads(path.read_text())["runs"]
        run = run_from_reports(runs, variant, repeat, spec)
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"{path}: not a bench_suite.py --json file ({exc})") from exc
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


def _cell(row: tuple[float, float, float, float]) -> str:
    return f"{row[0]:.2f}/{row[1]:.2f} {100 * row[2]:5.2f} {100 * row[3]:5.2f}"


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", help="FILE[:VARIANT][@REPEAT] of bench_suite.py --json")
    a = ap.parse_args(argv)
    if len(a.runs) < 2:
        ap.error("give at least two runs to compare")
    try:
        runs = [load_run(s) for s in a.runs]
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
    for k in range(1, len(runs)):
        parts = []
        for i, (what, seqs, scale, fmt) in enumerate((
                ("recall", names, 1.0, "+.3f"), ("precision", names, 1.0, "+.3f"),
                ("raw", matched, 100.0, "+.2f"), ("normalised", matched, 100.0, "+.2f"))):
            d = [runs[k].rows[n][i] - runs[0].rows[n][i] for n in seqs]
            mean = sum(d) / len(d) if d else float("nan")
            parts.append(f"{what} {scale * mean:{fmt}} (p {sign_flip_p(d):.2f})")
        print(f"run {k}: " + ", ".join(parts))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
