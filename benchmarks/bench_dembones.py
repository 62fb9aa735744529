"""Step 3 (joint learning, §6) against Dem Bones (Le and Deng's smooth skinning decomposition,
the ``py-dem-bones`` package) on the same registered points, in the same run.

Step 1 registers a synthetic sequence and step 2 finds its bones; both methods then get the
same rest points ``(M, 3)`` and registered points ``(F, M, 3)``: step 3 (``learn_joints``, also
given the observed frames it fits) and Dem Bones with as many bones as step 2 found and the
same number of bones per point, its mesh edges the ``k``-nearest-neighbour pairs of the rest
points (given to it as two-vertex faces). Printed per method: wall and CPU seconds, and the
reconstruction error of its skinned rest points (the linear blend of its weights and bone
transforms) against the registered points and against the observed points (the distance of
each skinned point to its frame's nearest observed point), mean over frames and points, cm.
Step 3 keeps its bones rigid and joined at joints and fits the observed frames; Dem Bones fits
the registered points with free rigid bones and no skeleton.

Dem Bones is an optional benchmark dependency (``pip install 'pointrig[bench]'`` or ``pip
install py-dem-bones``); without it the benchmark says so and stops::

    python -m benchmarks.bench_dembones [--frames 100] [--only human] [--neighbours 8]
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from benchmarks.sets import add_sequence_options, chosen, suite
from pointrig.config import PipelineConfig
from pointrig.joints import learn_joints
from pointrig.registration import register_sequence
from pointrig.structure import extract_structure

MISSING = ("py-dem-bones is not installed (pip install 'pointrig[bench]' or "
           "pip install py-dem-bones): the Dem Bones comparison is skipped")


def knn_pairs(points: np.ndarray, k: int) -> np.ndarray:
    """``(E, 2)`` undirected pairs ``i < j`` of each point of ``points (M, 3)`` with its ``k``
    nearest other points, each pair once, sorted."""
    k = min(k, len(points) - 1)
    _, nb = cKDTree(points).query(points, k=k + 1)
    i = np.repeat(np.arange(len(points)), k)
    j = nb[:, 1:].reshape(-1)
    pairs = np.sort(np.stack([i, j], axis=1), axis=1)
    return np.unique(pairs[pairs[:, 0] != pairs[:, 1]], axis=0)


def blend(rest: np.ndarray, weights: np.ndarray, R: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Linear blend skinning: ``(F, M, 3)`` positions ``sum_b w_mb (R_fb q_m + T_fb)`` of the
    rest points ``q = rest (M, 3)`` with ``weights (M, B)``, ``R (F, B, 3, 3)``, ``T (F, B, 3)``
    (metres)."""
    out = np.zeros((len(R), len(rest), 3))
    for f in range(len(R)):
        moved = np.einsum("bij,mj->bmi", R[f], rest) + T[f][:, None]  # (B, M, 3)
        out[f] = np.einsum("mb,bmi->mi", weights, moved)
    return out


def dem_bones_transforms(m: np.ndarray, n_frames: int, n_bones: int
                         ) -> tuple[np.ndarray, np.ndarray]:
    """Dem Bones' bone transforms ``m`` (``(4 F, 4 B)``: frame f, bone b is the column-vector
    affine block ``m[4f:4f+4, 4b:4b+4]``) as ``R (F, B, 3, 3)`` and ``T (F, B, 3)``."""
    blocks = np.asarray(m, dtype=np.float64).reshape(n_frames, 4, n_bones, 4).transpose(0, 2, 1, 3)
    return blocks[:, :, :3, :3].copy(), blocks[:, :, :3, 3].copy()


def run_dem_bones(rest: np.ndarray, points: np.ndarray, n_bones: int, nnz: int,
                  pairs: np.ndarray, iterations: int = 30) -> dict[str, Any]:
    """Dem Bones on the rest points ``(M, 3)`` and their registered positions ``(F, M, 3)``
    with ``n_bones`` bones, ``nnz`` bones per point and the mesh edges ``pairs (E, 2)`` as
    two-vertex faces: its ``weights (M, B)``, ``R``, ``T``, ``rmse`` (its own figure), and
    the wall and CPU seconds of its ``compute``."""
    from py_dem_bones._py_dem_bones import DemBones

    f, m = points.shape[:2]
    db = DemBones()
    db.nV, db.nF, db.nS, db.nB = m, f, 1, int(n_bones)
    db.nnz = int(min(nnz, n_bones))
    db.nIters = int(iterations)
    db.fStart = np.array([0, f], dtype=np.int32)
    db.subjectID = np.zeros(f, dtype=np.int32)
    db.u = np.ascontiguousarray(rest.T)  # (3, M): the rest pose, one column a point
    db.v = np.ascontiguousarray(points.transpose(0, 2, 1).reshape(3 * f, m))  # (3F, M)
    db.fv = [[int(a), int(b)] for a, b in pairs]
    w0, c0 = time.perf_counter(), time.process_time()
    db.compute()
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    weights = np.asarray(db.get_weights(), dtype=np.float64)  # (B', M)
    b = weights.shape[0]  # Dem Bones may end with fewer bones than asked for
    R, T = dem_bones_transforms(db.m, f, b)
    return {"weights": weights.T.copy(), "R": R, "T": T, "rmse": float(db.rmse()),
            "wall": wall, "cpu": cpu}


def errors(rest: np.ndarray, weights: np.ndarray, R: np.ndarray, T: np.ndarray,
           points: np.ndarray, frames: list[np.ndarray]) -> tuple[float, float]:
    """Mean distance (metres) of the skinned rest points to the registered ``points (F, M,
    3)``, and to their frame's nearest observed point (``frames[t]``: ``(N_t, 3)``)."""
    x = blend(rest, weights, R, T)
    to_registered = float(np.linalg.norm(x - points, axis=2).mean())
    to_observed = float(np.mean([cKDTree(v).query(y)[0].mean()
                                 for y, v in zip(x, frames) if len(v)]))
    return to_registered, to_observed


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_sequence_options(ap, only="human")
    ap.add_argument("--neighbours", type=int, default=8,
                    help="nearest neighbours per rest point as Dem Bones' mesh edges")
    ap.add_argument("--iterations", type=int, default=30, help="Dem Bones' iterations")
    a = ap.parse_args(argv)
    try:
        import py_dem_bones  # noqa: F401
    except ImportError:
        print(MISSING)
        return 0
    sequences, only = chosen(ap, a)
    cfg = PipelineConfig()
    print(f"{'sequence':<14}{'method':<12}{'bones':>6}{'wall s':>9}{'CPU s':>9}"
          f"{'to registered cm':>18}{'to observed cm':>16}")
    for name, syn in suite(a.frames, only, sequences):
        seq = syn.to_point_sequence()
        frames = list(seq.frames)
        reg = register_sequence(seq, cfg.registration)
        st = extract_structure(reg.rest_points, reg.points, cfg.structure)
        rest_index = int(reg.params["rest_frame_index"])
        w0, c0 = time.perf_counter(), time.process_time()
        jr = learn_joints(frames, reg.rest_points, reg.points, st, cfg.joints,
                          rest_index=rest_index)
        wall3, cpu3 = time.perf_counter() - w0, time.process_time() - c0
        e3 = errors(reg.rest_points, jr.weights, jr.R, jr.T, reg.points, frames)
        b = len(st.bone_parent)
        db = run_dem_bones(reg.rest_points, reg.points, b, cfg.joints.max_bones_per_point,
                           knn_pairs(reg.rest_points, a.neighbours), a.iterations)
        ed = errors(reg.rest_points, db["weights"], db["R"], db["T"], reg.points, frames)
        for method, nb, wall, cpu, e in (
                ("step 3", b, wall3, cpu3, e3),
                ("Dem Bones", db["weights"].shape[1], db["wall"], db["cpu"], ed)):
            print(f"{name:<14}{method:<12}{nb:>6}{wall:9.2f}{cpu:9.2f}"
                  f"{100 * e[0]:18.2f}{100 * e[1]:16.2f}", flush=True)
        print(f"{name:<14}{'ratio':<12}{'':>6}{wall3 / max(db['wall'], 1e-9):8.2f}x"
              f"{cpu3 / max(db['cpu'], 1e-9):8.2f}x{e3[0] / max(ed[0], 1e-12):17.2f}x"
              f"{e3[1] / max(ed[1], 1e-12):15.2f}x   (step 3 / Dem Bones; Dem Bones' own "
              f"RMSE {100 * db['rmse']:.2f} cm)", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
