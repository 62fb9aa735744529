"""Shared kinematics of the bone model: LBS (Eq. 13) and joint positions (Eq. 20).

Conventions used across steps 2 and 3:

- ``B`` bones (motion clusters). Bone ``b`` has the per-frame rigid transform
  ``T_frame_rest = (R[t, b], T[t, b])`` that maps rest-pose points to frame ``t``:
  ``x = R[t, b] @ q + T[t, b]``. ``R`` is ``(F, B, 3, 3)``, ``T`` is ``(F, B, 3)`` metres.
- The bone tree is ``bone_parent (B,)`` with ``-1`` for the root bone.
- Each bone ``b`` owns one joint, its *head*: for the root bone, a point at the root's centre;
  for any other bone, the joint ``c_{p b}`` it shares with its parent ``p`` (Eq. 20). So
  joints and bones are in one-to-one correspondence, joint ``b``'s parent is joint
  ``bone_parent[b]``, and skinning weights ``(M, B)`` refer to both.
"""

from __future__ import annotations

import numpy as np

__all__ = ["skin", "solve_joint_positions", "joint_trajectories"]


def skin(rest_points: np.ndarray, weights: np.ndarray, R: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Linear blend skinning (Eq. 13) of the rest points into every frame.

    Parameters
    ----------
    rest_points
        ``(M, 3)`` rest-pose points ``q_m``, metres.
    weights
        ``(M, B)`` weights ``w_mj`` (rows sum to 1).
    R, T
        ``(F, B, 3, 3)`` rotations and ``(F, B, 3)`` translations (``T_frame_rest``).

    Returns
    -------
    numpy.ndarray
        ``(F, M, 3)`` deformed points ``x_m^t``, metres.
    """
    # per bone: (F, B, M, 3) would be big; accumulate over bones instead
    F, B = R.shape[:2]
    out = np.zeros((F, rest_points.shape[0], 3))
    for b in range(B):
        w = weights[:, b]
        nz = w > 0
        if not nz.any():
            continue
        moved = np.einsum("fij,mj->fmi", R[:, b], rest_points[nz]) + T[:, b, None, :]
        out[:, nz] += w[nz, None] * moved
    return out


def solve_joint_positions(
    R: np.ndarray,
    T: np.ndarray,
    bone_parent: np.ndarray,
    c_tilde: np.ndarray,
    eta: float = 1.0,
) -> np.ndarray:
    """Joint positions by least squares (Eq. 20), in closed form, one 3x3 system per edge.

    For the edge between bone ``j = bone_parent[k]`` and bone ``k``, minimise
    ``eta |c - c~|^2 + sum_t |(R_j^t - R_k^t) c + (T_j^t - T_k^t)|^2``, i.e. solve
    ``(eta I + sum_t A_t^T A_t) c = eta c~ - sum_t A_t^T b_t`` with ``A_t = R_j^t - R_k^t`` and
    ``b_t = T_j^t - T_k^t``.

    Parameters
    ----------
    R, T
        ``(F, B, 3, 3)`` and ``(F, B, 3)`` bone transforms (``T_frame_rest``).
    bone_parent
        ``(B,)`` parent bone, ``-1`` for the root.
    c_tilde
        ``(B, 3)`` data-term targets: for a non-root bone, the centroid of the boundary points
        between it and its parent (metres, rest pose); for the root, its own head position
        (returned unchanged).
    eta
        Weight of the data term (Table 1: 1).

    Returns
    -------
    numpy.ndarray
        ``(B, 3)`` rest-pose joint positions (joint ``b`` = head of bone ``b``), metres.
    """
    c = np.array(c_tilde, dtype=np.float64, copy=True)
    for k, j in enumerate(np.asarray(bone_parent)):
        if j < 0:
            continue
        A = R[:, j] - R[:, k]  # (F, 3, 3)
        b = T[:, j] - T[:, k]  # (F, 3)
        lhs = eta * np.eye(3) + np.einsum("fji,fjk->ik", A, A)
        rhs = eta * c_tilde[k] - np.einsum("fji,fj->i", A, b)
        c[k] = np.linalg.solve(lhs, rhs)
    return c


def joint_trajectories(
    joints_rest: np.ndarray, R: np.ndarray, T: np.ndarray, bone_parent: np.ndarray
) -> np.ndarray:
    """Per-frame joint positions ``(F, B, 3)``, metres.

    A non-root joint moves with the mean of its two bones' transforms,
    ``0.5 (R_j c + T_j + R_k c + T_k)``; the root joint moves with the root bone.
    """
    F, B = R.shape[:2]
    out = np.empty((F, B, 3))
    for k, j in enumerate(np.asarray(bone_parent)):
        pk = np.einsum("fij,j->fi", R[:, k], joints_rest[k]) + T[:, k]
        if j < 0:
            out[:, k] = pk
        else:
            pj = np.einsum("fij,j->fi", R[:, j], joints_rest[k]) + T[:, j]
            out[:, k] = 0.5 * (pk + pj)
    return out
