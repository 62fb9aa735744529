"""Step 3 benchmark: kernel speed vs numpy references, and the accuracy ablation table.

Run: PYTHONPATH=python:tests python benchmarks/bench_joints.py [--frames 100 --points 2000]
Prints (1) Rust kernels vs numpy/scipy references measured in the same run, (2) joint errors
of step 2 (stand-in) vs step-3 variants on the tests' blended LBS figure and on
pointrig.synth "human" (Kinect-like noise; step 2 = rigid fits per GT part, see
tests/joints_helpers.py). Errors in cm; no timed asserts.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from joints_helpers import joint_errors, make_figure, step2_standin, synth_case, synth_scores

from pointrig import _core
from pointrig.config import JointsConfig
from pointrig.joints import e_step, e_step_numpy, learn_joints
from pointrig.kinematics import skin

VARIANTS = [
    ("paper (Table 1, Alg. 2)", dict(mode="paper", joint_tolerance=0.0, gmm_density_normalize=False,
                                     weight_candidates="all", prior_from_weights=False)),
    ("paper w/o E_Register", dict(mode="paper", joint_tolerance=0.0, gmm_density_normalize=False,
                                  weight_candidates="all", prior_from_weights=False, zeta=0.0,
                                  alpha_init=1e4 * 2000)),
    ("paper w/o alpha growth", dict(mode="paper", joint_tolerance=0.0, gmm_density_normalize=False,
                                    weight_candidates="all", prior_from_weights=False,
                                    alpha_growth=1.0)),
    ("ours (default)", dict()),
    ("ours w/o E_Register", dict(zeta=0.0)),
    ("ours w/o E_GMM (y only)", dict(use_gmm=False)),
    ("ours, E_GMM not density-normalised", dict(gmm_density_normalize=False)),
    ("ours, prior c~ (not weight crossing)", dict(prior_from_weights=False)),
    ("ours, weights fixed (step-2 labels)", dict(update_weights=False)),
]


def timeit(fn, reps=3):
    best = np.inf
    for _ in range(reps):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def kernels(F, M, N):
    fig = make_figure("human", n_frames=F, n_points=M, n_obs=N)
    idx = np.ascontiguousarray(np.argsort(-fig.weights, 1)[:, :4], dtype=np.int64)
    w = np.ascontiguousarray(np.take_along_axis(fig.weights, idx, 1))
    B = fig.weights.shape[1]
    Rf = np.ascontiguousarray(fig.R.reshape(F * B, 9))
    Tf = np.ascontiguousarray(fig.T.reshape(F * B, 3))
    a = np.ones((F, M)) * 1e4
    z = np.ascontiguousarray(fig.registered.reshape(-1, 3))
    tau = np.full(F, 2e-4)
    rows = [
        ("skin Eq.13 (F*M)", lambda: _core.lbs_skin(fig.rest_points, idx, w, Rf, Tf, F),
         lambda: skin(fig.rest_points, fig.weights, fig.R, fig.T)),
        ("E-step Eq.4 (all frames)", lambda: e_step(fig.frames, fig.registered, tau, 0.01),
         lambda: e_step_numpy(fig.frames, fig.registered, tau, 0.01)),
    ]
    print(f"\nKernels, F={F} M={M} N={N} B={B} (best of 3, s)")
    print(f"{'kernel':32s} {'rust':>8s} {'numpy':>8s} {'ratio':>7s}")
    for name, fr, fn in rows:
        tr, tn = timeit(fr), timeit(fn)
        print(f"{name:32s} {tr:8.3f} {tn:8.3f} {tn / tr:7.1f}x")
    # kernels without a numpy twin: absolute times
    for name, fr in [
        ("weights Eq.22 (all points)", lambda: _core.lbs_fit_weights(fig.rest_points, Rf, Tf, a, z, F, 4)),
        ("bones Eqs.23-26 sweep", lambda: _core.lbs_sweep_paper(
            fig.rest_points, idx, w, Rf, Tf, a, z, Rf, Tf, fig.bone_parent, fig.joints_rest, 1e7, 0.1, F)),
        ("bones articulated sweep", lambda: _core.lbs_sweep_articulated(
            fig.rest_points, idx, w, Rf, Tf, a, z, Rf, fig.bone_parent, fig.joints_rest, 0.1, F)),
    ]:
        print(f"{name:32s} {timeit(fr):8.3f}")
    # numpy reference of the weight QP for 200 points (scipy SLSQP per point)
    from scipy.optimize import minimize
    H = np.eye(4) + 0.1
    g = np.array([0.1, 0.2, 0.0, -0.1])
    t_s = timeit(lambda: [minimize(lambda x: 0.5 * x @ H @ x - g @ x, np.full(4, .25), method="SLSQP",
                                    bounds=[(0, 1)] * 4, constraints=[{"type": "eq", "fun": lambda x: x.sum() - 1}])
                           for _ in range(200)], 1)
    t_r = timeit(lambda: [_core.simplex_qp(H, g) for _ in range(200)], 1)
    print(f"{'simplex QP x200 (vs SLSQP)':32s} {t_r:8.3f} {t_s:8.3f} {t_s / t_r:7.1f}x")


def ablation_fixture(F):
    fig = make_figure("human", n_frames=F, n_points=2000, n_obs=6000)
    st = step2_standin(fig)
    e = joint_errors(fig, st.joints_rest, st.R, st.T)
    print(f"\nAblation A: blended LBS figure (tests/joints_helpers.py), F={F}, non-root joints, cm")
    print(f"{'variant':40s} {'traj':>6s} {'norm':>6s} {'rest':>6s} {'its':>4s} {'s':>6s}")
    print(f"{'step 2 only (rigid per-part + Eq. 20)':40s} {100*e['traj_mean']:6.2f} {100*e['norm_mean']:6.2f} {100*e['rest_mean']:6.2f}")
    for name, kw in VARIANTS:
        t = time.perf_counter()
        r = learn_joints(fig.frames, fig.rest_points, fig.registered, st, JointsConfig(**kw))
        dt = time.perf_counter() - t
        e = joint_errors(fig, r.joints_rest, r.R, r.T)
        print(f"{name:40s} {100*e['traj_mean']:6.2f} {100*e['norm_mean']:6.2f} {100*e['rest_mean']:6.2f} {r.diagnostics['iterations']:4d} {dt:6.1f}")


def ablation_synth(F, M):
    case = synth_case("human", n_frames=F, n_points=M)
    st = case.structure
    print(f"\nAblation B: pointrig.synth 'human' (Kinect noise), F={F}, M={M}, N~{len(case.frames[0])}; "
          "recall %, errors cm (raw, normalised, direct per-bone)")
    print(f"{'variant':40s} {'recall':>6s} {'raw':>6s} {'norm':>6s} {'direct':>6s} {'its':>4s} {'s':>6s}")
    s = synth_scores(case, st.joints_rest, st.R, st.T)
    print(f"{'step 2 only (rigid per-part + Eq. 20)':40s} {100*s['recall']:6.1f} {100*s['raw']:6.2f} {100*s['norm']:6.2f} {100*s['direct']:6.2f}")
    for name, kw in VARIANTS:
        t = time.perf_counter()
        r = learn_joints(case.frames, case.rest_points, case.registered, st, JointsConfig(**kw))
        dt = time.perf_counter() - t
        s = synth_scores(case, r.joints_rest, r.R, r.T)
        print(f"{name:40s} {100*s['recall']:6.1f} {100*s['raw']:6.2f} {100*s['norm']:6.2f} {100*s['direct']:6.2f} {r.diagnostics['iterations']:4d} {dt:6.1f}")


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--points", type=int, default=2000)
    ap.add_argument("--obs", type=int, default=10000)
    ap.add_argument("--ablation-frames", type=int, default=30)
    args = ap.parse_args()
    kernels(args.frames, args.points, args.obs)
    ablation_fixture(args.ablation_frames)
    ablation_synth(args.ablation_frames, args.points)
