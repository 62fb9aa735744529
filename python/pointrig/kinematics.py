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

__all__ = [
    "joint_trajectories",
    "minimal_twist",
    "skin",
    "solve_joint_positions",
    "swing_twist",
    "tree_order",
    "twist_angles",
]


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


def swing_twist(R: np.ndarray, axis: np.ndarray) -> tuple[np.ndarray, float]:
    """Split a rotation into a swing and a twist about ``axis``: ``R = swing @ twist``.

    ``twist`` turns about ``axis`` by the returned angle; ``swing`` turns about an axis
    perpendicular to ``axis`` (the swing-twist decomposition, from the quaternion's part along
    ``axis``).

    Parameters
    ----------
    R
        ``(3, 3)`` rotation matrix.
    axis
        ``(3,)`` direction (need not be unit length; its sign does not change ``swing``).

    Returns
    -------
    swing
        ``(3, 3)`` rotation.
    angle
        Twist angle in radians, in ``[-pi, pi]``, right-handed about ``axis``.
    """
    from scipy.spatial.transform import Rotation

    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    angle = float(twist_angles(np.asarray(R, dtype=np.float64)[None], a)[0])
    twist = Rotation.from_rotvec(angle * a).as_matrix()
    return np.asarray(R) @ twist.T, angle


def twist_angles(R: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Twist angles of many rotations about unit axes (:func:`swing_twist`'s angle).

    Parameters
    ----------
    R
        ``(F, 3, 3)`` rotation matrices.
    axis
        ``(3,)`` one unit axis for all, or ``(F, 3)`` one per rotation.

    Returns
    -------
    ``(F,)`` radians in ``[-pi, pi]``: twice the angle of the quaternion's part along the axis.
    """
    from scipy.spatial.transform import Rotation

    q = Rotation.from_matrix(R).as_quat()  # (F, 4) x, y, z, w
    along = np.einsum("fi,fi->f", q[:, :3], np.broadcast_to(axis, q[:, :3].shape))
    angle = 2.0 * np.arctan2(along, q[:, 3])
    return (angle + np.pi) % (2.0 * np.pi) - np.pi


def _min_rotations(a: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``(F, 3, 3)`` the smallest rotations taking the unit ``a (3,)`` to the unit ``v (F, 3)``
    (about ``a x v``); antiparallel: a half turn about an axis perpendicular to ``a``."""
    F = len(v)
    k = np.cross(a, v)  # (F, 3), |k| = sin
    c = v @ a  # (F,) cos
    K = np.zeros((F, 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    K[:, 1, 0], K[:, 2, 0], K[:, 2, 1] = k[:, 2], -k[:, 1], k[:, 0]
    flip = c < -1.0 + 1e-9
    den = np.where(flip, 1.0, 1.0 + c)
    out = np.eye(3) + K + np.einsum("fij,fjk->fik", K, K) / den[:, None, None]
    if flip.any():
        p = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
        p /= np.linalg.norm(p)
        out[flip] = 2.0 * np.outer(p, p) - np.eye(3)
    return out


def minimal_twist(R: np.ndarray, T: np.ndarray, joints_rest: np.ndarray,
                  bone_parent: np.ndarray, rest_points: np.ndarray, labels: np.ndarray,
                  min_elongation: float = 2.0, min_roll_deg: float = 0.0
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Bone transforms with no twist of a limb about its own axis beyond what it had at rest.

    A round limb's rotation about its own axis is a near null mode of a correspondence-free
    fit to one-sided depth data (docs/registration.md): the fitted bones roll by tens of
    degrees while every joint stays in place. This sets, for each non-root bone whose axis is defined and whose points
    are elongated along it, the rotation to its parent's (already corrected) rotation times
    the smallest rotation that gives the axis its fitted direction; the translation keeps the
    head joint in place. The axis runs from the bone's head joint to its only child's head
    joint, or for a leaf to the centroid of its points; bones with several children, the root,
    and bones whose points' spread along the axis is less than ``min_elongation`` times their
    largest spread across it (a torso, a head, a palm: their shape fixes the twist) keep
    their transforms. Every joint trajectory (:func:`joint_trajectories`) is unchanged: each
    bone still carries its head and its child's head to the same places.

    Parameters
    ----------
    R, T
        ``(F, B, 3, 3)`` and ``(F, B, 3)`` bone transforms ``T_frame_rest`` (metres).
    joints_rest
        ``(B, 3)`` head joint of each bone, rest pose, metres.
    bone_parent
        ``(B,)`` parent bone, ``-1`` for the root.
    rest_points
        ``(M, 3)`` rest points, metres.
    labels
        ``(M,)`` bone of each rest point.
    min_elongation
        Spread ratio (standard deviations) above which a bone counts as a limb.
    min_roll_deg
        Only bones whose fitted roll against their parent (about their axis) reaches this
        many degrees at the 90th percentile over the frames are changed (0 = every limb): a
        roll the shape fixes stays, a roll larger than limbs make is taken for the null mode.

    Returns
    -------
    R, T
        The corrected ``(F, B, 3, 3)`` and ``(F, B, 3)`` (new arrays).
    """
    R = np.asarray(R, dtype=np.float64)
    T = np.asarray(T, dtype=np.float64)
    parent = np.asarray(bone_parent, dtype=np.int64)
    joints_rest = np.asarray(joints_rest, dtype=np.float64)
    rest_points = np.asarray(rest_points, dtype=np.float64)
    labels = np.asarray(labels, dtype=np.int64)
    R2, T2 = R.copy(), T.copy()
    for b in tree_order(parent):  # parents first: each child uses its parent's new rotation
        b = int(b)
        p = int(parent[b])
        kids = np.flatnonzero(parent == b)
        pts = rest_points[labels == b]
        if p < 0 or len(kids) > 1 or len(pts) < 3:
            continue
        a = (joints_rest[kids[0]] if len(kids) else pts.mean(0)) - joints_rest[b]
        n = float(np.linalg.norm(a))
        if n <= 1e-9:
            continue
        a = a / n
        X = pts - pts.mean(0)
        along = X @ a
        across = X - along[:, None] * a
        w = np.linalg.eigvalsh(across.T @ across)[-1]  # largest spread across the axis
        if np.sqrt(along @ along) < min_elongation * np.sqrt(max(w, 0.0)):
            continue
        if min_roll_deg > 0:
            rel = np.einsum("fji,fjk->fik", R[:, p], R[:, b])  # fitted, against the parent
            if np.percentile(np.degrees(np.abs(twist_angles(rel, a))), 90) < min_roll_deg:
                continue
        d = np.einsum("fij,j->fi", R[:, b], a)  # the fitted world direction of the axis
        v = np.einsum("fji,fj->fi", R2[:, p], d)  # ... in the parent's (corrected) rest frame
        v /= np.linalg.norm(v, axis=1, keepdims=True)
        Rn = np.einsum("fij,fjk->fik", R2[:, p], _min_rotations(a, v))
        c = joints_rest[b]
        T2[:, b] = np.einsum("fij,j->fi", R[:, b], c) + T[:, b] - np.einsum("fij,j->fi", Rn, c)
        R2[:, b] = Rn
    return R2, T2


def tree_order(bone_parent: np.ndarray) -> np.ndarray:
    """Bone indices in breadth-first order from the root (parents before children)."""
    bone_parent = np.asarray(bone_parent)
    roots = [int(b) for b in np.flatnonzero(bone_parent < 0)]
    order: list[int] = []
    queue = list(roots)
    while queue:
        b = queue.pop(0)
        order.append(b)
        queue.extend(int(c) for c in np.flatnonzero(bone_parent == b))
    missing = [b for b in range(len(bone_parent)) if b not in order]
    return np.array(order + missing, dtype=np.int64)
