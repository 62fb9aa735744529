"""Step 3 (§6): weight QP, bone sweeps, joint solve and the whole EM on synthetic figures."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from joints_helpers import joint_errors, make_figure, step2_standin
from scipy.optimize import minimize

from pointrig import _core
from pointrig.config import JointsConfig
from pointrig.errors import ConfigError, InputError
from pointrig.joints import (
    JointsResult,
    learn_joints,
    solve_joints_articulated,
    subsample_frames,
    track_bones,
)
from pointrig.kinematics import joint_trajectories, skin


def _flat(R, T):
    F, B = R.shape[:2]
    return np.ascontiguousarray(R.reshape(F * B, 9)), np.ascontiguousarray(T.reshape(F * B, 3))


def _sparse(W, k):
    idx = np.argsort(-W, axis=1, kind="stable")[:, :k]
    return np.ascontiguousarray(idx, dtype=np.int64), np.ascontiguousarray(np.take_along_axis(W, idx, 1))


# ------------------------------------------------------------------------- Eq. 22 QP


@pytest.mark.parametrize("k", [1, 2, 3, 4, 6])
def test_simplex_qp_matches_scipy(k):
    rng = np.random.default_rng(k)
    for trial in range(25):
        G = rng.normal(size=(3 * k + trial % 3, k))
        if trial % 5 == 0 and k > 1:
            G[:, -1] = G[:, 0]  # singular H: duplicated bone
        H = G.T @ G
        g = rng.normal(size=k) * (3 if trial % 2 else 0.3)
        w = _core.simplex_qp(np.ascontiguousarray(H), g)
        assert np.all(w >= 0) and abs(w.sum() - 1) < 1e-12
        f = lambda x: 0.5 * x @ H @ x - g @ x  # noqa: E731
        ref = minimize(f, np.full(k, 1 / k), jac=lambda x: H @ x - g, method="SLSQP",
                       bounds=[(0, 1)] * k,
                       constraints=[{"type": "eq", "fun": lambda x: x.sum() - 1}],
                       options={"ftol": 1e-14, "maxiter": 500})
        assert f(w) <= f(ref.x) + 1e-9 * max(1.0, abs(f(ref.x)))
        if np.linalg.eigvalsh(H).min() > 1e-6:  # strictly convex: unique minimiser
            np.testing.assert_allclose(w, ref.x, atol=1e-5)


def test_simplex_qp_rejects_bad_input():
    with pytest.raises(ValueError):
        _core.simplex_qp(np.eye(9), np.zeros(9))  # k > 8
    with pytest.raises(InputError):
        _core.simplex_qp(np.array([[np.nan]]), np.zeros(1))


def test_fit_weights_recovers_blend_weights_on_clean_data():
    fig = make_figure("arm", n_frames=8, n_points=300, obs_noise=0, reg_noise=0, outliers=0)
    F, M = fig.registered.shape[:2]
    Rf, Tf = _flat(fig.R, fig.T)
    X = skin(fig.rest_points, fig.weights, fig.R, fig.T)
    idx, w, res = _core.lbs_fit_weights(fig.rest_points, Rf, Tf, np.ones((F, M)),
                                        np.ascontiguousarray(X.reshape(-1, 3)), F, 4)
    W = np.zeros_like(fig.weights)
    np.add.at(W, (np.repeat(np.arange(M), idx.shape[1]), idx.ravel()), w.ravel())
    assert np.all(w >= 0) and np.allclose(w.sum(1), 1)
    np.testing.assert_allclose(W, fig.weights, atol=1e-5)
    assert res.max() < 1e-10


def test_skin_kernel_matches_numpy():
    fig = make_figure("human", n_frames=4, n_points=400)
    idx, w = _sparse(fig.weights, 4)
    Rf, Tf = _flat(fig.R, fig.T)
    out = _core.lbs_skin(fig.rest_points, idx, w, Rf, Tf, 4).reshape(4, -1, 3)
    np.testing.assert_allclose(out, skin(fig.rest_points, fig.weights, fig.R, fig.T), atol=1e-12)


# ------------------------------------------------------------------ Eqs. 23-26 sweeps


def _surrogate(Q, W, R, T, a, z, R_pre, T_pre, parent, joints, alpha, gamma, trans_small=True):
    X = skin(Q, W, R, T)
    e = 0.5 * np.sum(a * np.sum((X - z) ** 2, axis=2))
    for k, j in enumerate(parent):
        if j >= 0 and alpha > 0:
            c = joints[k]
            d = np.einsum("fij,j->fi", R[:, j] - R[:, k], c) + T[:, j] - T[:, k]
            e += 0.5 * alpha * np.sum(d * d)
    e += 0.5 * gamma * np.sum((R - R_pre) ** 2)
    if trans_small:
        e += 0.5 * gamma * np.sum((T - T_pre) ** 2)
    return e


@pytest.mark.parametrize("mode", ["paper", "articulated", "articulated_smooth"])
def test_bone_sweeps_never_increase_energy(mode):
    fig = make_figure("human", n_frames=5, n_points=600, seed=3)
    st = step2_standin(fig)
    F, M = fig.registered.shape[:2]
    B = len(fig.bone_parent)
    rng = np.random.default_rng(0)
    a = rng.uniform(0.5, 2.0, (F, M)) * 1e4
    z = np.ascontiguousarray(fig.registered)
    idx, w = _sparse(fig.weights, 4)
    R, T = st.R.copy(), st.T.copy()
    R_pre, T_pre = R.copy(), T.copy()
    alpha, gamma = (1e5, 0.1) if mode == "paper" else (0.0, 0.1)
    # the temporal rotation term, one weight per bone, strong enough to matter
    smooth = rng.uniform(0.0, 2.0, B) * 1e3 if mode == "articulated_smooth" else None
    args = (fig.rest_points, fig.weights)

    def energy(R, T):
        e = _surrogate(*args, R, T, a, z, R_pre, T_pre, fig.bone_parent, st.joints_rest, alpha,
                       gamma, mode == "paper")
        if smooth is not None:
            e += 0.5 * np.sum(smooth * np.sum((R[2:] - 2 * R[1:-1] + R[:-2]) ** 2, axis=(2, 3)))
        return e

    prev = energy(R, T)
    for _ in range(4):
        Rf, Tf = _flat(R, T)
        if mode == "paper":
            Rn, Tn = _core.lbs_sweep_paper(fig.rest_points, idx, w, Rf, Tf, a, z.reshape(-1, 3),
                                           *_flat(R_pre, T_pre), fig.bone_parent,
                                           st.joints_rest, alpha, gamma, F)
        else:
            Rn, Tn = _core.lbs_sweep_articulated(fig.rest_points, idx, w, Rf, Tf, a,
                                                 z.reshape(-1, 3), _flat(R_pre, T_pre)[0],
                                                 fig.bone_parent, st.joints_rest, gamma, F,
                                                 smooth)
        R, T = Rn.reshape(R.shape), Tn.reshape(T.shape)
        assert np.allclose(np.einsum("fbij,fbkj->fbik", R, R), np.eye(3), atol=1e-10)
        assert np.all(np.linalg.det(R) > 0)
        e = energy(R, T)
        assert e <= prev * (1 + 1e-10)
        prev = e


def test_temporal_rotation_term_fills_an_occluded_frame_and_checks_its_weights():
    """A bone whose points are unseen in one frame takes the rotation nearest
    ``4 (R_(t-1) + R_(t+1)) - R_(t-2) - R_(t+2)`` (the second differences' minimiser; polar
    factor by numpy's SVD); without the term it keeps its own."""
    fig = make_figure("human", n_frames=6, n_points=600, seed=3)
    st = step2_standin(fig)
    F, M = fig.registered.shape[:2]
    B = len(fig.bone_parent)
    leaf = int(next(k for k in range(B) if k not in set(fig.bone_parent.tolist())))
    a = np.full((F, M), 1e4)
    a[2, fig.weights[:, leaf] > 0] = 0.0  # frame 2 (2 mod 3: updated after its neighbours)
    z = np.ascontiguousarray(fig.registered).reshape(-1, 3)
    idx, w = _sparse(fig.weights, 4)
    Rf, Tf = _flat(st.R, st.T)
    call = (fig.rest_points, idx, w, Rf, Tf, a, z, Rf.copy(), fig.bone_parent, st.joints_rest,
            0.0, F)
    Rn, _ = _core.lbs_sweep_articulated(*call, np.full(B, 1e2))
    R = Rn.reshape(F, B, 3, 3)
    U, _, Vt = np.linalg.svd(4 * (R[1, leaf] + R[3, leaf]) - R[0, leaf] - R[4, leaf])
    assert np.linalg.det(U @ Vt) > 0
    np.testing.assert_allclose(R[2, leaf], U @ Vt, atol=1e-9)
    R0 = _core.lbs_sweep_articulated(*call)[0].reshape(F, B, 3, 3)
    assert np.linalg.norm(R0[2, leaf] - U @ Vt) > 1e-3  # the term made the difference
    for bad in (np.full(B - 1, 1.0), np.full(B, -1.0), np.full(B, np.nan)):
        with pytest.raises((ValueError, InputError)):
            _core.lbs_sweep_articulated(*call, bad)


def test_articulated_joint_solve_is_exact_with_true_weights_and_rotations():
    fig = make_figure("human", n_frames=10, n_points=800, obs_noise=0, reg_noise=0, outliers=0)
    X = skin(fig.rest_points, fig.weights, fig.R, fig.T)
    a = np.ones(X.shape[:2])
    prior = fig.joints_rest + 0.05  # wrong prior with ~zero weight must not matter
    c, T = solve_joints_articulated(fig.rest_points, fig.weights, fig.R, a, X, fig.bone_parent,
                                    prior, 1e-9)
    nr = fig.bone_parent >= 0
    # hinge joints are only determined up to their axis; project the error off the axis
    for k in np.flatnonzero(nr):
        err = c[k] - fig.joints_rest[k]
        A = fig.R[:, fig.bone_parent[k]] - fig.R[:, k]
        assert np.linalg.norm(np.einsum("fij,j->fi", A, err)) < 1e-6
    np.testing.assert_allclose(skin(fig.rest_points, fig.weights, fig.R, T), X, atol=1e-6)


def test_articulated_joint_solve_matches_dense_least_squares():
    # Oracle: the whole objective (per-frame root translations and every joint as unknowns)
    # solved as one dense weighted least-squares problem in numpy, with the prior
    # lambda_e |c_e - c~_e|^2 and lambda_e = prior_weight * mean_t sum_m a ws_me^2.
    fig = make_figure("human", n_frames=4, n_points=300, obs_noise=0, reg_noise=0, outliers=0)
    rng = np.random.default_rng(3)
    F, B = fig.R.shape[:2]
    Q, W, R, parent = fig.rest_points, fig.weights, fig.R, fig.bone_parent
    z = skin(Q, W, R, fig.T) + rng.normal(scale=0.01, size=(F, len(Q), 3))
    a = rng.uniform(0.2, 2.0, size=(F, len(Q)))
    prior = fig.joints_rest + rng.normal(scale=0.03, size=fig.joints_rest.shape)
    c, T = solve_joints_articulated(Q, W, R, a, z, parent, prior, 0.7)
    edges = np.flatnonzero(parent >= 0)
    E = len(edges)
    # subtree indicator written here, not joints._subtree_matrix: the oracle stays independent
    sub = np.zeros((B, B))  # sub[e, b] = 1 if bone b is in the subtree of bone e
    for b in range(B):
        k = b
        while k >= 0:
            sub[k, b] = 1.0
            k = parent[k]
    ws = W @ sub[edges].T  # (M, E)
    s = np.einsum("mb,fbij,mj->fmi", W, R, Q)
    rows, rhs = [], []
    n = 3 * F + 3 * E
    for f in range(F):
        A = R[f, parent[edges]] - R[f, edges]  # (E, 3, 3)
        for m in range(len(Q)):
            blk = np.zeros((3, n))
            blk[:, 3 * f:3 * f + 3] = np.eye(3)
            for e in range(E):
                blk[:, 3 * F + 3 * e:3 * F + 3 * e + 3] = ws[m, e] * A[e]
            sw = np.sqrt(a[f, m])
            rows.append(sw * blk)
            rhs.append(sw * (z[f, m] - s[f, m]))
    lam = 0.7 * np.mean(np.einsum("fm,me->fe", a, ws ** 2), axis=0)
    for e in range(E):
        blk = np.zeros((3, n))
        blk[:, 3 * F + 3 * e:3 * F + 3 * e + 3] = np.sqrt(lam[e]) * np.eye(3)
        rows.append(blk)
        rhs.append(np.sqrt(lam[e]) * prior[edges[e]])
    sol = np.linalg.lstsq(np.vstack(rows), np.concatenate(rhs), rcond=None)[0]
    np.testing.assert_allclose(c[edges], sol[3 * F:].reshape(E, 3), atol=1e-7)
    root = int(np.flatnonzero(parent < 0)[0])
    np.testing.assert_allclose(T[:, root], sol[:3 * F].reshape(F, 3), atol=1e-7)
    # the prior made a difference (the oracle is not just the data term's minimiser)
    c_free, _ = solve_joints_articulated(Q, W, R, a, z, parent, prior, 1e-9)
    assert np.abs(c_free[edges] - c[edges]).max() > 1e-4


# --------------------------------------------------------------------------- the EM


@pytest.mark.parametrize("smoothing", [0.0, 0.01])
def test_noise_free_arm_joints_within_1cm(smoothing):
    fig = make_figure("arm", n_frames=12, n_points=600, n_obs=2000, obs_noise=0, reg_noise=0,
                      outliers=0, seed=1)
    st = step2_standin(fig)
    res = learn_joints(fig.frames, fig.rest_points, fig.registered, st,
                       JointsConfig(rotation_smoothing=smoothing))
    err = np.linalg.norm(res.joints_rest - fig.joints_rest, axis=1)[fig.bone_parent >= 0]
    assert err.max() < 0.01, err
    W = res.weights
    assert np.all(W >= 0) and np.allclose(W.sum(1), 1) and np.all((W > 0).sum(1) <= 4)


def test_step3_beats_step2_on_noisy_blended_figure():
    # An accurate registration (true LBS motion + 3 mm noise): the motion pins the joints, so
    # with a weak joint prior step 3 about halves step 2's error (0.50x). The default prior
    # (joint_prior=1) trades this sub-centimetre refinement for robustness to step-1 sliding.
    # The temporal rotation term is off here: this figure's limbs turn 31-37 deg per frame
    # (15 frames for the whole motion), and with the joints this free the term's pull on
    # their accelerations moves them.
    fig = make_figure("human", n_frames=15, n_points=1000, n_obs=2500, seed=2)
    st = step2_standin(fig)
    before = joint_errors(fig, st.joints_rest, st.R, st.T)
    res = learn_joints(fig.frames, fig.rest_points, fig.registered, st,
                       JointsConfig(joint_prior=0.01, rotation_smoothing=0.0))
    after = joint_errors(fig, res.joints_rest, res.R, res.T)
    assert after["traj_mean"] < 0.55 * before["traj_mean"], (before, after)
    assert after["traj_mean"] < 0.015
    assert res.R.shape == st.R.shape and res.tau.shape == (15,) and len(res.energy) >= 1
    assert np.all(res.tau > 0)


def test_rotation_term_costs_little_on_fast_limbs_with_the_default_prior():
    """The same fast figure with the default joint prior: the temporal rotation term (default
    0.01) keeps the joint error within 5 % of the run without it and takes out the spin."""
    fig = make_figure("human", n_frames=15, n_points=1000, n_obs=2500, seed=2)
    st = step2_standin(fig)
    runs = {v: learn_joints(fig.frames, fig.rest_points, fig.registered, st,
                            JointsConfig(rotation_smoothing=v)) for v in (0.0, 0.01)}
    err = {v: joint_errors(fig, r.joints_rest, r.R, r.T)["traj_mean"] for v, r in runs.items()}
    assert err[0.01] < 1.05 * err[0.0], err
    rel = np.einsum("fbji,fbjk->fbik", runs[0.01].R[:-1], runs[0.01].R[1:])
    turn = np.degrees(np.arccos(np.clip((np.trace(rel, axis1=2, axis2=3) - 1) / 2, -1, 1)))
    rel0 = np.einsum("fbji,fbjk->fbik", runs[0.0].R[:-1], runs[0.0].R[1:])
    turn0 = np.degrees(np.arccos(np.clip((np.trace(rel0, axis1=2, axis2=3) - 1) / 2, -1, 1)))
    assert turn.max() < 0.5 * turn0.max(), (turn.max(), turn0.max())


def test_paper_mode_runs_and_respects_constraints(tmp_path):
    fig = make_figure("arm", n_frames=6, n_points=300, n_obs=800, seed=4)
    st = step2_standin(fig)
    cfg = JointsConfig(mode="paper", max_iterations=4, joint_tolerance=0.0)
    res = learn_joints(fig.frames, fig.rest_points, fig.registered, st, cfg)
    assert res.diagnostics["alpha"][1] == pytest.approx(1.45 * 1e4 * 300)
    W = res.weights
    assert np.all(W >= 0) and np.allclose(W.sum(1), 1) and np.all((W > 0).sum(1) <= 4)
    res.save(tmp_path / "j.npz")
    back = JointsResult.load(tmp_path / "j.npz")
    np.testing.assert_array_equal(back.joints_rest, res.joints_rest)
    assert back.joints().shape == (6, 3, 3)


def test_input_errors():
    fig = make_figure("arm", n_frames=3, n_points=200, n_obs=300)
    st = step2_standin(fig)
    with pytest.raises(InputError):
        learn_joints(fig.frames[:2], fig.rest_points, fig.registered, st)
    with pytest.raises(InputError):
        learn_joints(fig.frames, fig.rest_points[:-1], fig.registered, st)
    with pytest.raises(ConfigError):
        learn_joints(fig.frames, fig.rest_points, fig.registered, st, JointsConfig(mode="x"))


def test_estep_kernel_matches_numpy_reference():
    from pointrig.joints import e_step, e_step_numpy

    fig = make_figure("human", n_frames=2, n_points=500, n_obs=1500)
    tau = np.array([6e-4, 2e-4])
    # untruncated on both sides: the Rust kernel may fall back to its dense loop when the
    # window is wide (see rust/core/gmm.rs), so only the dense semantics are comparable here;
    # the truncated kernel's error bound is tested in tests/test_gmm_estep.py
    a = e_step(fig.frames, fig.registered, tau, 0.01, 1e6)
    b = e_step_numpy(fig.frames, fig.registered, tau, 0.01, 500, 1e6)
    np.testing.assert_allclose(a.P1, b.P1, atol=1e-10)
    np.testing.assert_allclose(a.PX, b.PX, atol=1e-10)
    np.testing.assert_allclose(a.Np, b.Np, rtol=1e-10)


def test_batched_estep_matches_per_frame_kernel_and_single_precision():
    from pointrig.joints import e_step

    fig = make_figure("human", n_frames=3, n_points=400, n_obs=900)
    tau = np.array([6e-4, 3e-4, 1e-4])
    got = e_step(fig.frames, fig.registered, tau, 0.01, radius_sigmas=3.5)
    for t in range(3):
        p1, _, px, stats = _core.gmm_estep(fig.registered[t], fig.frames[t], tau[t], 0.01, 3.5)
        np.testing.assert_allclose(got.P1[t], p1, atol=1e-12)
        np.testing.assert_allclose(got.PX[t], px, atol=1e-12)
        assert got.Np[t] == pytest.approx(stats["n_p"], rel=1e-12)
        assert got.sxx[t] == pytest.approx(stats["sum_x2"], rel=1e-12)
    single = e_step(fig.frames, fig.registered, tau, 0.01, radius_sigmas=3.5, single=True)
    np.testing.assert_allclose(single.P1, got.P1, atol=1e-4)
    np.testing.assert_allclose(single.PX, got.PX, atol=1e-4)


def test_batched_estep_with_normals_matches_a_numpy_von_mises_fisher_mixture():
    """``e_step(..., normals=(XN, VN, kappa))`` (the tracker's E-step with normal agreement)
    against a dense numpy mixture: Gaussian x normalised vMF per component, uniform position
    x uniform direction for the outlier term."""
    from pointrig.joints import e_step, pack_frames

    rng = np.random.default_rng(3)
    fig = make_figure("human", n_frames=2, n_points=300, n_obs=700)
    unit = lambda a: a / np.linalg.norm(a, axis=-1, keepdims=True)  # noqa: E731
    XN = unit(rng.normal(size=fig.registered.shape))
    V, offsets = pack_frames(fig.frames)
    VN = unit(rng.normal(size=V.shape))
    tau, omega, kappa = np.array([6e-4, 2e-4]), 0.05, 1.5
    got = e_step(fig.frames, fig.registered, tau, omega, radius_sigmas=None,
                 normals=(XN, VN, kappa))
    for t in range(2):
        x, xn = fig.registered[t], XN[t]
        v, vn = V[offsets[t]:offsets[t + 1]], VN[offsets[t]:offsets[t + 1]]
        m, n = len(x), len(v)
        d2 = ((x[:, None] - v[None]) ** 2).sum(-1)
        vmf = kappa / (2 * np.pi * (1 - np.exp(-2 * kappa)))
        dens = (1 - omega) / m * np.exp(-d2 / (2 * tau[t])) / (2 * np.pi * tau[t]) ** 1.5 \
            * vmf * np.exp(kappa * (xn @ vn.T - 1))
        p = dens / (dens.sum(0) + omega / n / (4 * np.pi))
        np.testing.assert_allclose(got.P1[t], p.sum(1), rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(got.PX[t], p @ v, rtol=1e-9, atol=1e-12)
        assert got.Np[t] == pytest.approx(p.sum(), rel=1e-10)
    plain = e_step(fig.frames, fig.registered, tau, omega, radius_sigmas=None)
    assert np.abs(plain.P1 - got.P1).max() > 1e-3  # the factor matters
    with pytest.raises(ValueError, match="normals"):
        e_step(fig.frames, fig.registered, tau, omega, normals=(XN, VN[:-1], kappa))


def test_joint_normal_sums_match_numpy():
    rng = np.random.default_rng(3)
    F, M, E = 4, 50, 5
    ws = rng.random((M, E)) * (rng.random((M, E)) > 0.5)
    a = rng.random((F, M))
    a[1, :10] = 0.0
    r = rng.normal(size=(F * M, 3))
    S0, d0, S1, S2, d1 = _core.lbs_joint_normal_sums(ws, a, r)
    r3 = r.reshape(F, M, 3)
    np.testing.assert_allclose(S0, a.sum(1), rtol=1e-12)
    np.testing.assert_allclose(d0, np.einsum("fm,fmi->fi", a, r3), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(S1, a @ ws, rtol=1e-12)
    np.testing.assert_allclose(S2.reshape(F, E, E), np.einsum("fm,me,mg->feg", a, ws, ws),
                               rtol=1e-12)
    np.testing.assert_allclose(d1.reshape(F, E, 3), np.einsum("fm,me,fmi->fei", a, ws, r3),
                               rtol=1e-12, atol=1e-12)
    with pytest.raises(ValueError):
        _core.lbs_joint_normal_sums(ws, a[:, :-1], r)


def test_subsample_frames_is_even_and_bounded():
    from pointrig.joints import subsample_frames

    v = np.arange(30, dtype=float).reshape(10, 3)
    out = subsample_frames([v, v[:3]], 4)
    assert out[0].shape == (4, 3) and out[1].shape == (3, 3)
    np.testing.assert_array_equal(out[0][:, 0], [0.0, 6.0, 15.0, 21.0])  # rows 0, 2, 5, 7
    assert subsample_frames([v], 0)[0] is v


def test_final_weights_blend_without_moving_the_joints(monkeypatch):
    """With ``update_weights = False`` the EM keeps step 2's one-hot weights and one Eq. 22 fit
    after the loop gives the output's blend weights: 4-sparse, blended near the joints, and
    nothing else changes. Oracle: the same run with that fit replaced by the one-hot labels
    has the same joints and transforms."""
    import pointrig.joints as joints_mod
    from pointrig import _core

    fig = make_figure("arm", n_frames=10, n_points=500, n_obs=1500, seed=4)
    st = step2_standin(fig)
    cfg = JointsConfig(update_weights=False, max_iterations=4)
    a = learn_joints(fig.frames, fig.rest_points, fig.registered, st, cfg)

    class OneHot:
        def __getattr__(self, name):
            return getattr(_core, name)

        @staticmethod
        def lbs_fit_weights(*args):
            labels = np.asarray(st.labels, dtype=np.int64)
            return labels[:, None], np.ones((len(labels), 1)), None

    monkeypatch.setattr(joints_mod, "_core", OneHot())
    b = learn_joints(fig.frames, fig.rest_points, fig.registered, st, cfg)
    np.testing.assert_array_equal(a.joints_rest, b.joints_rest)
    np.testing.assert_array_equal(a.R, b.R)
    hard = np.zeros_like(b.weights)
    hard[np.arange(len(st.labels)), st.labels] = 1.0
    np.testing.assert_array_equal(b.weights, hard)
    W = a.weights
    assert np.all(W >= 0) and np.allclose(W.sum(1), 1) and np.all((W > 0).sum(1) <= 4)
    blended = (W > 1e-3).sum(1) > 1
    assert blended.mean() > 0.05  # the synthetic figure is blended near its joints


# --------------------------------------------------------------------------- tracking start


def _lost(st, F):
    """A step 1 that lost the figure: every frame keeps frame 0's bone transforms."""
    return dataclasses.replace(st, R=np.repeat(st.R[:1], F, axis=0),
                               T=np.repeat(st.T[:1], F, axis=0))


def test_tracking_recovers_the_motion_step1_lost():
    # oracle: the figure's forward kinematics. Step 2's transforms say nothing moves after
    # frame 0; tracked against the raw single-view frames, the joints follow the truth again
    fig = make_figure("arm", n_frames=15, n_points=1000, n_obs=3000, seed=3)
    lost = _lost(step2_standin(fig), 15)
    before = joint_errors(fig, lost.joints_rest, lost.R, lost.T)
    R, T = track_bones(subsample_frames(fig.frames, 4000), fig.rest_points, lost, 0,
                       JointsConfig())
    after = joint_errors(fig, lost.joints_rest, R, T)
    assert before["traj_mean"] > 0.1
    assert after["traj_mean"] < 0.02, (before, after)
    # the result keeps the joints: every bone meets its parent at its (fixed) joint
    for k in np.flatnonzero(lost.bone_parent >= 0):
        p, c = lost.bone_parent[k], lost.joints_rest[k]
        gap = np.einsum("fij,j->fi", R[:, p] - R[:, k], c) + T[:, p] - T[:, k]
        assert np.abs(gap).max() < 1e-9


@pytest.mark.parametrize("kind", ["arm", "human"])
def test_tracking_keeps_an_accurate_registration(kind):
    # step 2 from the true motion (+3 mm noise): the second hypothesis (step 2's own pose of
    # each frame) keeps it where the prediction alone drifts
    fig = make_figure(kind, n_frames=15, n_points=1000, n_obs=3000, seed=3)
    st = step2_standin(fig)
    before = joint_errors(fig, st.joints_rest, st.R, st.T)["traj_mean"]
    R, T = track_bones(subsample_frames(fig.frames, 4000), fig.rest_points, st, 0,
                       JointsConfig())
    after = joint_errors(fig, st.joints_rest, R, T)["traj_mean"]
    assert after < 1.2 * before + 0.001, (before, after)


def test_tracking_holds_the_pose_after_a_jump():
    """The arm holds frame 0's pose for three frames, jumps to frame 8's (joints up to 39 cm
    away) and holds that. Step 2's poses say nothing moves, so only the tracker's own start
    can follow. On the frame after the jump the constant-velocity prediction repeats the
    jump; ``track_predict_check`` starts from the previous pose instead. Oracle: the figure's
    forward kinematics."""
    fig = make_figure("arm", n_frames=15, n_points=1000, n_obs=3000, seed=3)
    order = [0, 0, 0, 8, 8, 8, 8, 8]
    jump = dataclasses.replace(fig, R=fig.R[order], T=fig.T[order],
                               registered=fig.registered[order],
                               frames=[fig.frames[i] for i in order])
    st = _lost(step2_standin(jump), len(order))
    err = {}
    for check in (1.0, 0.0):
        R, T = track_bones(jump.frames, jump.rest_points, st, 0,
                           JointsConfig(track_predict_check=check))
        traj = joint_trajectories(st.joints_rest, R, T, jump.bone_parent)
        err[check] = np.linalg.norm(traj - jump.joints_gt, axis=2).mean(1)
    assert err[1.0][4] < 0.03, err[1.0]
    assert err[0.0][4] > 2.0 * err[1.0][4], err  # the failure the check removes
    assert err[1.0].max() < 0.035, err[1.0]


def _track_frame_numpy(Q, labels, parent, joints, v, R, t_root, cfg, tau0, tau_max, floor,
                       normals=None):
    """The tracker's per-frame EM written with numpy around the E-step and sweep kernels (the
    reference of ``_core.lbs_track_frame``): scipy's k-d tree for the starting ``tau``, the
    chain translations and root shift in numpy."""
    from scipy.spatial import cKDTree

    from pointrig.joints import _topo_order, e_step

    M, B = len(Q), len(parent)
    order = _topo_order(parent)
    idx, w = np.ascontiguousarray(labels[:, None]), np.ones((M, 1))

    def pose(Rt, shift, a=None, z=None):
        T0 = np.zeros((B, 3))
        for k in order:
            if parent[k] >= 0:
                T0[k] = T0[parent[k]] + (Rt[parent[k]] - Rt[k]) @ joints[k]
        X0 = np.einsum("mij,mj->mi", Rt[labels], Q) + T0[labels]
        if a is not None and a.sum() > 0:
            shift = (a[:, None] * (z - X0)).sum(0) / a.sum()
        return T0 + shift, X0 + shift

    root = int(np.flatnonzero(parent < 0)[0])
    T, X = pose(R, np.asarray(t_root))
    tau = float(np.clip(4 / 3 * np.mean(cKDTree(v).query(X)[0] ** 2), tau0, tau_max))
    an = cfg.track_anneal
    k_coarse = int(np.ceil(np.log(tau / tau0) / np.log(1 / an))) if tau > tau0 else 0
    for it in range(cfg.track_iterations):
        nrm = None
        if normals is not None:
            nrm = (np.einsum("mab,mb->ma", R[labels], normals[0])[None], normals[1],
                   cfg.track_normal_kappa)
        es = e_step([v], X[None], np.array([tau]), cfg.omega, cfg.estep_radius_sigmas, True,
                    normals=nrm)
        a = es.P1[0] / tau * (M / len(v))
        z = np.where((a > 0)[:, None], es.PX[0] / np.maximum(es.P1[0], 1e-300)[:, None], X)
        R_pre = _flat(R[None], T[None])[0]
        for _ in range(cfg.track_sweeps):
            Rf, Tf = _flat(R[None], T[None])
            Rn, _ = _core.lbs_sweep_articulated(Q, idx, w, Rf, Tf,
                                                np.ascontiguousarray(a[None]),
                                                np.ascontiguousarray(z), R_pre, parent, joints,
                                                cfg.gamma, 1)
            R = Rn.reshape(B, 3, 3)
            T, X = pose(R, T[root], a, z)
        ss = float(es.sxx[0] - 2 * np.sum(es.PX[0] * X) + np.sum(es.P1[0][:, None] * X * X))
        eq12 = max(ss / (3 * float(es.Np[0])), floor)
        tau = min(eq12, max(an * tau, tau0)) if it < k_coarse else eq12
    return R, T, X


@pytest.mark.parametrize("with_normals,sweeps", [(False, 1), (True, 1), (True, 3)])
def test_track_frame_matches_the_numpy_loop(with_normals, sweeps):
    """``_core.lbs_track_frame`` (one frame of the tracker in Rust) against the same EM written
    in numpy around the E-step and sweep kernels, from a start 10 degrees off on every bone."""
    from scipy.spatial.transform import Rotation

    from pointrig.geometry import estimate_normals

    fig = make_figure("human", n_frames=6, n_points=1200, n_obs=3000, seed=4)
    st = step2_standin(fig)
    cfg = JointsConfig(track_sweeps=sweeps)
    rng = np.random.default_rng(1)
    R0 = np.einsum("bij,bjk->bik", Rotation.from_rotvec(
        rng.normal(size=(len(st.bone_parent), 3)) * np.radians(10) / np.sqrt(3)).as_matrix(),
        st.R[5])
    v = np.ascontiguousarray(fig.frames[5], dtype=float)
    Q, labels = np.ascontiguousarray(fig.rest_points), st.labels.astype(np.int64)
    parent, joints = st.bone_parent.astype(np.int64), np.ascontiguousarray(st.joints_rest)
    tau0, tau_max, floor = 6e-4, 0.01, 1e-6
    normals = None
    extra = ()
    if with_normals:
        vn = np.ascontiguousarray(estimate_normals(v, 0.03))
        normals = (np.ascontiguousarray(fig.normals), vn)
        extra = (normals[0], vn, cfg.track_normal_kappa)
    want = _track_frame_numpy(Q, labels, parent, joints, v, R0, st.T[5, st.root], cfg, tau0,
                              tau_max, floor, normals)
    got = _core.lbs_track_frame(
        Q, labels, parent, joints, v, np.ascontiguousarray(R0.reshape(-1, 9)),
        tuple(st.T[5, st.root]), cfg.track_iterations, tau0, tau_max, floor, cfg.track_anneal,
        cfg.omega, cfg.estep_radius_sigmas, cfg.gamma, len(Q) / len(v), *extra,
        sweeps=cfg.track_sweeps)
    # the E-step's float32 distances turn last-bit differences of the rotated normals (numpy's
    # einsum against Rust's sum) into ~1e-7 ones
    np.testing.assert_allclose(got[0].reshape(-1, 3, 3), want[0], atol=1e-6)
    np.testing.assert_allclose(got[1], want[1], atol=1e-6)
    np.testing.assert_allclose(got[2], want[2], atol=1e-6)
    # the fit moved: the start is 10 degrees off on every bone
    assert np.abs(got[0].reshape(-1, 3, 3) - R0).max() > 0.01
    with pytest.raises(InputError):
        _core.lbs_track_frame(Q, labels + 100, parent, joints, v,
                              np.ascontiguousarray(R0.reshape(-1, 9)), (0.0, 0.0, 0.0), 3,
                              tau0, tau_max, floor, 0.5, 0.01, 3.5, 0.1, 1.0)


def test_tracking_config_errors():
    fig = make_figure("arm", n_frames=3, n_points=200, n_obs=300)
    st = step2_standin(fig)
    for bad in (dict(init="x"), dict(track_iterations=0), dict(track_anneal=0.0),
                dict(track_tau_max=0.0), dict(track_velocity=-1.0),
                dict(track_predict_check=1.5), dict(track_normal_kappa=-1.0),
                dict(normal_radius=0.0), dict(rotation_smoothing=-0.1),
                dict(max_iterations=-1), dict(max_iterations=2.5)):
        (name,) = bad
        with pytest.raises(ConfigError, match=rf"\[joints\] {name} must be"):
            JointsConfig(**bad)
    with pytest.raises(InputError):
        learn_joints(fig.frames, fig.rest_points, fig.registered, st, rest_index=3)


def test_zero_iterations_return_the_tracked_step2_skeleton():
    """``max_iterations = 0``: no EM, step 2's joints and one-hot weights under the tracked
    motions. Oracle: the tracker called on its own."""
    fig = make_figure("arm", n_frames=6, n_points=300, n_obs=600, seed=1)
    st = step2_standin(fig)
    cfg = JointsConfig(max_iterations=0, track_normal_kappa=0.0)  # the tracker alone
    res = learn_joints(fig.frames, fig.rest_points, fig.registered, st, cfg, rest_index=0)
    R, T = track_bones(subsample_frames(fig.frames, cfg.estep_max_points), fig.rest_points, st,
                       0, cfg)
    np.testing.assert_allclose(res.R, R, atol=1e-12)
    np.testing.assert_allclose(res.T, T, atol=1e-12)
    np.testing.assert_array_equal(res.joints_rest, st.joints_rest)
    np.testing.assert_array_equal(np.argmax(res.weights, axis=1), st.labels)
    assert res.energy == [] and res.diagnostics["iterations"] == 0


def test_tracking_reports_progress_per_frame():
    """The tracking pass reports every frame once, in order, ending at (F, F); learn_joints
    passes its own callback on, and the result does not depend on whether one is given."""
    fig = make_figure("arm", n_frames=6, n_points=200, n_obs=300)
    st = step2_standin(fig)
    calls: list[tuple[int, int]] = []
    R, T = track_bones(subsample_frames(fig.frames, 4000), fig.rest_points, st, 2,
                       JointsConfig(), progress=lambda d, n: calls.append((d, n)))
    assert calls == [(k, 6) for k in range(1, 7)]
    R0, T0 = track_bones(subsample_frames(fig.frames, 4000), fig.rest_points, st, 2,
                         JointsConfig())
    np.testing.assert_array_equal(R, R0)
    np.testing.assert_array_equal(T, T0)
    seen: list[tuple[int, int]] = []
    learn_joints(fig.frames, fig.rest_points, fig.registered, st,
                 JointsConfig(max_iterations=1), track_progress=lambda d, n: seen.append((d, n)))
    assert seen[-1] == (6, 6) and len(seen) == 6
