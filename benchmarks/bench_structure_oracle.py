"""What step 2 on the registration costs after step 3: a ladder of exact-motion oracles.

On the cached inputs of the default pipeline's final step 3 (``bench_step3.py --cache DIR``),
step 2 runs six ways and step 3 (the default, on the real frames and the refined
registration, then the pipeline's output stage) after each; only the structure changes:

* ``registration``: step 2 on the registered points (the default pipeline);
* ``exact labels``: the segmentation of step 2 run on the *exact* motion of the same rest
  points, with the tree, the bone motions and the joints from the registration
  (:func:`pointrig.structure.structure_from_labels`);
* ``+ exact tree``: that segmentation and its tree, motions and joints from the registration;
* ``+ exact joints``: segmentation, tree and joints of the exact motion's step 2, the bone
  motions from the registration (step 3's tracker holds step 2's joints and starts from its
  motions: this rung and the next tell which of the two costs more, session 52);
* ``+ exact motions``: segmentation, tree and bone motions of the exact motion's step 2, the
  joints from the registration;
* ``exact step 2``: all of step 2 on the exact motion.

The exact motion ties each rest point to its nearest exact surface sample of the rest frame
and moves it with that sample (:func:`exact_points`). Prints recall / precision, raw /
normalised error (cm) and the bone count per sequence and rung, then the means::

    PYTHONPATH=python python benchmarks/bench_structure_oracle.py --cache /tmp/step3
    PYTHONPATH=python python benchmarks/bench_structure_oracle.py --cache /tmp/step3 \\
        --only human,girl_run
    PYTHONPATH=python python benchmarks/bench_structure_oracle.py --cache /tmp/step3 \\
        --set validation --only v_hand,v_girl_idle_y40
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "python"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_refine import add_cache_options, chosen, suite  # noqa: E402
from bench_registration_downstream import score_joints  # noqa: E402
from bench_step3 import cached_inputs, step3_skeleton, summary  # noqa: E402

from pointrig.config import PipelineConfig  # noqa: E402
from pointrig.structure import extract_structure, structure_from_labels  # noqa: E402

RUNGS = ("registration", "exact labels", "+ exact tree", "+ exact joints", "+ exact motions",
         "exact step 2")


def exact_points(rest: np.ndarray, surface: np.ndarray, rest_index: int) -> np.ndarray:
    """``(F, M, 3)`` exact motion of the rest points ``(M, 3)`` (metres): each is tied to its
    nearest sample of ``surface[rest_index]`` (``surface``: ``(F, S, 3)`` exact samples) and
    carried by that sample's motion, keeping its offset, so frame ``rest_index`` is ``rest``
    exactly."""
    nn = cKDTree(surface[rest_index]).query(rest)[1]
    return np.ascontiguousarray(surface[:, nn] + (rest - surface[rest_index, nn])[None])


def structures(d: dict[str, Any], syn: Any, cfg: PipelineConfig) -> dict[str, Any]:
    """Step 2 of each rung for the cached inputs ``d`` of sequence ``syn``."""
    Q, Y = d["rest"], np.ascontiguousarray(d["regpts"])
    exact = extract_structure(Q, exact_points(Q, syn.surface, d["rest_index"]), cfg.structure)
    tree = structure_from_labels(Q, Y, exact.labels, cfg.structure, exact.bone_parent)
    return {
        "registration": d["structure"],
        "exact labels": structure_from_labels(Q, Y, exact.labels, cfg.structure),
        "+ exact tree": tree,
        # the same labels and tree, so the bones line up one to one
        "+ exact joints": dataclasses.replace(tree, joints_rest=exact.joints_rest,
                                              c_tilde=exact.c_tilde),
        "+ exact motions": dataclasses.replace(exact, joints_rest=tree.joints_rest,
                                               c_tilde=tree.c_tilde),
        "exact step 2": exact,
    }


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_cache_options(ap)
    a = ap.parse_args(argv)
    sequences, only = chosen(ap, a)
    cfg = PipelineConfig()
    rows: dict[str, list[tuple[float, ...]]] = {k: [] for k in RUNGS}
    print(f"{'sequence':<24} " + " | ".join(f"{k}: rec/prec raw norm B" for k in RUNGS))
    for name, syn in suite(a.frames, only, sequences):
        d = cached_inputs(name, syn, Path(a.cache))
        t0 = time.perf_counter()
        cells = []
        for rung, st in structures(d, syn, cfg).items():
            sk, _secs = step3_skeleton(d, st, cfg.joints, cfg.structure)
            r = score_joints(sk.joint_positions, syn)
            B = len(st.bone_parent)
            rows[rung].append((r.recall, r.precision, 100 * r.raw_error,
                               100 * r.normalized_error, B))
            cells.append(f"{r.recall:.2f}/{r.precision:.2f} {100 * r.raw_error:5.2f} "
                         f"{100 * r.normalized_error:5.2f} {B:2d}")
        print(f"{name:<24} " + " | ".join(cells) + f"  ({time.perf_counter() - t0:.0f} s)",
              flush=True)
    if not rows[RUNGS[0]]:
        return 0
    arr, ok = summary(rows, "rung")
    for k, v in arr.items():
        print(f"{k:<15} recall {v[:, 0].mean():.3f} precision {v[:, 1].mean():.3f} "
              f"raw {v[ok, 2].mean():.2f} cm normalised {v[ok, 3].mean():.2f} cm "
              f"bones {v[:, 4].mean():.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
