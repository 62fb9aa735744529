"""The Rust kernels of steps 2 and 3 against numpy / scipy references, measured in the same run.

On a synthetic human (:func:`pointrig.synth.synthesize`, ``--points`` surface samples moving
with the rig over ``--frames`` frames, the rendered depth frames as observations), prints per
kernel the best of three runs of the Rust kernel and of its reference (seconds), their ratio,
and the largest difference between their results:

* step 2: the Kabsch fits of every cluster in every frame (Eq. 14) and the point-to-cluster
  residual matrix;
* step 3: linear blend skinning (Eq. 13), the truncated E-step of every frame (Eq. 4; the
  reference on scipy k-d trees with enough neighbours to hold every pair within the radius)
  and the weight QP on the simplex (Eq. 22; 200 problems, against scipy's SLSQP).

Run::

    python -m benchmarks.bench_kernels [--frames 100] [--points 2000] [--clusters 30]
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from scipy.optimize import minimize

from pointrig import _core
from pointrig.joints import e_step, e_step_numpy
from pointrig.kinematics import skin
from pointrig.synth import synthesize


def best_of(fn: Callable[[], Any], repeat: int = 3) -> tuple[float, Any]:
    """Fastest of ``repeat`` calls of ``fn`` (seconds) and the last result."""
    best, out = float("inf"), None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def kabsch_numpy(q: np.ndarray, y: np.ndarray, labels: np.ndarray, k: int
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Reference of ``_core.cluster_fit``: per cluster and frame the rigid motion (Kabsch)
    from rest points ``q (M, 3)`` to ``y (F, M, 3)``; ``(F, K, 3, 3)`` and ``(F, K, 3)``."""
    f = y.shape[0]
    rot = np.zeros((f, k, 3, 3))
    tr = np.zeros((f, k, 3))
    for c in range(k):
        sel = labels == c
        cs = q[sel].mean(0)
        yc = y[:, sel]
        cd = yc.mean(1)
        h = np.einsum("mi,fmj->fij", q[sel] - cs, yc - cd[:, None])
        u, _s, vt = np.linalg.svd(h)
        d = np.sign(np.linalg.det(np.einsum("fji,fkj->fik", vt, u)))
        dm = np.zeros((f, 3, 3))
        dm[:, 0, 0] = dm[:, 1, 1] = 1
        dm[:, 2, 2] = d
        rot[:, c] = np.einsum("fji,fjk,flk->fil", vt, dm, u)
        tr[:, c] = cd - np.einsum("fij,j->fi", rot[:, c], cs)
    return rot, tr


def residuals_numpy(q: np.ndarray, y: np.ndarray, rot: np.ndarray, tr: np.ndarray) -> np.ndarray:
    """Reference of ``_core.cluster_residuals`` with every cluster a candidate: ``(M, K)``
    squared distances (m^2) of each point's track ``y (F, M, 3)`` from each cluster's motion
    of its rest point."""
    out = np.zeros((q.shape[0], rot.shape[1]))
    for c in range(rot.shape[1]):
        moved = np.einsum("fij,mj->fmi", rot[:, c], q) + tr[:, c, None]
        out[:, c] = ((y - moved) ** 2).sum((0, 2))
    return out


def slsqp_simplex(h: np.ndarray, g: np.ndarray) -> np.ndarray:
    """Reference of ``_core.simplex_qp``: ``argmin 0.5 w'Hw - g'w`` on the simplex (SLSQP)."""
    k = len(g)
    res = minimize(lambda x: 0.5 * x @ h @ x - g @ x, np.full(k, 1.0 / k), method="SLSQP",
                   bounds=[(0.0, 1.0)] * k,
                   constraints=[{"type": "eq", "fun": lambda x: x.sum() - 1.0}])
    return res.x


def _diff(a: Any, b: Any) -> float:
    """Largest absolute difference between two results (arrays or tuples of arrays)."""
    if isinstance(a, tuple):
        return max(_diff(x, y) for x, y in zip(a, b))
    return float(np.abs(np.asarray(a, np.float64) - np.asarray(b, np.float64)).max())


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--points", type=int, default=2000, help="surface samples M")
    ap.add_argument("--clusters", type=int, default=30, help="step 2's k")
    a = ap.parse_args(argv)
    syn = synthesize("human", a.frames, seed=0, surface_points=a.points)
    q = np.ascontiguousarray(syn.rest_surface)
    y = np.ascontiguousarray(syn.surface)
    f, m = y.shape[:2]
    rng = np.random.default_rng(0)
    k = a.clusters
    labels = rng.integers(0, k, m).astype(np.int64)
    rot, tr, _ = _core.cluster_fit(q, y, labels, k)
    cand = np.tile(np.arange(k, dtype=np.int64), (m, 1))

    w_full = syn.surface_weights
    b = w_full.shape[1]
    idx = np.ascontiguousarray(np.argsort(-w_full, 1)[:, :4], dtype=np.int64)
    w = np.ascontiguousarray(np.take_along_axis(w_full, idx, 1))
    r_flat = np.ascontiguousarray(syn.bone_rotations.reshape(f * b, 9))
    t_flat = np.ascontiguousarray(syn.bone_translations.reshape(f * b, 3))
    tau = np.full(f, 2e-4)

    qp = []
    for _ in range(200):
        a_mat = rng.normal(size=(4, 4))
        qp.append((a_mat @ a_mat.T + 0.1 * np.eye(4), rng.normal(size=4)))

    n_obs = int(np.median([len(x) for x in syn.frames]))
    rows: list[tuple[str, Callable[[], Any], Callable[[], Any]]] = [
        (f"step 2 Kabsch fits (K={k} x F)", lambda: _core.cluster_fit(q, y, labels, k)[:2],
         lambda: kabsch_numpy(q, y, labels, k)),
        (f"step 2 residuals (M x K={k})", lambda: _core.cluster_residuals(q, y, rot, tr, cand),
         lambda: residuals_numpy(q, y, rot, tr)),
        (f"step 3 skinning Eq. 13 (B={b})",
         lambda: _core.lbs_skin(q, idx, w, r_flat, t_flat, f).reshape(f, m, 3),
         lambda: skin(q, w_full, syn.bone_rotations, syn.bone_translations)),
        (f"step 3 E-step Eq. 4 (N~{n_obs})",
         lambda: e_step(syn.frames, y, tau, 0.01).P1,
         lambda: e_step_numpy(syn.frames, y, tau, 0.01, n_neighbors=48).P1),
        ("step 3 weight QP x200 (SLSQP)",
         lambda: np.array([_core.simplex_qp(h, g) for h, g in qp]),
         lambda: np.array([slsqp_simplex(h, g) for h, g in qp])),
    ]
    print(f"human, F={f} M={m} (best of 3, s; ratio = reference / Rust)")
    print(f"{'kernel':34s} {'Rust':>8s} {'reference':>10s} {'ratio':>8s} {'max diff':>9s}")
    for name, rust, ref in rows:
        t_rust, got = best_of(rust)
        t_ref, want = best_of(ref, 1 if "QP" in name else 3)
        print(f"{name:34s} {t_rust:8.3f} {t_ref:10.3f} {t_ref / t_rust:7.1f}x "
              f"{_diff(got, want):9.1e}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
