"""Step 2 accuracy suite on every ``pointrig.synth`` figure.

For each figure in :data:`pointrig.synth.FIGURES` and each seed, ``extract_structure`` runs on

* **exact**: the exact surface samples ``syn.surface`` (perfect registration stand-in), rest
  pose = frame 0;
* **degraded**: the same samples re-skinned with LBS weights diffused over the rest surface
  (Gaussian, ``--blend`` x subject size: blending near joints, like an over-smooth
  deformation graph), temporally smoothed (moving average over ``--smooth`` frames) and
  jittered (Gaussian, ``--noise`` x subject size per coordinate, point and frame: 0.00125 is
  ~2.7 mm on the 2.2 m human; ``--noise-abs`` gives metres instead), i.e. what a real
  registration returns. Subject size = diagonal of the rest surface's bounding box.

The step-2 joints (bone heads moved by ``kinematics.joint_trajectories``) are scored with
:func:`pointrig.evaluate.evaluate` (recall, precision, normalised error) and the bone count is
compared with the number of scorable ground-truth joints.

Run:  PYTHONPATH=python python benchmarks/bench_structure_suite.py [--amplitude 1.0]
      [--frames 50] [--seeds 0 1 2] [--figures human hand ...] [--points 2000]
Prints one row per run and the means; no timed asserts.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "python"))

from pointrig.config import StructureConfig  # noqa: E402
from pointrig.evaluate import evaluate  # noqa: E402
from pointrig.kinematics import joint_trajectories  # noqa: E402
from pointrig.structure import extract_structure  # noqa: E402
from pointrig.synth import FIGURES, Camera, NoiseConfig, synthesize  # noqa: E402
from pointrig.synth.camera import KINECT_FX  # noqa: E402

# the depth frames are not used: render at a tiny resolution to save time
_TINY_CAMERA = Camera(KINECT_FX / 10, KINECT_FX / 10, 31.5, 23.5, 64, 48)


def degrade(syn, noise: float, blend: float, smooth: int, seed: int) -> np.ndarray:
    """Registration-like version of ``syn.surface``, ``(F, S, 3)`` metres (see module doc)."""
    from scipy.spatial import cKDTree

    q = syn.rest_surface
    W = np.asarray(syn.surface_weights, np.float64)
    size = float(np.linalg.norm(np.ptp(q, axis=0)))
    sig = blend * size
    if sig > 0:
        tree = cKDTree(q)
        pairs = tree.query_pairs(3.0 * sig, output_type="ndarray")
        d2 = ((q[pairs[:, 0]] - q[pairs[:, 1]]) ** 2).sum(1)
        k = np.exp(-0.5 * d2 / sig ** 2)
        Wd = W.copy()
        np.add.at(Wd, pairs[:, 0], k[:, None] * W[pairs[:, 1]])
        np.add.at(Wd, pairs[:, 1], k[:, None] * W[pairs[:, 0]])
        norm = np.ones(len(q))
        np.add.at(norm, pairs[:, 0], k)
        np.add.at(norm, pairs[:, 1], k)
        W = Wd / norm[:, None]
    R, T = syn.bone_rotations, syn.bone_translations
    Y = np.einsum("sj,fjik,sk->fsi", W, R, q) + np.einsum("sj,fji->fsi", W, T)
    if smooth > 1:
        F = Y.shape[0]
        h = smooth // 2
        pad = np.concatenate([Y[:1].repeat(h, 0), Y, Y[-1:].repeat(h, 0)])
        Y = np.stack([pad[t:t + 2 * h + 1].mean(0) for t in range(F)])
    rng = np.random.default_rng(1000 + seed)
    return Y + noise * rng.normal(size=Y.shape)


def subject_size(syn) -> float:
    """Bounding-box diagonal of the rest surface, metres."""
    return float(np.linalg.norm(np.ptp(syn.rest_surface, axis=0)))


def run_one(Y: np.ndarray, syn, cfg: StructureConfig) -> dict:
    t0 = time.perf_counter()
    r = extract_structure(Y[0], Y, cfg)
    dt = time.perf_counter() - t0
    pj = joint_trajectories(r.joints_rest, r.R, r.T, r.bone_parent)
    rep = evaluate(pj, syn.gt_joints, syn.joint_parents, **syn.eval_kwargs())
    return {"B": r.n_bones, "S": rep.n_scorable, "recall": rep.recall,
            "precision": rep.precision, "nerr": rep.normalized_error / rep.subject_size,
            "time": dt, "missed": [row.name for row in rep.rows
                                   if row.scorable and row.matched < 0]}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--figures", nargs="*", default=list(FIGURES))
    ap.add_argument("--seeds", nargs="*", type=int, default=[0, 1, 2])
    ap.add_argument("--frames", type=int, default=50)
    ap.add_argument("--amplitude", type=float, default=1.0)
    ap.add_argument("--points", type=int, default=2000)
    ap.add_argument("--noise", type=float, default=0.00125, help="fraction of subject size")
    ap.add_argument("--noise-abs", type=float, default=None, help="metres (overrides --noise)")
    ap.add_argument("--blend", type=float, default=0.02)
    ap.add_argument("--smooth", type=int, default=3)
    ap.add_argument("--modes", nargs="*", default=["exact", "degraded"])
    ap.add_argument("--timing", action="store_true",
                    help="only time extract_structure on human, S=2000, F=100 (best of 3)")
    ap.add_argument("--set", nargs="*", default=[], metavar="FIELD=VALUE",
                    help="StructureConfig overrides (ablations)")
    a = ap.parse_args(argv)
    over = {}
    for kv in a.set:
        k, v = kv.split("=", 1)
        kind = type(getattr(StructureConfig(), k))
        over[k] = v if kind is str else kind(float(v) if kind is not bool else v == "true")
    # syn.surface samples both sides of the subject (not one depth view): no single-view depth
    # correction of the joints unless asked for
    cfg = dataclasses.replace(StructureConfig(), **{"single_view": "no", **over})
    if a.timing:
        syn = synthesize("human", n_frames=100, seed=0, camera=_TINY_CAMERA,
                         noise=NoiseConfig.clean(), surface_points=2000)
        Y = np.ascontiguousarray(syn.surface)
        ts = []
        for _ in range(3):
            t0 = time.perf_counter()
            r = extract_structure(Y[0], Y, cfg)
            ts.append(time.perf_counter() - t0)
        print(f"extract_structure human M={Y.shape[1]} F=100: best {min(ts):.3f} s, "
              f"clustering {r.diagnostics['time_clustering_s']:.3f} s, {r.n_bones} bones")
        return 0
    print(f"amplitude {a.amplitude}, F={a.frames}, S~{a.points}, degraded: noise {a.noise} x size "
          f"(abs {a.noise_abs} m), "
          f"blend {a.blend} x size, smooth {a.smooth} frames; overrides {over}")
    print(f"{'figure':<11}{'seed':>4} {'mode':<9}{'B':>4}{'GT':>4}{'recall':>8}{'prec':>7}"
          f"{'nerr%':>7}{'s':>6}  missed")
    rows: dict[str, list[dict]] = {m: [] for m in a.modes}
    for fig in a.figures:
        for seed in a.seeds:
            syn = synthesize(fig, n_frames=a.frames, seed=seed, camera=_TINY_CAMERA,
                             noise=NoiseConfig.clean(), amplitude=a.amplitude,
                             surface_points=a.points)
            for mode in a.modes:
                sigma = a.noise_abs if a.noise_abs is not None else a.noise * subject_size(syn)
                Y = syn.surface if mode == "exact" else degrade(syn, sigma, a.blend, a.smooth,
                                                                 seed)
                d = run_one(np.ascontiguousarray(Y), syn, cfg)
                d["fig"] = fig
                rows[mode].append(d)
                print(f"{fig:<11}{seed:>4} {mode:<9}{d['B']:>4}{d['S']:>4}{d['recall']:>8.3f}"
                      f"{d['precision']:>7.3f}{100 * d['nerr']:>7.2f}{d['time']:>6.2f}  "
                      f"{','.join(d['missed'])}", flush=True)
    print()
    print("| mode | recall | precision | norm. error (% size) | exact bone count | s/run |")
    print("|---|---|---|---|---|---|")
    for mode, rs in rows.items():
        if not rs:
            continue
        rec = np.mean([r["recall"] for r in rs])
        pre = np.mean([r["precision"] for r in rs])
        ne = np.nanmean([r["nerr"] for r in rs])
        ok = sum(r["B"] == r["S"] for r in rs)
        tm = np.mean([r["time"] for r in rs])
        print(f"| {mode} | {rec:.3f} | {pre:.3f} | {100 * ne:.2f} | {ok}/{len(rs)} | {tm:.2f} |")
    print()
    print("per figure (recall / precision, exact ; degraded):")
    for fig in a.figures:
        cells = []
        for mode, rs in rows.items():
            fr = [r for r in rs if r["fig"] == fig]
            if fr:
                cells.append(f"{np.mean([r['recall'] for r in fr]):.3f}/"
                             f"{np.mean([r['precision'] for r in fr]):.3f}")
        print(f"  {fig:<11} " + " ; ".join(cells))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
