"""Synthetic articulated figures with known joints for the step-3 tests and benchmarks.

A figure is a tree of capsules (bones). Bone ``b``'s head joint is ``heads[b]``; the rest points
are sampled on the capsule surfaces and skinned with smooth LBS weights that blend parent and
child over ``blend`` metres on both sides of each joint (so rigid per-part fits are biased, as
in real data). Per-frame bone transforms come from forward kinematics with the child rotating
about its head joint (so ``R_p c + T_p = R_k c + T_k`` holds exactly at every joint).

Observations imitate one depth camera on the +z axis: only points whose (blended) normal faces
the camera are kept, then Gaussian noise and uniform outliers are added. ``registered`` is the
exact LBS deformation plus noise (a stand-in for step 1). :func:`step2_standin` gives a step-2
result: one rigid Kabsch fit per ground-truth part (Eq. 14 on the registered points) and the
Eq. 20 joints with boundary centroids, the same quantities ``pointrig.structure`` returns.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from pointrig.config import StructureConfig
from pointrig.kinematics import joint_trajectories, skin, solve_joint_positions
from pointrig.structure import _boundary_centroids, _Ctx


@dataclass
class Figure:
    rest_points: np.ndarray  # (M, 3) rest pose, metres
    normals: np.ndarray  # (M, 3) rest-pose outward normals
    labels: np.ndarray  # (M,) primary bone of each point
    weights: np.ndarray  # (M, B) ground-truth LBS weights
    bone_parent: np.ndarray  # (B,)
    joints_rest: np.ndarray  # (B, 3) ground-truth head joints (root: its centre)
    R: np.ndarray  # (F, B, 3, 3)
    T: np.ndarray  # (F, B, 3)
    registered: np.ndarray  # (F, M, 3) noisy LBS points (step-1 stand-in)
    frames: list  # F arrays (N_t, 3): single-view noisy observations
    root: int = 0
    camera: np.ndarray | None = None  # (3,) the camera of a front-only rest surface

    @property
    def joints_gt(self) -> np.ndarray:
        """(F, B, 3) ground-truth joint trajectories."""
        return joint_trajectories(self.joints_rest, self.R, self.T, self.bone_parent)


@dataclass
class StructureStandin:
    labels: np.ndarray
    bone_parent: np.ndarray
    R: np.ndarray
    T: np.ndarray
    joints_rest: np.ndarray
    c_tilde: np.ndarray
    root: int
    view_camera: np.ndarray | None = None
    view_quantile: float = 0.0


def _capsule_points(head, tail, radius, n, rng, front_only):
    axis = tail - head
    length = np.linalg.norm(axis)
    u = axis / length
    tmp = np.array([0.0, 0.0, 1.0]) if abs(u[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    e1 = np.cross(u, tmp)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(u, e1)
    s = rng.uniform(0.0, length, n)
    if front_only:  # only the half facing +z (the camera at the rest frame)
        phi = rng.uniform(0, 2 * np.pi, 4 * n)
        nz = np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2
        phi = phi[nz[:, 2] > 0][:n]
        if phi.size < n:
            phi = np.concatenate([phi, rng.uniform(0, 2 * np.pi, n - phi.size)])
    else:
        phi = rng.uniform(0, 2 * np.pi, n)
    nrm = np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2
    pts = head + s[:, None] * u + radius * nrm
    return pts, nrm, s / length


# name, parent, head, tail, radius, kind ("ball" / "hinge" axis), angle amplitude (rad)
_HUMAN = [
    ("torso", -1, (0.0, 1.05, 0.0), (0.0, 1.45, 0.0), 0.14, None, 0.0),
    ("head", 0, (0.0, 1.50, 0.0), (0.0, 1.72, 0.0), 0.09, "ball", 0.3),
    ("l_upperarm", 0, (0.20, 1.42, 0.0), (0.48, 1.42, 0.0), 0.045, "ball", 0.9),
    ("l_forearm", 2, (0.48, 1.42, 0.0), (0.74, 1.42, 0.0), 0.04, (0, 1, 0), 1.1),
    ("r_upperarm", 0, (-0.20, 1.42, 0.0), (-0.48, 1.42, 0.0), 0.045, "ball", 0.9),
    ("r_forearm", 4, (-0.48, 1.42, 0.0), (-0.74, 1.42, 0.0), 0.04, (0, 1, 0), 1.1),
    ("l_thigh", 0, (0.10, 0.98, 0.0), (0.10, 0.55, 0.0), 0.07, "ball", 0.6),
    ("l_shin", 6, (0.10, 0.55, 0.0), (0.10, 0.12, 0.0), 0.055, (1, 0, 0), 1.0),
    ("r_thigh", 0, (-0.10, 0.98, 0.0), (-0.10, 0.55, 0.0), 0.07, "ball", 0.6),
    ("r_shin", 8, (-0.10, 0.55, 0.0), (-0.10, 0.12, 0.0), 0.055, (1, 0, 0), 1.0),
]

_ARM = [
    ("upper", -1, (0.0, 0.0, 0.0), (0.30, 0.0, 0.0), 0.045, None, 0.0),
    ("fore", 0, (0.30, 0.0, 0.0), (0.55, 0.0, 0.0), 0.04, (0, 1, 0), 1.2),
    ("hand", 1, (0.55, 0.0, 0.0), (0.68, 0.0, 0.0), 0.035, "ball", 0.6),
]


def make_figure(
    kind: str = "human",
    n_frames: int = 20,
    n_points: int = 1200,
    n_obs: int = 3000,
    blend: float = 0.04,
    obs_noise: float = 0.004,
    reg_noise: float = 0.003,
    outliers: float = 0.02,
    front_only_rest: bool = True,
    seed: int = 0,
) -> Figure:
    """Build a skinned figure, its motion, registered points and single-view observations.

    ``kind`` is ``"human"`` (10 bones, 1.7 m) or ``"arm"`` (3 bones). Noise levels in metres;
    ``outliers`` is the fraction of uniform outliers added to each observed frame.
    """
    rng = np.random.default_rng(seed)
    spec = _HUMAN if kind == "human" else _ARM
    B = len(spec)
    parent = np.array([s[1] for s in spec])
    heads = np.array([s[2] for s in spec], float)
    tails = np.array([s[3] for s in spec], float)
    lengths = np.linalg.norm(tails - heads, axis=1)
    area = np.array([s[4] for s in spec]) * lengths
    counts = np.maximum((n_points * area / area.sum()).astype(int), 20)
    counts[0] += n_points - counts.sum()
    pts, nrms, labels = [], [], []
    for b, (_, _, _, _, rad, _, _) in enumerate(spec):
        p, n, _ = _capsule_points(heads[b], tails[b], rad, counts[b], rng, front_only_rest)
        pts.append(p)
        nrms.append(n)
        labels.append(np.full(len(p), b))
    Q = np.concatenate(pts)
    Nr = np.concatenate(nrms)
    labels = np.concatenate(labels)
    M = len(Q)

    # LBS weights: blend each child with its parent around the child's head joint
    W = np.zeros((M, B))
    W[np.arange(M), labels] = 1.0
    for k in range(B):
        p = parent[k]
        if p < 0:
            continue
        u = (tails[k] - heads[k]) / lengths[k]
        s = (Q - heads[k]) @ u  # signed distance along the child axis
        near = (labels == k) | (labels == p)
        near &= np.linalg.norm((Q - heads[k]) - s[:, None] * u, axis=1) < 3 * spec[k][4] + 0.1
        wk = np.clip(0.5 + 0.5 * s / blend, 0.0, 1.0)
        sel = near & (np.abs(s) < blend)
        moved = W[sel, k] + W[sel, p]
        W[sel, k] = wk[sel] * moved
        W[sel, p] = (1 - wk[sel]) * moved

    # joints: root at its centre, others at their heads
    joints = heads.copy()
    joints[0] = 0.5 * (heads[0] + tails[0])

    # motion: smooth random angles per bone; root translates and turns slowly
    tt = np.linspace(0, 1, n_frames)
    R = np.zeros((n_frames, B, 3, 3))
    T = np.zeros((n_frames, B, 3))
    for f in range(n_frames):
        for b in range(B):
            _, p, _, _, _, kk, amp = spec[b]
            ph = (b * 1.7) % (2 * np.pi)
            if p < 0:
                rel = Rotation.from_rotvec([0.0, 0.4 * np.sin(2 * np.pi * tt[f]), 0.0]).as_matrix()
                R[f, b] = rel
                T[f, b] = joints[b] - rel @ joints[b] + np.array([0.1 * tt[f], 0.0, 0.05 * np.sin(3 * tt[f])])
                continue
            if kk == "ball":
                ax = np.array([np.sin(ph), np.cos(ph), 0.5 * np.sin(2 * ph)])
                ax2 = np.array([0.0, 0.0, 1.0])
                rv = amp * (
                    np.sin(2 * np.pi * tt[f] + ph) * ax / np.linalg.norm(ax)
                    + 0.6 * np.sin(2 * np.pi * 1.3 * tt[f] + 2 * ph) * ax2
                )
            else:
                ax = np.asarray(kk, float)
                rv = amp * (0.5 + 0.5 * np.sin(2 * np.pi * tt[f] + ph)) * ax
            rel = Rotation.from_rotvec(rv).as_matrix()
            R[f, b] = R[f, p] @ rel
            c = joints[b]
            T[f, b] = R[f, p] @ c + T[f, p] - R[f, b] @ c
    X = skin(Q, W, R, T)
    registered = X + rng.normal(0, reg_noise, X.shape)

    # single-view observations from a camera on +z
    frames = []
    cam = np.array([0.0, 1.0, 4.0])
    for f in range(n_frames):
        nb = np.einsum("mb,bij,mj->mi", W, R[f], Nr)
        vis = np.einsum("mi,mi->m", nb, cam - X[f]) > 0
        src = X[f][vis]
        # resample the visible surface densely: jitter along the surface around visible points
        pick = rng.integers(0, len(src), n_obs)
        obs = src[pick] + rng.normal(0, obs_noise, (n_obs, 3))
        n_out = int(outliers * n_obs)
        lo, hi = X[f].min(0) - 0.2, X[f].max(0) + 0.2
        obs[:n_out] = rng.uniform(lo, hi, (n_out, 3))
        frames.append(np.ascontiguousarray(obs))
    return Figure(Q, Nr, labels, W, parent, joints, R, T, registered, frames,
                  camera=cam.copy() if front_only_rest else None)


def boundary_centroids(Q, labels, bone_parent, radius=0.03):
    """c~ (B,3): centroid of points of bone k or its parent with a neighbour of the other label
    within ``radius``; the root gets its cluster centroid."""
    B = len(bone_parent)
    tree = cKDTree(Q)
    pairs = tree.query_pairs(radius, output_type="ndarray")
    la, lb = labels[pairs[:, 0]], labels[pairs[:, 1]]
    c = np.zeros((B, 3))
    for k in range(B):
        p = bone_parent[k]
        if p < 0:
            c[k] = Q[labels == k].mean(0)
            continue
        sel = ((la == k) & (lb == p)) | ((la == p) & (lb == k))
        idx = np.unique(pairs[sel].ravel())
        c[k] = Q[idx].mean(0) if idx.size else Q[labels == k].mean(0)
    return c


def step2_standin(fig: Figure, eta: float = 1.0) -> StructureStandin:
    """Rigid per-part fits (Eq. 14) on the registered points with the true part labels, and
    Eq. 20 joints with boundary centroids: what step 2 returns on a perfect clustering."""
    from pointrig import _core

    F = fig.registered.shape[0]
    B = len(fig.bone_parent)
    R = np.zeros((F, B, 3, 3))
    T = np.zeros((F, B, 3))
    for b in range(B):
        sel = fig.labels == b
        src = np.ascontiguousarray(fig.rest_points[sel])
        for f in range(F):
            R[f, b], T[f, b] = _core.kabsch(src, np.ascontiguousarray(fig.registered[f, sel]))
    # step 2's own c~ (boundary band of the vote neighbourhoods, single-view depth correction
    # with the fixture's camera when the rest surface is one-sided)
    cfg = StructureConfig()
    q = cfg.view_depth_quantile if fig.camera is not None else 0.0
    ctx = _Ctx(fig.rest_points, fig.registered, cfg)
    ct = _boundary_centroids(ctx, fig.labels, fig.bone_parent, fig.camera)
    joints = solve_joint_positions(R, T, fig.bone_parent, ct, eta)
    return StructureStandin(fig.labels.copy(), fig.bone_parent.copy(), R, T, joints, ct, 0,
                            fig.camera, q)


def joint_errors(fig: Figure, joints_rest, R, T) -> dict:
    """Errors of non-root joints vs ground truth, metres: rest-pose distance, mean per-frame
    distance of the trajectories, and that distance after subtracting each joint's mean offset
    (the normalisation of Helten et al. used by the paper)."""
    nr = fig.bone_parent >= 0
    rest = np.linalg.norm(joints_rest - fig.joints_rest, axis=1)[nr]
    traj = joint_trajectories(joints_rest, R, T, fig.bone_parent)[:, nr]
    gt = fig.joints_gt[:, nr]
    d = traj - gt
    per_frame = np.linalg.norm(d, axis=2)
    norm = np.linalg.norm(d - d.mean(0, keepdims=True), axis=2)
    return {
        "rest_mean": float(rest.mean()),
        "rest_max": float(rest.max()),
        "traj_mean": float(per_frame.mean()),
        "norm_mean": float(norm.mean()),
    }


# ------------------------------------------------------------------ pointrig.synth adapter


@dataclass
class SynthCase:
    """A pointrig.synth sequence prepared for step 3 with a step-2 stand-in."""

    name: str
    frames: list
    rest_points: np.ndarray  # (M, 3) = exact surface samples at frame 0 (camera frame)
    registered: np.ndarray  # (F, M, 3) exact correspondences + noise (step-1 stand-in)
    structure: StructureStandin
    seq: object  # the SynthSequence (GT joints, surface, ...)
    bone_joint: np.ndarray  # (B,) GT joint index of each bone


def synth_case(name: str = "human", n_frames: int = 30, n_points: int = 2000,
               reg_noise: float = 0.005, seed: int = 0, **synth_kw) -> SynthCase:
    """Render ``name`` with pointrig.synth (Kinect-like noise) and build step-2 inputs: rest
    points = ``n_points`` exact surface samples at frame 0; registered = their exact positions
    in every frame plus ``reg_noise`` Gaussian noise; step 2 = rigid Kabsch fit per GT part
    (``surface_labels``) and Eq. 20 joints with boundary centroids (parts without samples are
    dropped and their children re-attached to the nearest kept ancestor)."""
    from pointrig import _core
    from pointrig.synth import synthesize

    seq = synthesize(name, n_frames, seed=seed, **synth_kw)
    rng = np.random.default_rng(seed)
    S = seq.surface.shape[1]
    pick = np.sort(rng.choice(S, size=min(n_points, S), replace=False))
    Q = np.ascontiguousarray(seq.surface[0, pick])
    Y = seq.surface[:, pick] + rng.normal(0, reg_noise, (n_frames, len(pick), 3))
    lab_gt = np.asarray(seq.surface_labels)[pick]
    parents_gt = np.asarray(seq.joint_parents)
    kept = [j for j in range(len(parents_gt)) if np.sum(lab_gt == j) >= 10]
    remap = {j: i for i, j in enumerate(kept)}

    def kept_ancestor(j):
        p = parents_gt[j]
        while p >= 0 and p not in remap:
            p = parents_gt[p]
        return p

    parent = np.array([remap[kept_ancestor(j)] if kept_ancestor(j) >= 0 else -1 for j in kept])
    # points of dropped parts go to their nearest kept ancestor (or the root)
    lab = np.empty(len(pick), int)
    for j in np.unique(lab_gt):
        a = j
        while a >= 0 and a not in remap:
            a = parents_gt[a]
        lab[lab_gt == j] = remap[a] if a >= 0 else 0
    roots = np.flatnonzero(parent < 0)
    for r_ in roots[1:]:
        parent[r_] = roots[0]
    B = len(kept)
    R = np.zeros((n_frames, B, 3, 3))
    T = np.zeros((n_frames, B, 3))
    for b in range(B):
        sel = lab == b
        for f in range(n_frames):
            R[f, b], T[f, b] = _core.kabsch(Q[sel], np.ascontiguousarray(Y[f, sel]))
    ct = boundary_centroids(Q, lab, parent)
    joints = solve_joint_positions(R, T, parent, ct, 1.0)
    st = StructureStandin(lab, parent, R, T, joints, ct, int(roots[0]))
    return SynthCase(name, [np.ascontiguousarray(v) for v in seq.frames], Q,
                     np.ascontiguousarray(Y), st, seq, np.array(kept))


def synth_scores(case: SynthCase, joints_rest, R, T) -> dict:
    """pointrig.evaluate scores of the predicted joint trajectories (one joint per bone)."""
    from pointrig.evaluate import evaluate

    seq = case.seq
    pred = joint_trajectories(joints_rest, R, T, case.structure.bone_parent)
    rep = evaluate(pred, seq.gt_joints, seq.joint_parents, **seq.eval_kwargs())
    # also the direct per-bone error (bone b's joint vs the GT joint it came from)
    d = np.linalg.norm(pred - seq.gt_joints[:, case.bone_joint], axis=2).mean(0)
    nr = case.structure.bone_parent >= 0
    return {"recall": rep.recall, "raw": rep.raw_error, "norm": rep.normalized_error,
            "direct": float(d[nr].mean())}
