"""How much of the registration's error is its objective's, and how much its start's.

The refinement (``RegistrationConfig.refine_rounds``, docs/registration.md "Session 26") fits
every frame alone from a posed template. Started from the *exact* pose (each rest point carried
by the true motion of its nearest exact surface sample of the rest frame,
:func:`bench_structure_oracle.exact_points`), the EM can only move away from the truth where
the objective (E_GMM + E_smooth + E_small of Eq. 8a on that frame's data) prefers another
pose: that drift is the objective's *bias*. The rest of the cached refined registration's
error (started from step 3's tracked pose) is the *start's* share. On ``bench_step3.py``'s
cache, per sequence::

    PYTHONPATH=python python benchmarks/bench_fit_bias.py --cache /tmp/step3 --set all
    PYTHONPATH=python python benchmarks/bench_fit_bias.py --cache /tmp/step3 --only girl_run \\
        '{}' '{"smooth_robust": 0.2}' '{"beta_smooth_rel": 1.0}'

Each positional JSON object is a set of ``[registration]`` overrides for the refinement from
the exact pose (``{}`` = the defaults, the first is the reference). Prints the mean
correspondence error (cm) of the exact pose itself (the tie's floor: rest points are noisy
samples, not the exact surface), of the refinement from it per variant, and of the cached
refined registration, each with the point-weighted mean ``|along|`` slide of the true bones
(:func:`bench_slide.bone_slides`) and the worst bone's mean / largest ``|along|``; then the
means over the sequences.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "python"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_refine import add_cache_options, chosen, suite  # noqa: E402
from bench_slide import bone_slides, correspondence, nearest_samples  # noqa: E402
from bench_step3 import cached_inputs  # noqa: E402
from bench_structure_oracle import exact_points  # noqa: E402

from pointrig.config import RegistrationConfig  # noqa: E402
from pointrig.registration import RegistrationResult, refine_registration  # noqa: E402
from pointrig.sequence import PointSequence  # noqa: E402


def refine_from(frames: list[np.ndarray], rest: np.ndarray, rest_index: int,
                posed: np.ndarray, config: RegistrationConfig) -> np.ndarray:
    """``(F, M, 3)`` the refinement (:func:`pointrig.registration.refine_registration`) of
    the ``F`` clouds ``frames`` (``(N_t, 3)``, metres) from the template ``rest`` ``(M, 3)``
    posed as ``posed`` ``(F, M, 3)`` in every frame, with the rest frame ``rest_index`` (whose
    cloud sets up the graph and the normals, as in the pipeline)."""
    F = len(frames)
    reg = RegistrationResult(rest_points=np.ascontiguousarray(rest, dtype=float),
                             points=np.asarray(posed, dtype=float), sigma2=np.zeros(F),
                             iterations=np.zeros(F), energy=np.zeros(F),
                             params={"rest_frame_index": int(rest_index)})
    return refine_registration(PointSequence(frames=list(frames)), reg, posed, config).points


def slide_summary(rest: np.ndarray, points: np.ndarray, syn: Any, rest_index: int,
                  nearest: np.ndarray) -> tuple[float, float, str]:
    """``(correspondence, mean |along|, worst bone)`` of registered ``points`` ``(F, M, 3)``:
    :func:`bench_slide.correspondence` (metres; ``nearest`` from
    :func:`bench_slide.nearest_samples`), the point-weighted mean ``|along|``
    slide over the true bones with one child (metres) and a label of the bone with the largest
    mean ``|along|`` (``"name mean/largest"`` cm)."""
    corr = correspondence(points, syn, nearest)
    rows = bone_slides(rest, points, syn, rest_index, nearest=nearest)
    if not rows:
        return corr, float("nan"), "-"
    n = np.array([r[1] for r in rows], dtype=float)
    al = np.array([np.abs(r[2]).mean() for r in rows])
    w = int(np.argmax(al))
    worst = f"{rows[w][0]} {100 * al[w]:.1f}/{100 * np.abs(rows[w][2]).max():.1f}"
    return corr, float((n * al).sum() / n.sum()), worst


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_cache_options(ap)
    ap.add_argument("variants", nargs="*", default=["{}"],
                    help="JSON [registration] overrides of the refinement from the exact pose")
    a = ap.parse_args(argv)
    sequences, only = chosen(ap, a)
    variants = [json.loads(v) for v in a.variants]
    configs = [dataclasses.replace(RegistrationConfig(), **v) for v in variants]
    heads = ["exact"] + [f"from exact {json.dumps(v)}" for v in variants] + ["cached refined"]
    print("per column: correspondence cm / mean |along| cm / worst bone mean/largest |along|")
    print(f"{'sequence':<24} " + " | ".join(heads), flush=True)
    table: list[list[tuple[float, float]]] = []
    for name, syn in suite(a.frames, only, sequences):
        d = cached_inputs(name, syn, Path(a.cache))
        r0, rest = int(d["rest_index"]), d["rest"]
        nn = nearest_samples(rest, syn, r0)
        exact = exact_points(rest, syn.surface, r0)
        poses = [exact] + [refine_from(d["frames"], rest, r0, exact, c) for c in configs]
        poses.append(d["regpts"])
        cells, row = [], []
        for P in poses:
            corr, along, worst = slide_summary(rest, P, syn, r0, nn)
            cells.append(f"{100 * corr:5.2f} / {100 * along:4.2f} / {worst}")
            row.append((corr, along))
        table.append(row)
        print(f"{name:<24} " + " | ".join(cells), flush=True)
    if table:
        arr = np.array(table)  # (S, columns, 2)
        print(f"\nmeans over {len(arr)} sequences (correspondence / mean |along|, cm):")
        for k, h in enumerate(heads):
            print(f"  {h:<44} {100 * arr[:, k, 0].mean():5.2f} / "
                  f"{100 * np.nanmean(arr[:, k, 1]):4.2f}")
        bias = arr[:, 1, 0] - arr[:, 0, 0]
        start = arr[:, -1, 0] - arr[:, 1, 0]
        print(f"  objective's bias (from exact - exact, first variant)  "
              f"{100 * bias.mean():5.2f}\n  start's share (cached refined - from exact)"
              f"           {100 * start.mean():5.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
