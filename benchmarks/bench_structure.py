"""Step 2 benchmark: Rust cluster kernels vs a numpy reference, and the k-means feature and
end-to-end ablations on generated articulated sequences (tests/structure_helpers.py).

Run: PYTHONPATH=python:tests python benchmarks/bench_structure.py
Prints tables; no timed asserts.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from pointrig import _core  # noqa: E402
from pointrig.config import StructureConfig  # noqa: E402
from pointrig.structure import extract_structure  # noqa: E402
from structure_helpers import make_sequence, purity, topology_matches  # noqa: E402


def numpy_fit(Q, Y, labels, K):
    F = Y.shape[0]
    R = np.zeros((F, K, 3, 3))
    T = np.zeros((F, K, 3))
    for k in range(K):
        sel = labels == k
        q = Q[sel]
        cs = q.mean(0)
        y = Y[:, sel]
        cd = y.mean(1)
        H = np.einsum("mi,fmj->fij", q - cs, y - cd[:, None])
        U, _S, Vt = np.linalg.svd(H)
        d = np.sign(np.linalg.det(np.einsum("fji,fkj->fik", Vt, U)))
        D = np.zeros((F, 3, 3))
        D[:, 0, 0] = D[:, 1, 1] = 1
        D[:, 2, 2] = d
        R[:, k] = np.einsum("fji,fjk,flk->fil", Vt, D, U)
        T[:, k] = cd - np.einsum("fij,j->fi", R[:, k], cs)
    return R, T


def numpy_residuals(Q, Y, R, T):
    out = np.zeros((Q.shape[0], R.shape[1]))
    for k in range(R.shape[1]):
        out[:, k] = ((Y - np.einsum("fij,mj->fmi", R[:, k], Q) - T[:, k, None]) ** 2).sum((0, 2))
    return out


def best_of(fn, n=3):
    ts = []
    for _ in range(n):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return min(ts)


def kernels(M=2000, F=100, K=30):
    rng = np.random.default_rng(0)
    Q = rng.normal(size=(M, 3))
    Y = np.ascontiguousarray(Q[None] + 0.01 * rng.normal(size=(F, M, 3)))
    lab = rng.integers(0, K, M).astype(np.int64)
    R, T, _ = _core.cluster_fit(Q, Y, lab, K)
    cand = np.tile(np.arange(K, dtype=np.int64), (M, 1))
    rows = [
        ("Kabsch fits K x F", best_of(lambda: _core.cluster_fit(Q, Y, lab, K)),
         best_of(lambda: numpy_fit(Q, Y, lab, K))),
        ("residual matrix M x K", best_of(lambda: _core.cluster_residuals(Q, Y, R, T, cand)),
         best_of(lambda: numpy_residuals(Q, Y, R, T))),
    ]
    print(f"\nkernels, M={M} F={F} K={K} (best of 3)")
    print(f"{'kernel':24s} {'rust ms':>9s} {'numpy ms':>9s} {'speed-up':>9s}")
    for name, tr, tn in rows:
        print(f"{name:24s} {tr * 1e3:9.2f} {tn * 1e3:9.2f} {tn / tr:9.1f}")


def ablations(seeds=(0, 1, 2)):
    print("\nend to end (generated sequences, noise 5 mm, blend 12 cm, 5-frame smoothing)")
    print(f"{'setting':28s} {'kind':10s} {'topology':>8s} {'min purity':>10s} {'bones':>14s} {'s/run':>6s}")
    settings = {
        "default": StructureConfig(),
        "k-means on positions only": StructureConfig(trajectory_weight=0.0),
        "unguarded vote (paper)": StructureConfig(vote_guard_ratio=0.0),
        "no noise discount": StructureConfig(noise_margin=0.0),
        "no band test": StructureConfig(band_ratio=0.0),
    }
    for label, cfg in settings.items():
        for kind in ("humanoid", "arm", "quadruped"):
            ok, pur, nb, tt = 0, [], [], []
            for seed in seeds:
                d = make_sequence(kind, seed=seed, noise=0.005, blend=0.12, smooth_frames=5)
                t = time.perf_counter()
                r = extract_structure(d["rest"], d["points"], cfg)
                tt.append(time.perf_counter() - t)
                ok += topology_matches(r.labels, r.bone_parent, d["labels"], d["figure"])
                pur.append(purity(r.labels, d["labels"]))
                nb.append(r.n_bones)
            print(f"{label:28s} {kind:10s} {ok:>5d}/{len(seeds)} {min(pur):10.3f} "
                  f"{str(nb):>14s} {np.mean(tt):6.2f}")


def end_to_end_time(M=2000, F=100, k=30):
    d = make_sequence("humanoid", n_points=M, n_frames=F, seed=0, noise=0.003, blend=0.06)
    cfg = StructureConfig(n_clusters=k)
    t = best_of(lambda: extract_structure(d["rest"], d["points"], cfg), n=2)
    r = extract_structure(d["rest"], d["points"], cfg)
    print(f"\nextract_structure humanoid M={len(d['rest'])} F={F} k={k}: {t:.2f} s "
          f"(clustering {r.diagnostics['time_clustering_s']:.2f} s), {r.n_bones} bones")


if __name__ == "__main__":
    kernels()
    end_to_end_time()
    ablations()
