"""Can a per-joint test remove the extra joints (#5's precision)? Matched vs unmatched joints.

For each sequence (the figures of ``bench_structure_real.py``; registrations cached in
``--cache``) the default pipeline runs steps 2 and 3, the output is scored, and every
predicted non-root joint (child bone ``c``, parent bone ``p``) gets two statistics, both as a
fraction of the subject size:

* **oracle articulation**: with the exact surface motion of the rest points (nearest
  ground-truth sample in the rest frame), the largest over frames of the RMS residual of
  ``c``'s points after one rigid fit (Eq. 14) of ``p`` and ``c`` together, i.e. how much the
  two bones *really* move against each other. No test on estimated motion can beat this one.
* **data support**: with step 3's bone motions and the raw frames, the 90th percentile over
  frames of ``sqrt(max(d_merged^2 - d_split^2, 0))``, where ``d`` is the RMS distance from the
  observed points nearest ``c`` to the template (truncated at 5 % of the size), split as step
  3 has it or with ``p`` and ``c`` merged into one rigid bone refitted to the frame (ICP, from
  either bone's pose): how much worse the frame is explained without the joint.

Prints per sequence and overall the AUC of matched (scored) vs unmatched joints, and the
fraction of each class below a few thresholds. AUC 0.5 = no separation; above 0.5 = matched
joints articulate more (a threshold would remove extra joints first)::

    PYTHONPATH=python python benchmarks/bench_joint_support.py --cache /tmp/reg40 \
        human upper_body hand girl snake quadruped girl_run_s05
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "python"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_registration_downstream import FIGURES, score_joints  # noqa: E402
from bench_structure_real import _load  # noqa: E402

from pointrig.config import PipelineConfig  # noqa: E402
from pointrig.joints import learn_joints, subsample_frames  # noqa: E402
from pointrig.kinematics import tree_order  # noqa: E402
from pointrig.pipeline import build_skeleton  # noqa: E402
from pointrig.structure import extract_structure, fit_bones  # noqa: E402


def _rigid(q: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Kabsch (Eq. 14) of one frame, ``q (n, 3)`` -> ``y (n, 3)``: ``R (3, 3)``, ``T (3,)``."""
    R, T, _ = fit_bones(np.ascontiguousarray(q), np.ascontiguousarray(y[None]),
                        np.zeros(len(q), np.int64), 1)
    return R[0, 0], T[0, 0]


def oracle_articulation(Q: np.ndarray, Yt: np.ndarray, labels: np.ndarray, c: int, p: int
                        ) -> float:
    """Largest over frames of the RMS residual (m) of bone ``c``'s points after one rigid fit of
    bones ``p`` and ``c`` to their exact trajectories ``Yt (F, M, 3)``."""
    sel = (labels == c) | (labels == p)
    own = labels[sel] == c
    R, T, _ = fit_bones(Q[sel], np.ascontiguousarray(Yt[:, sel]),
                        np.zeros(int(sel.sum()), np.int64), 1)
    res = Yt[:, sel] - (np.einsum("fij,nj->fni", R[:, 0], Q[sel]) + T[:, 0, None])
    return float(np.sqrt((res[:, own] ** 2).sum(2).mean(1)).max())


def data_support(obs: list[np.ndarray], Q: np.ndarray, labels: np.ndarray, parent: np.ndarray,
                 R: np.ndarray, T: np.ndarray, trunc: float, n_frames: int = 20,
                 icp_iterations: int = 8, min_points: int = 10) -> np.ndarray:
    """``(B,)`` data support (m) of every non-root joint (NaN at the root or if unseen)."""
    F, B = len(obs), len(parent)
    frames = np.unique(np.linspace(0, F - 1, min(n_frames, F)).round().astype(int))
    E = np.full((len(frames), B), np.nan)
    for i, t in enumerate(frames):
        v = obs[t]
        X = np.einsum("mij,mj->mi", R[t, labels], Q) + T[t, labels]
        d, nn = cKDTree(X).query(v)
        assign = np.where(d < trunc, labels[nn], -1)
        for c in range(B):
            p = parent[c]
            if p < 0 or (assign == c).sum() < min_points:
                continue
            v_c, v_pc = v[assign == c], v[(assign == c) | (assign == p)]
            q_pc = Q[(labels == c) | (labels == p)]
            best = None
            for s in (p, c):
                Rm, Tm = R[t, s], T[t, s]
                for _ in range(icp_iterations):
                    dd, j = cKDTree(q_pc @ Rm.T + Tm).query(v_pc)
                    inl = dd < trunc
                    if inl.sum() < 3:
                        break
                    Rm, Tm = _rigid(q_pc[j[inl]], v_pc[inl])
                tree = cKDTree(q_pc @ Rm.T + Tm)
                total = np.mean(np.minimum(tree.query(v_pc)[0], trunc) ** 2)
                if best is None or total < best[0]:
                    best = (total, tree)
            assert best is not None
            d_merged = np.minimum(best[1].query(v_c)[0], trunc)
            d_split = np.minimum(d[assign == c], trunc)
            E[i, c] = np.sqrt(max(np.mean(d_merged ** 2) - np.mean(d_split ** 2), 0.0))
    out = np.full(B, np.nan)
    seen = np.isfinite(E).any(0)
    out[seen] = np.nanquantile(E[:, seen], 0.9, axis=0)
    return out


def auc(pos: list[float], neg: list[float]) -> float:
    """P(a matched joint's statistic > an unmatched one's), ties count one half."""
    p, n = np.asarray(pos, float), np.asarray(neg, float)
    if len(p) == 0 or len(n) == 0:
        return float("nan")
    return float(np.mean([(x > n).mean() + 0.5 * (x == n).mean() for x in p]))


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("names", nargs="*", help="sequences (default: the 9 base figures)")
    ap.add_argument("--cache", type=Path, default=None, help="directory for registrations")
    ap.add_argument("--frames", type=int, default=40)
    a = ap.parse_args(argv)
    base = {Path(f).stem: f for f in FIGURES}
    names = a.names or list(base)
    cfg = PipelineConfig()
    stats: dict[str, list[list[float]]] = {"oracle": [[], []], "data": [[], []]}
    print(f"{'sequence':<16} {'prec':>5} {'joints':>6} {'AUC oracle':>10} {'AUC data':>9}")
    for name in names:
        d = _load(base.get(name, name), a.frames, a.cache, {})
        if not d:
            print(f"{name:<16} (missing)")
            continue
        syn, Q, Y = d["syn"], d["rest"], d["pts"]
        frames = syn.to_point_sequence().frames
        st = extract_structure(Q, np.ascontiguousarray(Y), cfg.structure)
        jr = learn_joints(frames, Q, Y, st, cfg.joints)
        sk = build_skeleton(Q, st.bone_parent, jr.joints_rest, jr.R, jr.T, jr.weights, None)
        rep = score_joints(sk.joint_positions, syn)
        order = tree_order(st.bone_parent)
        matched = {int(order[row.matched]) for row in rep.rows if row.matched >= 0}
        size = rep.subject_size
        rest = int(np.argmin(((Y - Q[None]) ** 2).sum(axis=(1, 2))))
        Yt = syn.surface[:, cKDTree(syn.surface[rest]).query(Q)[1]]
        obs = subsample_frames([np.asarray(f) for f in frames], cfg.joints.estep_max_points)
        sup = data_support(obs, Q, st.labels, st.bone_parent, jr.R, jr.T, 0.05 * size)
        local: dict[str, list[list[float]]] = {"oracle": [[], []], "data": [[], []]}
        for c, p in enumerate(st.bone_parent):
            if p < 0:
                continue
            k = 0 if c in matched else 1
            local["oracle"][k].append(oracle_articulation(Q, Yt, st.labels, c, int(p)) / size)
            local["data"][k].append(0.0 if not np.isfinite(sup[c]) else sup[c] / size)
        for key in stats:
            for k in (0, 1):
                stats[key][k] += local[key][k]
        print(f"{name:<16} {rep.precision:5.2f} {len(st.bone_parent) - 1:6d} "
              f"{auc(*local['oracle']):10.3f} {auc(*local['data']):9.3f}", flush=True)
    n_m, n_u = len(stats["oracle"][0]), len(stats["oracle"][1])
    print(f"\nall: {n_m} matched, {n_u} unmatched joints; AUC oracle "
          f"{auc(*stats['oracle']):.3f}, data {auc(*stats['data']):.3f}")
    print(f"{'threshold (% of size)':<22} {'oracle: matched / unmatched below':>34} "
          f"{'data: matched / unmatched below':>32}")
    for thr in (0.005, 0.01, 0.015, 0.02):
        o = [float(np.mean(np.asarray(x) < thr)) for x in stats["oracle"]]
        g = [float(np.mean(np.asarray(x) < thr)) for x in stats["data"]]
        print(f"{100 * thr:<22.1f} {o[0]:>22.2f} / {o[1]:.2f} {g[0]:>20.2f} / {g[1]:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
