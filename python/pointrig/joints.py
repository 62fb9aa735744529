"""Step 3: LBS-based skeleton joint learning (paper §6, Eqs. 13, 16-26, Algorithm 2).

EM over the LBS model (Eq. 13) with the deformed rest points ``x_m^t`` as GMM centroids for
the observed points ``v_i^t`` of each frame (Eq. 16):

* E-step: truncated posteriors of Eq. 4 per frame (near neighbours only), kept as sufficient
  statistics ``P1 (F, M)``, ``PX (F, M, 3)`` (:func:`e_step`).
* Reduction: ``E_GMM + zeta/2 E_Register`` equals ``sum a/2 |x - z|^2 + const`` with
  ``a = P1 / tau + zeta`` and ``z = (PX / tau + zeta y) / a`` (docs/joints.md), so every M-step
  update is a weighted least-squares problem in ``x_m^t``.
* M-step: point weights (Eq. 22, exact 4-bone simplex QP, Rust); bone rotations and
  translations (Eqs. 23-26, Rust, parallel over frames); joint positions (Eq. 20);
  covariances ``tau^t`` (Eq. 12 form); deformed points (Eq. 13).

Start (``JointsConfig.init``): ``"track"`` (default, our deviation) fits step 2's skeleton to
the raw frames one by one, outwards from the rest frame (:func:`track_bones`), so that the EM
does not start from step 1's slides and lost limbs; ``"structure"`` starts from step 2's bone
motions as the paper does.

Two variants (``JointsConfig.mode``):

``"paper"``
    Algorithm 2 as printed: the soft joint term ``alpha/2 E_Joint`` with ``alpha = zeta M``
    growing by 1.45 per iteration, per-bone updates of Eqs. 23-26 and joints from Eq. 20.
``"articulated"`` (default, our deviation)
    The joint term taken to its limit ``alpha -> inf``: bones always meet at their joints.
    Rotations are updated bone by bone about the bone's head joint, carrying the subtree along,
    and the joint positions are solved *jointly with the translations* from the data
    (a linear least-squares problem), plus the ``eta |c - c~|^2`` prior. With the paper's
    alternation, the growing alpha makes every bone rotate about the previous joint, so Eq. 20
    returns that joint again and the joints barely move (docs/joints.md).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from . import _core
from .config import JointsConfig, pool_size
from .errors import InputError
from .geometry import (
    chamfer_misfit,
    estimate_normals,
    mean_spacing,
)
from .kinematics import joint_trajectories, solve_joint_positions

__all__ = [
    "JointsResult",
    "StructureLike",
    "e_step",
    "e_step_numpy",
    "learn_joints",
    "posed_rest_points",
    "solve_joints_articulated",
    "track_bones",
]

log = logging.getLogger(__name__)
#: subject size (rest bounding-box diagonal, m) the paper's tau_init = 6e-4 m^2 refers to
_REFERENCE_SIZE = 1.8


class StructureLike(Protocol):
    """What step 3 needs from step 2 (``pointrig.structure.StructureResult``)."""

    labels: np.ndarray  # (M,) int in [0, B)
    bone_parent: np.ndarray  # (B,) int, -1 at the root
    R: np.ndarray  # (F, B, 3, 3) T_frame_rest rotations
    T: np.ndarray  # (F, B, 3) translations, metres
    joints_rest: np.ndarray  # (B, 3) head joints, metres
    c_tilde: np.ndarray  # (B, 3) boundary centroids (root: its centre), metres
    root: int


@dataclass
class JointsResult:
    """Output of step 3.

    Attributes
    ----------
    weights
        ``(M, B)`` LBS weights: non-negative, rows sum to 1, at most
        ``max_bones_per_point`` non-zeros per row (Eq. 21b).
    R, T
        ``(F, B, 3, 3)``, ``(F, B, 3)`` bone transforms (T_frame_rest: ``x = R q + T``).
    joints_rest
        ``(B, 3)`` rest-pose joints (joint b = head of bone b), metres.
    tau
        ``(F,)`` GMM variances ``tau^t``, m^2.
    energy
        ``E_Total`` (Eq. 21a) after each iteration.
    bone_parent
        ``(B,)`` bone tree (copied from step 2).
    diagnostics
        Per-iteration terms, joint shifts, alpha, timings.
    """

    weights: np.ndarray
    R: np.ndarray
    T: np.ndarray
    joints_rest: np.ndarray
    tau: np.ndarray
    energy: list[float]
    bone_parent: np.ndarray
    root: int = 0
    diagnostics: dict[str, Any] = field(default_factory=dict)

    def joints(self) -> np.ndarray:
        """``(F, B, 3)`` joint trajectories, metres."""
        return joint_trajectories(self.joints_rest, self.R, self.T, self.bone_parent)

    def save(self, path: str | Path) -> None:
        """Write to ``.npz`` (diagnostics with array-like values only)."""
        from .io import write_npz

        diag = {f"diag_{k}": np.asarray(v) for k, v in self.diagnostics.items()
                if isinstance(v, (list, tuple, np.ndarray, float, int))}
        write_npz(
            path,
            weights=self.weights, R=self.R, T=self.T, joints_rest=self.joints_rest,
            tau=self.tau, energy=np.asarray(self.energy), bone_parent=self.bone_parent,
            root=np.asarray(self.root), **diag,
        )

    @classmethod
    def load(cls, path: str | Path) -> JointsResult:
        with np.load(path) as z:
            diag = {k[5:]: z[k] for k in z.files if k.startswith("diag_")}
            return cls(
                weights=z["weights"], R=z["R"], T=z["T"], joints_rest=z["joints_rest"],
                tau=z["tau"], energy=[float(v) for v in z["energy"]],
                bone_parent=z["bone_parent"], root=int(z["root"]), diagnostics=diag,
            )


# ----------------------------------------------------------------------------- E-step


@dataclass
class EStats:
    """Sufficient statistics of the E-step of one EM iteration, all frames."""

    P1: np.ndarray  # (F, M) sum_i p_mi
    PX: np.ndarray  # (F, M, 3) sum_i p_mi v_i
    Np: np.ndarray  # (F,) sum_mi p_mi
    sxx: np.ndarray  # (F,) sum_i (sum_m p_mi) |v_i|^2


def e_step(
    frames: Sequence[np.ndarray],
    X: np.ndarray,
    tau: np.ndarray,
    omega: float,
    radius_sigmas: float | None = 3.5,
    single: bool = False,
    *,
    packed: tuple[np.ndarray, np.ndarray] | None = None,
    normals: tuple[np.ndarray, np.ndarray, float] | None = None,
) -> EStats:
    """Posteriors of Eq. 4 (form of §6.2) of every frame in one Rust call
    (``_core.lbs_estep_frames``: parallel over frames, each truncated at
    ``radius_sigmas * sqrt(tau^t)``; ``None`` = dense; ``single`` = float32 distances and
    exponentials with float64 sums, as step 3 runs it).

    Shapes: ``frames`` F arrays ``(N_t, 3)``; ``X (F, M, 3)``; ``tau (F,)`` m^2.
    ``packed`` = ``(V, offsets)`` from :func:`pack_frames` (skips the concatenation).
    ``normals`` = ``(XN (F, M, 3), VN (sum N_t, 3), kappa)``: unit normals of the centroids and
    of the packed observed points; each pair is weighed by ``exp(kappa (n . n~ - 1))``.
    """
    F, M, _ = X.shape
    V, offsets = packed if packed is not None else pack_frames(frames)
    xn = vn = None
    kappa = 0.0
    if normals is not None:
        xn = np.ascontiguousarray(normals[0].reshape(F * M, 3), dtype=np.float64)
        vn = np.ascontiguousarray(normals[1], dtype=np.float64)
        kappa = float(normals[2])
    P1, PX, Np, sxx = _core.lbs_estep_frames(
        np.ascontiguousarray(X.reshape(F * M, 3)), V, offsets,
        np.ascontiguousarray(tau, dtype=np.float64), float(omega),
        None if radius_sigmas is None else float(radius_sigmas), bool(single),
        xn, vn, kappa)
    return EStats(P1.reshape(F, M), PX.reshape(F, M, 3), Np, sxx)


def pack_frames(frames: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Concatenate ``F`` frames ``(N_t, 3)`` into ``V (sum N_t, 3)`` and ``offsets (F+1,)``."""
    offsets = np.zeros(len(frames) + 1, dtype=np.int64)
    offsets[1:] = np.cumsum([len(v) for v in frames])
    V = np.ascontiguousarray(np.concatenate(frames, axis=0), dtype=np.float64)
    return V, offsets


def subsample_frames(frames: Sequence[np.ndarray], max_points: int) -> list[np.ndarray]:
    """Deterministic even subsampling: every frame keeps at most ``max_points`` of its points
    (a fixed stride through the frame's order, so the sensor's spatial coverage is kept).
    ``max_points <= 0`` keeps everything."""
    if max_points <= 0:
        return list(frames)
    out = []
    for v in frames:
        n = len(v)
        if n <= max_points:
            out.append(v)
        else:
            sel = np.floor(np.arange(max_points) * (n / max_points)).astype(np.int64)
            out.append(np.ascontiguousarray(v[sel]))
    return out


def e_step_numpy(
    frames: Sequence[np.ndarray],
    X: np.ndarray,
    tau: np.ndarray,
    omega: float,
    n_neighbors: int = 8,
    radius_sigmas: float = 3.5,
) -> EStats:
    """Posteriors of Eq. 4 (form of §6.2) between deformed points ``X`` and each frame.

    Truncated: each observed point only sees its ``n_neighbors`` nearest deformed points within
    ``radius_sigmas * sqrt(tau^t)``; the outlier term ``(2 pi tau)^{3/2} omega M / ((1-omega) N)``
    is exact. Numpy/scipy reference of :func:`e_step` (k nearest only), one frame after the
    other.

    Parameters
    ----------
    frames
        ``F`` arrays ``(N_t, 3)`` of observed points, metres.
    X
        ``(F, M, 3)`` deformed rest points ``x_m^t``.
    tau
        ``(F,)`` variances, m^2.
    """
    F, M, _ = X.shape
    P1 = np.zeros((F, M))
    PX = np.zeros((F, M, 3))
    Np = np.zeros(F)
    sxx = np.zeros(F)
    k = min(n_neighbors, M)

    def one(t: int) -> None:
        V = frames[t]
        N = len(V)
        from scipy.spatial import cKDTree  # lazy: keeps `import pointrig` light

        tree = cKDTree(X[t])
        r = radius_sigmas * np.sqrt(tau[t])
        d, idx = tree.query(V, k=k, distance_upper_bound=r)
        if k == 1:
            d, idx = d[:, None], idx[:, None]
        ok = np.isfinite(d)
        g = np.exp(-0.5 * np.where(ok, d * d, np.inf) / tau[t])
        c = (2 * np.pi * tau[t]) ** 1.5 * omega * M / ((1 - omega) * N)
        p = g / (g.sum(1, keepdims=True) + c)
        flat = np.where(ok, idx, 0).ravel()
        pf = p.ravel()
        P1[t] = np.bincount(flat, pf, minlength=M)
        for a in range(3):
            PX[t, :, a] = np.bincount(flat, (p * V[:, a:a + 1]).ravel(), minlength=M)
        pt1 = p.sum(1)
        Np[t] = pt1.sum()
        sxx[t] = float(pt1 @ np.einsum("ij,ij->i", V, V))

    for t in range(F):
        one(t)
    return EStats(P1, PX, Np, sxx)


def _gmm_energy(st: EStats, X: np.ndarray, tau: np.ndarray) -> tuple[float, np.ndarray]:
    """Eq. 18 and the per-frame weighted squared residual sum_im p |v - x|^2."""
    ss = st.sxx - 2 * np.einsum("fmi,fmi->f", X, st.PX) + np.einsum("fm,fmi,fmi->f", st.P1, X, X)
    ss = np.maximum(ss, 0.0)
    e = float(np.sum(ss / (2 * tau) + 1.5 * st.Np * np.log(tau)))
    return e, ss


# ------------------------------------------------------------------------ joint solves


def _subtree_matrix(parent: np.ndarray) -> np.ndarray:
    """``S (B, B)`` with ``S[a, j] = 1`` when bone j is in the subtree of bone a."""
    B = len(parent)
    S = np.zeros((B, B))
    for j in range(B):
        a = j
        while a >= 0:
            S[a, j] = 1.0
            a = parent[a]
    return S


def _topo_order(parent: np.ndarray) -> list[int]:
    B = len(parent)
    children: list[list[int]] = [[] for _ in range(B)]
    roots = []
    for j, p in enumerate(parent):
        (roots if p < 0 else children[p]).append(j)
    order, stack = [], list(roots)
    while stack:
        j = stack.pop()
        order.append(j)
        stack.extend(children[j])
    return order


def chain_translations(R: np.ndarray, T_root: np.ndarray, joints: np.ndarray, parent: np.ndarray) -> np.ndarray:
    """Translations of every bone from the root's and the joints (bones meet at joints):
    ``T_k = T_p + (R_p - R_k) c_k``. Returns ``(F, B, 3)``."""
    F, B = R.shape[:2]
    T = np.zeros((F, B, 3))
    for k in _topo_order(parent):
        p = parent[k]
        if p < 0:
            T[:, k] = T_root[:, k] if T_root.ndim == 3 else T_root
        else:
            T[:, k] = T[:, p] + np.einsum("fij,j->fi", R[:, p] - R[:, k], joints[k])
    return T


def solve_joints_articulated(
    Q: np.ndarray,
    W: np.ndarray,
    R: np.ndarray,
    a: np.ndarray,
    z: np.ndarray,
    parent: np.ndarray,
    c_prior: np.ndarray,
    prior_weight: float,
    root_translation: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Joint positions and translations that minimise the reduced data term for fixed R, W.

    With bones meeting at their joints, ``T_b = T_root + sum_{e on path(b)} (R_p(e) - R_e) c_e``
    so ``x_m^t = s_m^t + T_root^t + sum_e ws_me A_e^t c_e`` with ``s = sum_b w_mb R_b q_m``,
    ``ws_me = sum_{b in subtree(e)} w_mb`` and ``A_e = R_p(e) - R_e``: a linear least-squares
    problem in ``(T_root^t, c_e)``. ``T_root^t`` is eliminated frame by frame (Schur
    complement) and the ``3(B-1)`` normal equations are solved with the prior
    ``lambda_e |c_e - c~_e|^2``, ``lambda_e = prior_weight * mean_t sum_m a ws_me^2``
    (docs/joints.md).

    Returns
    -------
    joints
        ``(B, 3)`` joints (the root's entry is ``c_prior[root]``).
    T
        ``(F, B, 3)`` chain-consistent translations.
    """
    F, B = R.shape[:2]
    M = Q.shape[0]
    edges = np.flatnonzero(parent >= 0)
    root = int(np.flatnonzero(parent < 0)[0])
    joints = np.array(c_prior, dtype=float, copy=True)
    S = _subtree_matrix(parent)
    # s (F, M, 3) = LBS with zero translations
    idx, w = _dense_to_sparse(W, int(max(1, (W > 0).sum(1).max())))
    Rf = np.ascontiguousarray(R.reshape(F * B, 9))
    s = _core.lbs_skin(Q, idx, w, Rf, np.zeros((F * B, 3)), F).reshape(F, -1, 3)
    r0 = np.ascontiguousarray((z - s).reshape(F * M, 3))
    a = np.ascontiguousarray(a, dtype=np.float64)
    if edges.size == 0:
        S0 = a.sum(1)
        S0s = np.where(S0 > 0, S0, 1.0)
        T_root = np.einsum("fm,fmi->fi", a, r0.reshape(F, M, 3)) / S0s[:, None]
        return joints, np.broadcast_to(T_root[:, None], (F, B, 3)).copy()
    ws = np.ascontiguousarray(W @ S[edges].T)  # (M, E)
    E = len(edges)
    # per-frame sums over points (Rust, parallel over frames, sparse in ws)
    S0, d0, S1, S2, d1 = _core.lbs_joint_normal_sums(ws, a, r0)
    S2, d1 = S2.reshape(F, E, E), d1.reshape(F, E, 3)
    S0s = np.where(S0 > 0, S0, 1.0)
    K = S2 - S1[:, :, None] * S1[:, None, :] / S0s[:, None, None]
    A = R[:, parent[edges]] - R[:, edges]  # (F, E, 3, 3)
    # H[(e, i), (g, k)] = sum_t K[t, e, g] (A_e^T A_g)[i, k]: the blocks of every frame as one
    # batched product of the (3, 3E) matrices [A_1 ... A_E], weighted by K and summed
    At = A.transpose(0, 2, 1, 3).reshape(F, 3, 3 * E)
    H = np.einsum("tab,tab->ab", np.repeat(np.repeat(K, 3, axis=1), 3, axis=2),
                  np.matmul(At.transpose(0, 2, 1), At))
    rhs_v = d1 - S1[:, :, None] * (d0 / S0s[:, None])[:, None, :]
    rhs = np.einsum("teji,tej->ei", A, rhs_v)
    lam = prior_weight * S2[:, np.arange(E), np.arange(E)].mean(0)  # (E,)
    lam = np.maximum(lam, 1e-12 * max(1.0, float(np.abs(H).max())))
    H[np.arange(3 * E), np.arange(3 * E)] += np.repeat(lam, 3)
    rhs = rhs + lam[:, None] * c_prior[edges]
    sol = np.linalg.solve(H, rhs.reshape(-1)).reshape(E, 3)
    joints[edges] = sol
    T_root = (d0 - np.einsum("fe,feij,ej->fi", S1, A, sol)) / S0s[:, None]
    if root_translation is not None:
        T_root = np.where((S0 > 0)[:, None], T_root, root_translation)
    T = chain_translations(R, T_root, joints, parent)
    del root
    return joints, T


def _size_scale2(Q: np.ndarray) -> float:
    """``(size / 1.8 m)^2`` with ``size`` the bounding-box diagonal of ``Q (M, 3)`` (1 if 0)."""
    size = float(np.linalg.norm(Q.max(0) - Q.min(0)))
    return (size / _REFERENCE_SIZE) ** 2 if size > 0 else 1.0


def _tau_start(Q: np.ndarray, cfg: JointsConfig) -> float:
    """The starting ``tau`` (m^2): ``tau_init``, scaled by :func:`_size_scale2` when
    ``tau_init_relative``, at least ``tau_min``."""
    scale = _size_scale2(Q) if cfg.tau_init_relative else 1.0
    return max(cfg.tau_init * scale, cfg.tau_min)


# -------------------------------------------------------------------------- tracking


def _fixed_joint_translations(
    R: np.ndarray, T_root: np.ndarray, joints: np.ndarray, parent: np.ndarray,
    skin_one: Callable[[np.ndarray, np.ndarray], np.ndarray],
    a: np.ndarray | None = None, z: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """One frame's chain translations ``(B, 3)`` with the joints held, and its skinned points.

    Every bone meets its parent at its joint (:func:`chain_translations`); the root
    translation is ``T_root (3,)``, or with weights ``a (M,)`` and targets ``z (M, 3)`` the
    weighted mean offset ``sum_m a_m (z_m - x0_m) / sum_m a_m`` of the targets from the points
    ``x0`` skinned with zero root translation (a rigid shift of the whole chain).
    ``skin_one(R, T)`` returns the ``(M, 3)`` skinned points of one frame.
    """
    T0 = chain_translations(R[None], np.zeros((1, 3)), joints, parent)[0]
    X0 = skin_one(R, T0)
    if a is None or z is None or not float(a.sum()) > 0:
        shift = T_root
    else:
        shift = (a[:, None] * (z - X0)).sum(0) / float(a.sum())
    return T0 + shift, X0 + shift


def _predict_rigid(R1: np.ndarray, T1: np.ndarray, R0: np.ndarray, T0: np.ndarray,
                   gain: float) -> tuple[np.ndarray, np.ndarray]:
    """Constant-velocity prediction per bone ``(B, 3, 3)``, ``(B, 3)``: the last step
    ``S = (R1, T1) o (R0, T0)^-1`` (``R_s = R1 R0^T``, ``T_s = T1 - R_s T0``) applied once more,
    ``S o (R1, T1)``. ``gain`` scales the step's rotation vector and translation (exact for 1;
    0 = no prediction, the last frame's transforms)."""
    if gain <= 0:
        return R1.copy(), T1.copy()
    from scipy.spatial.transform import Rotation

    Rs = np.einsum("bij,bkj->bik", R1, R0)
    Ts = T1 - np.einsum("bij,bj->bi", Rs, T0)
    if gain != 1.0:
        Rs = Rotation.from_rotvec(Rotation.from_matrix(Rs).as_rotvec() * gain).as_matrix()
        Ts = Ts * gain
    return np.einsum("bij,bjk->bik", Rs, R1), np.einsum("bij,bj->bi", Rs, T1) + Ts


def _fit_and_score(fit_frame: Callable[..., tuple[np.ndarray, np.ndarray, np.ndarray]],
                   v: np.ndarray, vn: np.ndarray | None, trunc: float | None,
                   start: tuple[np.ndarray, np.ndarray]
                   ) -> tuple[float, np.ndarray, np.ndarray]:
    """One tracking hypothesis of a frame: ``fit_frame`` from ``start`` (``(B, 3, 3)``,
    ``(B, 3)``), and the fit's truncated chamfer misfit to the frame ``v`` ``(N, 3)`` (metres;
    0 when ``trunc`` is None: a single hypothesis needs no score). Returns ``(misfit, R, T)``."""
    Rt, Tt, X = fit_frame(v, start[0], start[1], vn)
    return (0.0 if trunc is None else chamfer_misfit(X, v, trunc)), Rt, Tt


def track_bones(
    obs: Sequence[np.ndarray],
    rest_points: np.ndarray,
    structure: StructureLike,
    rest_index: int,
    config: JointsConfig,
    progress: Callable[[int, int], None] | None = None,
    normals: tuple[np.ndarray, Sequence[np.ndarray]] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Track step 2's skeleton through the observed frames (the ``init="track"`` start of
    step 3).

    Step 2's bone motions are Kabsch fits to step 1's registered points, so they carry the
    registration's sliding along limbs and its lost fast limbs. Here the bones (step 2's
    labels as one-hot weights, step 2's joints held fixed) are fitted to the raw points of
    each frame in turn, outwards from the rest frame, each frame starting from the
    constant-velocity prediction of its neighbours: EM (in Rust, ``_core.lbs_track_frame``)
    with the posteriors of Eq. 4 (no E_Register), then ``track_sweeps`` rounds of
    joint-constrained bone rotations (the articulated sweep of Eqs. 23-26) each followed by
    the root translation, ``tau`` from ``4/3`` of the mean squared nearest-point distance of
    the prediction (capped at ``track_tau_max``, m^2 at 1.8 m, scaled by size^2) annealed by
    ``track_anneal`` to ``tau_init``, then Eq. 12. Each frame is also fitted from step 2's own
    pose of it, and the fit with the smaller symmetric chamfer
    misfit to the frame (template to data plus data to template, each distance truncated at
    ``3 sqrt(track_tau_max)``) is kept: the prediction recovers what step 1 lost, step 2's pose
    keeps what step 1 got right (a rigid-bone prediction drifts on smoothly bending bodies).
    The prediction itself gives way to the previous frame's pose when that pose's misfit is
    below ``track_predict_check`` times the prediction's (after a jump the prediction repeats
    it). A frame's two fits run side by side on ``config.workers`` threads (the same result as
    one after the other).
    Frames without points keep the prediction.

    Parameters
    ----------
    obs
        ``F`` observed point clouds ``(N_t, 3)``, metres.
    rest_points
        ``(M, 3)`` rest points, metres.
    structure
        Step 2's result (labels, bone tree, joints, per-frame transforms).
    rest_index
        Frame whose bone transforms are the rest pose's start (``0 <= rest_index < F``).
    config
        Step 3's parameters (E-step, ``gamma``, ``track_*``).
    progress
        Called as ``progress(frames_done, F)`` after each frame.
    normals
        ``(rest normals (M, 3), F observed normals (N_t, 3))``, unit: with
        ``config.track_normal_kappa > 0`` the E-step weighs pairs by normal agreement, each
        rest normal turned by its bone.

    Returns
    -------
    R, T
        ``(F, B, 3, 3)`` and ``(F, B, 3)``: ``T_frame_rest`` of every bone per frame, metres.
    """
    # C-contiguous float64 / int64: the native calls' layout
    Q = np.ascontiguousarray(rest_points, dtype=float)
    F, M = len(obs), Q.shape[0]
    parent = np.ascontiguousarray(structure.bone_parent, dtype=np.int64)
    B = len(parent)
    root = int(np.flatnonzero(parent < 0)[0])
    labels = np.ascontiguousarray(structure.labels, dtype=np.int64)
    idx = np.ascontiguousarray(labels[:, None])
    w = np.ones((M, 1))
    joints = np.ascontiguousarray(structure.joints_rest, dtype=float)
    scale2 = _size_scale2(Q)
    tau0 = _tau_start(Q, config)
    tau_max = max(config.track_tau_max * scale2, tau0)
    floor = max(config.tau_min, 1e-6 * scale2)
    R = np.array(structure.R, dtype=float)
    T = np.array(structure.T, dtype=float)

    def skin(Rb: np.ndarray, Tb: np.ndarray) -> np.ndarray:
        Rf, Tf = _flat_rt(Rb[None], Tb[None])
        return _core.lbs_skin(Q, idx, w, Rf, Tf, 1).reshape(M, 3)

    use_normals = normals is not None and config.track_normal_kappa > 0
    rest_normals = np.ascontiguousarray(normals[0], dtype=float) if use_normals else None

    def fit_frame(v: np.ndarray, Rt: np.ndarray, Tt: np.ndarray,
                  vn: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        # one frame's EM in Rust (rust/core/track.rs; the GIL is released, so a frame's two
        # hypotheses run side by side)
        nrm = (rest_normals, vn, config.track_normal_kappa) if use_normals and vn is not None \
            else (None, None, 0.0)
        Rn, Tn, X = _core.lbs_track_frame(
            Q, labels, parent, joints, np.ascontiguousarray(v, dtype=float),
            np.ascontiguousarray(Rt.reshape(B, 9)),
            tuple(float(c) for c in Tt[root]), config.track_iterations, tau0, tau_max, floor,
            config.track_anneal, config.omega, config.estep_radius_sigmas, config.gamma,
            M / len(v) if config.gmm_density_normalize else 1.0, *nrm,
            sweeps=config.track_sweeps)
        return Rn.reshape(B, 3, 3), Tn, X

    # symmetric chamfer, each distance truncated at 3 sqrt(tau_max): how well a pose explains
    # the frame (template on data, and no data left without template)
    trunc = 3.0 * float(np.sqrt(tau_max))

    order = [rest_index] + list(range(rest_index + 1, F)) + list(range(rest_index - 1, -1, -1))
    # a frame's hypotheses are independent fits: they run side by side (the native calls and
    # the nearest-distance queries release the GIL), each with the same arithmetic as alone
    with ThreadPoolExecutor(max_workers=pool_size(config.workers, 2)) as pool:
        for done, t in enumerate(order, start=1):
            if progress is not None and done > 1:
                progress(done - 1, F)
            v = obs[t]
            s = 1 if t >= rest_index else -1
            p1, p2 = t - s, t - 2 * s
            starts = []
            if t == rest_index:
                starts.append((R[t].copy(), T[t].copy()))
            else:
                if (p2 - rest_index) * s >= 0:
                    starts.append(_predict_rigid(R[p1], T[p1], R[p2], T[p2],
                                                 config.track_velocity))
                else:
                    starts.append((R[p1].copy(), T[p1].copy()))
                # second hypothesis: step 2's own pose of this frame (the registration)
                starts.append((np.array(structure.R[t], dtype=float),
                               np.array(structure.T[t], dtype=float)))
            if len(v) == 0:
                Rt, Tt = starts[0]
                R[t] = Rt
                T[t] = _fixed_joint_translations(Rt, Tt[root], joints, parent, skin)[0]
                continue
            if t != rest_index and (p2 - rest_index) * s >= 0 and config.track_velocity > 0 \
                    and config.track_predict_check > 0:
                # the previous pose instead of the prediction when it explains the frame better
                # (a sudden jump or stop: the prediction repeats the jump)
                Rh, Th = R[p1], T[p1]  # its translations already meet at the joints
                Xh = skin(Rh, Th)
                Xp = _fixed_joint_translations(starts[0][0], starts[0][1][root], joints, parent,
                                               skin)[1]
                if chamfer_misfit(Xh, v, trunc) < \
                        config.track_predict_check * chamfer_misfit(Xp, v, trunc):
                    starts[0] = (Rh.copy(), Th.copy())
            vn = np.ascontiguousarray(normals[1][t], dtype=float) if use_normals else None

            fit = partial(_fit_and_score, fit_frame, v, vn,
                          trunc if len(starts) > 1 else None)
            fits = list(pool.map(fit, starts))
            best = min(fits, key=lambda f: f[0])  # the first on a tie
            R[t], T[t] = best[1], best[2]
    if progress is not None:
        progress(F, F)
    return R, T


# -------------------------------------------------------------------------- main loop


def _dense_to_sparse(W: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    k = min(k, W.shape[1])
    idx = np.argsort(-W, axis=1, kind="stable")[:, :k]
    w = np.take_along_axis(W, idx, axis=1)
    return np.ascontiguousarray(idx, dtype=np.int64), np.ascontiguousarray(w)


def _sparse_to_dense(idx: np.ndarray, w: np.ndarray, B: int) -> np.ndarray:
    W = np.zeros((idx.shape[0], B))
    np.add.at(W, (np.repeat(np.arange(idx.shape[0]), idx.shape[1]), idx.ravel()), w.ravel())
    return W


def posed_rest_points(rest_points: np.ndarray, labels: np.ndarray, R: np.ndarray,
                      T: np.ndarray) -> np.ndarray:
    """The rest points carried rigidly by their bones (one-hot LBS, Eq. 13), ``(F, M, 3)``
    metres.

    Parameters
    ----------
    rest_points
        ``(M, 3)`` rest points, metres.
    labels
        ``(M,)`` bone of each point.
    R, T
        ``(F, B, 3, 3)`` and ``(F, B, 3)`` bone transforms ``T_frame_rest``.
    """
    q = np.ascontiguousarray(rest_points, dtype=np.float64)
    idx = np.ascontiguousarray(np.asarray(labels, dtype=np.int64)[:, None])
    Rf, Tf = _flat_rt(np.asarray(R, dtype=np.float64), np.asarray(T, dtype=np.float64))
    F = R.shape[0]
    return _core.lbs_skin(q, idx, np.ones((len(q), 1)), Rf, Tf, F).reshape(F, len(q), 3)


def _flat_rt(R: np.ndarray, T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    F, B = R.shape[:2]
    return (np.ascontiguousarray(R.reshape(F * B, 9)), np.ascontiguousarray(T.reshape(F * B, 3)))


def _joint_term(R, T, joints, parent) -> float:
    """Second sum of Eq. 20: sum_t sum_edges |R_j c + T_j - R_k c - T_k|^2."""
    e = 0.0
    for k, j in enumerate(parent):
        if j < 0:
            continue
        c = joints[k]
        d = np.einsum("fij,j->fi", R[:, j] - R[:, k], c) + T[:, j] - T[:, k]
        e += float(np.sum(d * d))
    return e


def _validate(frames, Q, Y, st) -> None:
    if Q.ndim != 2 or Q.shape[1] != 3 or len(Q) == 0:
        raise InputError(f"rest_points must be (M, 3) with M > 0, got {Q.shape}")
    if Y.ndim != 3 or Y.shape[1:] != Q.shape:
        raise InputError(f"registered must be (F, {len(Q)}, 3), got {Y.shape}")
    F = Y.shape[0]
    if len(frames) != F:
        raise InputError(f"{len(frames)} frames but registered has {F}")
    for t, V in enumerate(frames):
        if V.ndim != 2 or V.shape[1] != 3 or len(V) == 0:
            raise InputError(f"frame {t}: expected (N, 3) with N > 0, got {V.shape}")
        if not np.all(np.isfinite(V)):
            raise InputError(f"frame {t}: non-finite values")
    if not (np.all(np.isfinite(Q)) and np.all(np.isfinite(Y))):
        raise InputError("rest_points / registered: non-finite values")
    B = len(st.bone_parent)
    if st.R.shape != (F, B, 3, 3) or st.T.shape != (F, B, 3):
        raise InputError(f"structure R/T must be ({F}, {B}, 3, 3)/({F}, {B}, 3), "
                         f"got {st.R.shape}/{st.T.shape}")
    if st.labels.shape != (len(Q),) or st.labels.min() < 0 or st.labels.max() >= B:
        raise InputError("structure.labels must be (M,) in [0, B)")
    if int(np.sum(np.asarray(st.bone_parent) < 0)) != 1:
        raise InputError("bone_parent must have exactly one root (-1)")


def learn_joints(
    frames: Sequence[np.ndarray],
    rest_points: np.ndarray,
    registered: np.ndarray,
    structure: StructureLike,
    config: JointsConfig | None = None,
    progress: Callable[[int, int], None] | None = None,
    rest_index: int | None = None,
    track_progress: Callable[[int, int], None] | None = None,
) -> JointsResult:
    """Refine the skeleton's joints with the full LBS model (Algorithm 2).

    Parameters
    ----------
    frames
        ``F`` observed point clouds ``(N_t, 3)``, metres (the original input ``V^t``).
    rest_points
        ``(M, 3)`` rest points ``q_m``, metres.
    registered
        ``(F, M, 3)`` registered points ``y_m^t`` from step 1.
    structure
        Step-2 result (:class:`StructureLike`): labels, bone tree, transforms, joints, c~.
    config
        :class:`~pointrig.config.JointsConfig` (Table 1 defaults).
    progress
        Called as ``progress(iteration, max_iterations)`` after each iteration.
    rest_index
        The rest frame of step 1 (where the registered points are the rest points), from
        which ``init="track"`` tracks outwards; ``None`` = the frame whose registered points
        are nearest the rest points.
    track_progress
        Called as ``progress(frames_done, F)`` after each frame of the ``init="track"`` pass.

    Returns
    -------
    JointsResult

    Raises
    ------
    InputError
        On inconsistent shapes or non-finite input, or a ``rest_index`` outside the frames.
    """
    cfg = config or JointsConfig()
    Q = np.ascontiguousarray(rest_points, dtype=np.float64)
    Y = np.ascontiguousarray(registered, dtype=np.float64)
    frames = [np.ascontiguousarray(v, dtype=np.float64) for v in frames]
    _validate(frames, Q, Y, structure)
    F, M, _ = Y.shape
    parent = np.asarray(structure.bone_parent, dtype=np.int64)
    B = len(parent)
    root = int(np.flatnonzero(parent < 0)[0])
    size2 = float(np.sum((Q.max(0) - Q.min(0)) ** 2))  # squared rest bounding-box diagonal
    K = min(cfg.max_bones_per_point, B)
    c_tilde = np.asarray(structure.c_tilde, dtype=float)
    # observed points of the E-steps (tracking and EM): subsampled per frame (the statistics
    # scale with N_t, which gmm_density_normalize divides out), packed once for the kernel
    obs = subsample_frames(frames, cfg.estep_max_points)
    R, T, t_track = _initial_motions(frames, obs, Q, Y, structure, cfg, rest_index,
                                     track_progress)
    joints = np.array(structure.joints_rest, dtype=float)
    W = np.zeros((M, B))
    W[np.arange(M), np.asarray(structure.labels)] = 1.0
    tau = np.full(F, _tau_start(Q, cfg))
    zeta = cfg.zeta * cfg.zeta_scale
    alpha = cfg.alpha_init if cfg.alpha_init is not None else cfg.zeta * M
    articulated = cfg.mode == "articulated"
    c_prior = c_tilde.copy()
    c_prior[root] = joints[root]

    def skin_all(W_, R_, T_):
        idx, w = _dense_to_sparse(W_, K)
        Rf, Tf = _flat_rt(R_, T_)
        return _core.lbs_skin(Q, idx, w, Rf, Tf, F).reshape(F, M, 3)

    energy: list[float] = []
    diag: dict[str, list] = {k: [] for k in (
        "e_gmm", "e_register", "e_joint", "e_small", "alpha", "joint_shift", "tau_mean",
        "t_estep", "t_weights", "t_bones", "t_joints")}
    allowed = _weight_candidates(parent, structure.labels, cfg)
    X = skin_all(W, R, T)
    packed = pack_frames(obs)
    n_obs = np.array([len(v) for v in obs], float)
    joints0 = joints.copy()
    prev_total = None
    it = 0
    for it in range(1, cfg.max_iterations + 1):
        t0 = time.perf_counter()
        # ---- E-step (Eq. 4 form) and the reduced data term
        st = e_step(obs, X, tau, cfg.omega, cfg.estep_radius_sigmas, True, packed=packed)
        a, z, zf = _data_term(st, tau, zeta, Y, X, n_obs, cfg)
        t1 = time.perf_counter()
        R_pre, T_pre = R.copy(), T.copy()
        # ---- weights (Eq. 22)
        if cfg.update_weights:
            W = _fit_weights(Q, R, T, a, zf, K, allowed, W)
        t2 = time.perf_counter()
        # ---- bones (Eqs. 23-26) and joints (Eq. 20)
        R, T, joints, smooth, t3, t4 = _fit_bones_and_joints(
            Q, W, R, T, R_pre, T_pre, a, z, zf, parent, joints, c_prior, alpha, size2, K, cfg)
        t5 = time.perf_counter()
        # ---- deformed points (Eq. 13) and covariances (Eq. 12 form)
        X = skin_all(W, R, T)
        _, ss = _gmm_energy(st, X, tau)
        tau = np.maximum(ss / (3 * np.maximum(st.Np, 1e-12)), cfg.tau_min)
        total, e_gmm, e_reg, e_joint, e_small = _energy(
            st, X, tau, Y, R, T, R_pre, T_pre, joints, parent, c_tilde, a, zeta, alpha, smooth,
            cfg)
        energy.append(float(total))
        shift = float(np.max(np.linalg.norm(joints - joints0, axis=1))) if it == 1 else float(
            np.max(np.linalg.norm(joints - diag["_prev_joints"], axis=1)))  # type: ignore[arg-type]
        diag["_prev_joints"] = joints.copy()  # type: ignore[assignment]
        for key, val in (("e_gmm", e_gmm), ("e_register", e_reg), ("e_joint", e_joint),
                         ("e_small", e_small), ("alpha", alpha), ("joint_shift", shift),
                         ("tau_mean", float(tau.mean())), ("t_estep", t1 - t0),
                         ("t_weights", t2 - t1), ("t_bones", t4 - t3),
                         ("t_joints", (t3 - t2) + (t5 - t4))):
            diag[key].append(val)
        log.debug("step 3 iteration %d: E=%.6g shift=%.4g m tau=%.3g", it, total, shift, tau.mean())
        if progress is not None:
            progress(it, cfg.max_iterations)
        if not articulated:
            alpha *= cfg.alpha_growth
        if prev_total is not None and abs(total - prev_total) <= cfg.tolerance * max(abs(total), 1e-300):
            break
        if cfg.joint_tolerance > 0 and it >= cfg.min_iterations and shift < cfg.joint_tolerance:
            break
        prev_total = total
    diag.pop("_prev_joints", None)
    if it > 0 and not cfg.update_weights:
        # blend weights for the output only (Eq. 22 once, with the last data term)
        W = _fit_weights(Q, R, T, a, zf, K, allowed, W)
    out_diag: dict[str, Any] = dict(diag)
    out_diag["iterations"] = it
    out_diag["mode"] = cfg.mode
    out_diag["init"] = cfg.init
    out_diag["t_track"] = t_track
    out_diag["joints_step2"] = np.asarray(structure.joints_rest, dtype=float)
    return JointsResult(W, R, T, joints, tau, energy, parent.copy(), root, out_diag)


def _initial_motions(frames: list[np.ndarray], obs: list[np.ndarray], Q: np.ndarray,
                     Y: np.ndarray, structure: StructureLike, cfg: JointsConfig,
                     rest_index: int | None,
                     track_progress: Callable[[int, int], None] | None
                     ) -> tuple[np.ndarray, np.ndarray, float]:
    """The bone motions the EM starts from, ``R (F, B, 3, 3)``, ``T (F, B, 3)`` (metres), and
    the seconds spent: step 2's with ``init="structure"``; with ``init="track"`` step 2's
    skeleton fitted to the subsampled frames ``obs`` outwards from ``rest_index``
    (:func:`track_bones`, with normals when ``track_normal_kappa > 0``).

    Raises
    ------
    InputError
        If ``rest_index`` is outside the frames.
    """
    R = np.array(structure.R, dtype=float)
    T = np.array(structure.T, dtype=float)
    if cfg.init != "track":
        return R, T, 0.0
    F = len(Y)
    if rest_index is None:
        rest_index = int(np.argmin(((Y - Q[None]) ** 2).sum(axis=(1, 2))))
    if not 0 <= rest_index < F:
        raise InputError(f"rest_index {rest_index} outside the {F} frames")
    t_tr = time.perf_counter()
    track_normals = None
    if cfg.track_normal_kappa > 0:
        radius = cfg.normal_radius * mean_spacing(Q)
        track_normals = (
            estimate_normals(Q, radius, source=frames[int(rest_index)]),
            [estimate_normals(o, radius, source=v) for o, v in zip(obs, frames)],
        )
    R, T = track_bones(obs, Q, structure, int(rest_index), cfg, track_progress, track_normals)
    return R, T, time.perf_counter() - t_tr


def _weight_candidates(parent: np.ndarray, labels: np.ndarray, cfg: JointsConfig
                       ) -> np.ndarray | None:
    """``(M, B)`` bool mask of the bones a point may be skinned to with
    ``weight_candidates="tree"`` (its step-2 bone and the bones adjacent to it in the tree),
    else ``None`` (every bone)."""
    if cfg.weight_candidates != "tree":
        return None
    B = len(parent)
    adj = np.eye(B, dtype=bool)
    for k_, p_ in enumerate(parent):
        if p_ >= 0:
            adj[k_, p_] = adj[p_, k_] = True
    return np.ascontiguousarray(adj[np.asarray(labels)])


def _data_term(st: EStats, tau: np.ndarray, zeta: float, Y: np.ndarray, X: np.ndarray,
               n_obs: np.ndarray, cfg: JointsConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The reduced data term ``sum a/2 |x - z|^2`` of ``E_GMM + zeta/2 E_Register`` (module
    docstring): weights ``a (F, M)``, targets ``z (F, M, 3)`` (metres; ``X`` where ``a = 0``)
    and ``z`` flattened to ``(F M, 3)``, from the E-step statistics ``st``, the covariances
    ``tau (F,)``, the registered points ``Y`` and the deformed points ``X (F, M, 3)``."""
    F, M = Y.shape[:2]
    a_g = st.P1 / tau[:, None]
    if cfg.gmm_density_normalize:
        # one unit of evidence per template point, not per observed point (N_t / M)
        a_g = a_g * (M / n_obs)[:, None]
    a = a_g + zeta
    num = a_g[..., None] * (st.PX / np.maximum(st.P1, 1e-300)[..., None]) + zeta * Y
    safe = np.where(a > 0, a, 1.0)
    z = np.where((a > 0)[..., None], num / safe[..., None], X)
    a = np.ascontiguousarray(a)
    zf = np.ascontiguousarray(z.reshape(F * M, 3))
    return a, z, zf


def _fit_weights(Q: np.ndarray, R: np.ndarray, T: np.ndarray, a: np.ndarray, zf: np.ndarray,
                 K: int, allowed: np.ndarray | None, W: np.ndarray) -> np.ndarray:
    """Skinning weights ``(M, B)`` by Eq. 22 (at most ``K`` bones a point, Rust); a point no
    frame's data term sees (``a`` summed over frames is 0) keeps its row of ``W``."""
    F, B = R.shape[:2]
    Rf, Tf = _flat_rt(R, T)
    idx, w, _ = _core.lbs_fit_weights(Q, Rf, Tf, a, zf, F, K, allowed)
    Wn = _sparse_to_dense(idx, w, B)
    seen = a.sum(0) > 0
    return np.where(seen[:, None], Wn, W)


def _fit_bones_and_joints(Q: np.ndarray, W: np.ndarray, R: np.ndarray, T: np.ndarray,
                          R_pre: np.ndarray, T_pre: np.ndarray, a: np.ndarray, z: np.ndarray,
                          zf: np.ndarray, parent: np.ndarray, joints: np.ndarray,
                          c_prior: np.ndarray, alpha: float, size2: float, K: int,
                          cfg: JointsConfig
                          ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None,
                                     float, float]:
    """One M-step of the bones (Eqs. 23-26, ``cfg.bone_sweeps`` Rust sweeps) and the joints.

    ``mode="articulated"``: joints and translations solved jointly (:func:`solve_joints_articulated`)
    before and after the sweeps, which rotate each bone about its head joint, with the rotation
    smoothing weights (``(B,)`` or ``None``); ``mode="paper"``: the sweeps with the soft joint
    term ``alpha``, then the joints by Eq. 20. Returns ``R (F, B, 3, 3)``, ``T (F, B, 3)``,
    the joints ``(B, 3)`` (metres), the smoothing weights (``None`` for ``"paper"``) and the
    ``perf_counter`` times at the start and end of the sweeps.
    """
    F, B = R.shape[:2]
    root = int(np.flatnonzero(parent < 0)[0])
    idx, w = _dense_to_sparse(W, K)
    smooth = None
    if cfg.mode == "articulated":
        joints, T = solve_joints_articulated(Q, W, R, a, z, parent, c_prior,
                                             cfg.eta * cfg.joint_prior, T[:, root])
        t3 = time.perf_counter()
        if cfg.rotation_smoothing > 0 and F > 2:
            smooth = np.full(B, cfg.rotation_smoothing * float(np.mean(a)) * size2)
        for _ in range(cfg.bone_sweeps):
            Rf, Tf = _flat_rt(R, T)
            Rn, Tn = _core.lbs_sweep_articulated(
                Q, idx, w, Rf, Tf, a, zf, _flat_rt(R_pre, T_pre)[0], parent, joints,
                cfg.gamma, F, smooth)
            R, T = Rn.reshape(F, B, 3, 3), Tn.reshape(F, B, 3)
        t4 = time.perf_counter()
        joints, T = solve_joints_articulated(Q, W, R, a, z, parent, c_prior,
                                             cfg.eta * cfg.joint_prior, T[:, root])
    else:
        t3 = time.perf_counter()
        for _ in range(cfg.bone_sweeps):
            Rf, Tf = _flat_rt(R, T)
            Rpf, Tpf = _flat_rt(R_pre, T_pre)
            Rn, Tn = _core.lbs_sweep_paper(
                Q, idx, w, Rf, Tf, a, zf, Rpf, Tpf, parent, joints, alpha, cfg.gamma, F)
            R, T = Rn.reshape(F, B, 3, 3), Tn.reshape(F, B, 3)
        t4 = time.perf_counter()
        joints = solve_joint_positions(R, T, parent, c_prior, cfg.eta)
    return R, T, joints, smooth, t3, t4


def _energy(st: EStats, X: np.ndarray, tau: np.ndarray, Y: np.ndarray, R: np.ndarray,
            T: np.ndarray, R_pre: np.ndarray, T_pre: np.ndarray, joints: np.ndarray,
            parent: np.ndarray, c_tilde: np.ndarray, a: np.ndarray, zeta: float, alpha: float,
            smooth: np.ndarray | None, cfg: JointsConfig
            ) -> tuple[float, float, float, float, float]:
    """The objective after an iteration and its terms: ``(total, E_GMM, E_Register, joint
    term, small-motion term)``. ``"articulated"``: the joint term is the prior
    ``eta |c - c~|^2`` scaled by the mean data weight, plus the rotation smoothing; ``"paper"``:
    ``eta |c - c~|^2`` plus the second sum of Eq. 20, weighted by ``alpha``."""
    e_gmm, _ = _gmm_energy(st, X, tau)
    e_reg = float(np.sum((Y - X) ** 2))
    e_joint_cons = _joint_term(R, T, joints, parent)
    nr = parent >= 0
    e_prior = float(np.sum((joints[nr] - c_tilde[nr]) ** 2))
    e_small = float(np.sum((R - R_pre) ** 2) + np.sum((T - T_pre) ** 2))
    e_smooth = float(np.sum((R[2:] - 2 * R[1:-1] + R[:-2]) ** 2))
    if cfg.mode == "articulated":
        lam_scale = cfg.eta * cfg.joint_prior * float(np.mean(a.sum(1)))
        e_joint = lam_scale * e_prior
        total = e_gmm + 0.5 * zeta * e_reg + 0.5 * e_joint + 0.5 * cfg.gamma * e_small
        if smooth is not None:
            total += 0.5 * float(smooth[0]) * e_smooth
    else:
        e_joint = cfg.eta * e_prior + e_joint_cons
        total = e_gmm + 0.5 * zeta * e_reg + 0.5 * alpha * e_joint + 0.5 * cfg.gamma * e_small
    return total, e_gmm, e_reg, e_joint, e_small
