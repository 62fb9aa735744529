"""Which ground-truth joints sit where their parts turn: the off-pivot joints of each sequence.

An articulated skeleton puts each joint where two parts turn about each other (Eq. 20). For
every scorable joint of a sequence's ground truth, :func:`pointrig.evaluate.pivot_errors`
gives the raw error of a joint at that turning point under the rig's exact motion; where it
reaches the matching threshold the joint is *off pivot*: the rig holds the part away from
where it turns (a skinless bone) or slides it (a translated bone), and a skeleton of turning
points matches it only through an error of its own. Needs only the synthesized ground truth
(no pipeline run). With ``--cache DIR`` (``bench_step3.py``'s cache of the default pipeline)
it also scores the cached run's joints over all scorable joints and over the on-pivot ones::

    PYTHONPATH=python python benchmarks/bench_pivots.py --set all
    PYTHONPATH=python python benchmarks/bench_pivots.py --set all --cache /tmp/step3

Prints per sequence the scorable and off-pivot joints (each with its pivot error against the
threshold, cm), then the counts per group (procedural figures, glTF rigs) and, with a cache,
the mean recall over all scorable joints and over the on-pivot ones.
"""

from __future__ import annotations

import argparse
import pickle
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "python"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_refine import add_set_option, chosen, suite  # noqa: E402
from bench_registration_downstream import score_joints  # noqa: E402


def pivot_row(syn: Any, joint_positions: np.ndarray | None = None) -> dict[str, Any]:
    """The off-pivot joints of ``syn``'s ground truth, and with ``joint_positions`` ``(F, P,
    3)`` (metres) their scores: ``n_scorable``, ``off`` (``[(name, pivot error m)]``),
    ``threshold`` (m) and, with positions, ``recall`` and ``recall_on`` (over the on-pivot
    scorable joints; nan if there are none)."""
    P = syn.gt_joints[:, :1] if joint_positions is None else joint_positions
    r = score_joints(P, syn)
    off = r.off_pivot
    out: dict[str, Any] = {"n_scorable": r.n_scorable, "threshold": r.threshold,
                           "off": [(row.name, row.pivot_error)
                                   for row, o in zip(r.rows, off) if o]}
    if joint_positions is not None:
        on = [row.matched >= 0 for row, o in zip(r.rows, off) if row.scorable and not o]
        out["recall"] = r.recall
        out["recall_on"] = float(np.mean(on)) if on else float("nan")
    return out


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_set_option(ap)
    ap.add_argument("--only", default="", help="comma-separated sequence names")
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--cache", default="", help="bench_step3.py's cache of the default run")
    a = ap.parse_args(argv)
    sequences, only = chosen(ap, a)
    groups: dict[str, list[dict[str, Any]]] = {"procedural": [], "glTF": []}
    for name, syn in suite(a.frames, only, sequences):
        pk = Path(a.cache) / f"{name}.pkl" if a.cache else None
        P = None
        if pk is not None and pk.exists():
            with open(pk, "rb") as f:
                P = pickle.load(f)["default_P"]
        row = pivot_row(syn, P)
        groups["glTF" if sequences[name][0].endswith(".glb") else "procedural"].append(row)
        off = ", ".join(f"{n} {100 * e:.1f}" for n, e in row["off"]) or "-"
        score = (f"  recall {row['recall']:.2f}, on pivot {row['recall_on']:.2f}"
                 if "recall" in row else "")
        print(f"{name:<24} scorable {row['n_scorable']:2d}  threshold "
              f"{100 * row['threshold']:5.1f} cm  off pivot {len(row['off'])}: {off}{score}",
              flush=True)
    print()
    for g, rows in groups.items():
        if not rows:
            continue
        n_sc = sum(r["n_scorable"] for r in rows)
        n_off = sum(len(r["off"]) for r in rows)
        line = (f"{g:<10} {len(rows):2d} sequences: {n_off} of {n_sc} scorable joints off pivot "
                f"({100 * n_off / max(n_sc, 1):.1f} %)")
        scored = [r for r in rows if "recall" in r]
        if scored:
            rec = np.mean([r["recall"] for r in scored])
            rec_on = np.nanmean([r["recall_on"] for r in scored])
            line += (f"; {len(scored)} cached runs: recall {rec:.3f}, over on-pivot joints "
                     f"{rec_on:.3f}")
        print(line)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
