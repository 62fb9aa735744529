"""Step 2 on exact tracks: how much of the corpus's gap is the registration's.

For every sequence of the subject-split corpus (:mod:`benchmarks.corpus`), step 2 (the skeletal
structure, §5, with the defaults; no output stage) runs on three sets of tracked points and its
skeleton is scored as :mod:`benchmarks.bench_generalise` scores the pipeline's:

- ``exact, all``: 2000 of the ground-truth surface samples, exactly where the rig puts them in
  every frame, the back of the body included (no method sees it from one view);
- ``exact, seen``: the same from the samples seen in the first frame only (:func:`seen_from`),
  the surface one depth view tracks at best;
- ``registered``: the pipeline's final registration (step 1 and the refinement round, the
  defaults, seed 0), read from ``bench_generalise --output-stage``'s cache of steps 1-3 (run
  and cached when missing, about a minute a sequence).

The difference between the last two rows is what a perfect registration would win::

    python -m benchmarks.bench_tracks [--set check] [--only cowboy_0] [--jobs 2]

``--step1 VARIANT ...`` (JSON overrides, as bench_generalise's variants) adds a row per
variant, the defaults first: step 2 on the first registration (step 1 alone, seed 0, no
refinement) of that variant: a change of step 1 read without step 3 and the refinement, so
both sets in about the time of one whole run of the variant, on one seed; a change found there
still has to win in :mod:`benchmarks.bench_generalise`::

    python -m benchmarks.bench_tracks --jobs 2 --step1 '{"registration": {"rigid_iterations": 6}}'

Prints per sequence recall / precision, joints out / scored, the normalised error and the near
misses (:attr:`pointrig.evaluate.EvalReport.near_miss`) of each row, then the means per set and
per set and group.
"""

from __future__ import annotations

import argparse
from concurrent.futures import ProcessPoolExecutor
from contextlib import nullcontext
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks import bench_generalise as bg
from benchmarks import corpus
from pointrig.config import StructureConfig
from pointrig.evaluate import evaluate
from pointrig.kinematics import joint_trajectories
from pointrig.pipeline import extract
from pointrig.structure import extract_structure

ROWS = ("exact, all", "exact, seen", "registered")
#: tracked points a run of step 2 reads (the pipeline's ``n_rest_points``)
N_POINTS = 2000


def seen_from(points: np.ndarray, camera: np.ndarray, bin_deg: float = 0.4,
              depth_tolerance: float = 0.03) -> np.ndarray:
    """Which surface samples a camera sees: a z-buffer over directions.

    The directions from ``camera`` are binned in azimuth and elevation (``bin_deg`` degrees);
    a sample is seen when it is within ``depth_tolerance`` of the nearest sample of its bin.

    Parameters
    ----------
    points
        ``(S, 3)`` surface samples, metres, dense enough that every bin the surface covers
        holds a sample of its front.
    camera
        ``(3,)`` camera position, metres, same frame (looking along +z).
    bin_deg, depth_tolerance
        Bin size (degrees) and depth tolerance (metres).

    Returns
    -------
    numpy.ndarray
        ``(S,)`` bool.
    """
    v = np.asarray(points, dtype=np.float64) - np.asarray(camera, dtype=np.float64)
    r = np.linalg.norm(v, axis=1)
    az = np.floor(np.degrees(np.arctan2(v[:, 0], v[:, 2])) / bin_deg).astype(np.int64)
    el = np.floor(np.degrees(np.arctan2(v[:, 1], v[:, 2])) / bin_deg).astype(np.int64)
    _, key = np.unique(np.stack([az, el], axis=1), axis=0, return_inverse=True)
    nearest = np.full(int(key.max()) + 1 if len(key) else 0, np.inf)
    np.minimum.at(nearest, key.ravel(), r)
    return r <= nearest[key.ravel()] + depth_tolerance


def _score(pred: np.ndarray, data: dict[str, Any]) -> dict[str, float]:
    return bg.report_scores(evaluate(pred, data["gt_joints"], data["parents"], **data["eval"]))


def _step2(rest: np.ndarray, tracks: np.ndarray) -> np.ndarray:
    """``(F, P, 3)`` joints of step 2 (defaults) on ``tracks (F, M, 3)`` from ``rest (M, 3)``."""
    st = extract_structure(rest, tracks, StructureConfig())
    return joint_trajectories(st.joints_rest, st.R, st.T, st.bone_parent)


def run_sequence(name: str, seq_path: str, inputs_path: str, step1: tuple[str, ...] = ()
                 ) -> dict[str, dict[str, float]]:
    """The rows (:data:`ROWS`, then ``step 1 v<i>`` for the ``i``-th variant of ``step1``) of
    one sequence, each scored."""
    data = bg.load_cached(Path(seq_path))
    surf = np.asarray(data["eval"]["surface"], dtype=np.float64)  # (F, S, 3)
    rng = np.random.default_rng(0)
    out = {}
    for row, pool in ((ROWS[0], np.arange(surf.shape[1])),
                      (ROWS[1], np.flatnonzero(seen_from(surf[0], np.zeros(3))))):
        idx = np.sort(rng.choice(pool, min(N_POINTS, len(pool)), replace=False))
        out[row] = _score(_step2(surf[0, idx], surf[:, idx]), data)
    if not Path(inputs_path).exists():
        bg.run_output_stage(name, seq_path, 0, inputs_path, [])
    with np.load(inputs_path) as z:
        out[ROWS[2]] = _score(_step2(z["rest_points"], z["registered"]), data)
    for i, v in enumerate(step1):
        reg = extract(bg._sequence(name, data), bg.make_config(v), None, pictures=False,
                      stop_after="registration").registration
        out[f"step 1 v{i}"] = _score(_step2(reg.rest_points, reg.points), data)
    return out


def _task(args: tuple[str, str, str, tuple[str, ...]]) -> tuple[str, dict[str, dict[str, float]]]:
    return args[0], run_sequence(*args)


def _line(s: dict[str, float]) -> str:
    return (f"{s['recall']:.2f}/{s['precision']:.2f} {s['n_pred']:4.1f}/{s['n_scorable']:4.1f} "
            f"{s['normalized_error_cm']:4.1f} {s['n_near_miss']:3.1f}")


def _mean(rows: list[dict[str, float]]) -> dict[str, float]:
    return {k: float(np.nanmean([r[k] for r in rows])) for k in rows[0]}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set", default="both", choices=("tuning", "check", "both"))
    ap.add_argument("--only", default="", help="comma-separated sequence names")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--cache", type=Path, default=bg.DEFAULT_CACHE)
    ap.add_argument("--step1", nargs="+", default=[], metavar="VARIANT",
                    help="JSON overrides: a row of step 2 on each one's step 1 (defaults first)")
    a = ap.parse_args(argv)
    step1 = tuple(dict.fromkeys(["{}"] + a.step1)) if a.step1 else ()
    for v in step1:
        try:
            bg.make_config(v)
        except (ValueError, TypeError) as exc:
            ap.error(f"bad variant {v}: {exc}")
    rows = ROWS + tuple(f"step 1 v{i}" for i in range(len(step1)))
    for i, v in enumerate(step1):
        print(f"v{i}: {v}")
    only = {x.strip() for x in a.only.split(",") if x.strip()}
    names = [n for n, q in corpus.SEQUENCES.items()
             if (a.set == "both" or q.set == a.set) and (not only or n in only)]
    if only - set(corpus.SEQUENCES):
        ap.error(f"unknown sequence: {', '.join(sorted(only - set(corpus.SEQUENCES)))}")
    names.sort(key=lambda n: corpus.SEQUENCES[n].set != "tuning")
    synth_code, code_1_3 = bg.synth_fingerprint(), bg.code_fingerprint(steps_1_to_3=True)
    tasks = []
    for n in names:
        path, _ = bg.ensure_sequence(n, corpus.FRAMES, a.cache, synth_code)
        tasks.append((n, path, str(bg.stage_inputs_path(a.cache, path, 0, code_1_3)), step1))
    head = "rec/prec  out/scored  cm near"
    print(f"{'sequence':<24} {'set':<6}" + "".join(f"  {r + ': ' + head:>38}" for r in rows))
    results: dict[str, dict[str, dict[str, float]]] = {}
    with ProcessPoolExecutor(a.jobs) if a.jobs > 1 else nullcontext() as ex:
        for n, res in (ex.map(_task, tasks) if ex is not None else map(_task, tasks)):
            results[n] = res
            print(f"{n:<24} {corpus.SEQUENCES[n].set:<6}"
                  + "".join(f"  {_line(res[r]):>38}" for r in rows), flush=True)
    print()
    for st in ("tuning", "check"):
        for grp in (None, "human-sized", "animal", "other"):
            sel = [n for n in names if corpus.SEQUENCES[n].set == st
                   and (grp is None or corpus.SEQUENCES[n].group == grp)]
            if not sel:
                continue
            label = f"{st} ({len(sel)})" if grp is None else f"  {grp} ({len(sel)})"
            print(f"{label:<31}" + "".join(
                f"  {_line(_mean([results[n][r] for n in sel])):>38}" for r in rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
