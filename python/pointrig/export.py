"""Exports that open in animation tools: BVH motion capture files.

A BVH file holds the joint hierarchy with rest offsets and, per frame, the root position and
every joint's rotation relative to its parent. Blender (File > Import > Motion Capture),
MotionBuilder and most game-engine importers read it. Units are the input's (metres); set the
importer's scale accordingly.

The rotation of joint ``j`` in frame ``t`` is its bone's ``T_frame_rest`` rotation relative to
its parent's: ``L_j^t = (R_parent^t)^T R_j^t`` (``R`` from step 3 or step 2), so forward
kinematics ``p_j = p_parent + W_parent (c_j - c_parent)`` reproduces the joints to within how
far the parent bone's transform moves its child joint (exact for a rigid articulated body).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .io.atomic import atomic_path
from .skeleton import Skeleton

__all__ = ["write_bvh"]


def write_bvh(path: str | Path, skel: Skeleton, fps: float = 30.0) -> None:
    """Write ``skel`` as a BVH file, atomically.

    Parameters
    ----------
    path
        Output ``.bvh`` file.
    skel
        A skeleton with ``bone_rotations (F, J, 3, 3)`` (joint ``j`` = head of bone ``j``)
        and ``joint_positions (F, J, 3)`` metres; joints in parent-before-child order.
    fps
        Frame rate written as ``Frame Time``.

    Raises
    ------
    ValueError
        If the skeleton has no bone rotations or its joints are not parent-before-child.
    """
    from scipy.spatial.transform import Rotation

    if skel.bone_rotations is None:
        raise ValueError("BVH export needs per-frame bone rotations")
    parents = skel.parents
    J, F = skel.n_joints, skel.n_frames
    if any(parents[j] >= j for j in range(J)):
        raise ValueError("joints must be ordered parent before child")
    children: list[list[int]] = [[] for _ in range(J)]
    for j in range(1, J):
        children[parents[j]].append(j)
    rest = skel.rest_positions
    lines = ["HIERARCHY"]

    def emit(j: int, depth: int) -> None:
        pad = "  " * depth
        if parents[j] < 0:
            lines.append(f"{pad}ROOT {skel.joint_names[j]}")
            off = np.zeros(3)
            chans = "CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation"
        else:
            lines.append(f"{pad}JOINT {skel.joint_names[j]}")
            off = rest[j] - rest[parents[j]]
            chans = "CHANNELS 3 Zrotation Xrotation Yrotation"
        lines.append(pad + "{")
        lines.append(f"{pad}  OFFSET {off[0]:.6f} {off[1]:.6f} {off[2]:.6f}")
        lines.append(f"{pad}  {chans}")
        for c in children[j]:
            emit(c, depth + 1)
        if not children[j]:
            lines.append(f"{pad}  End Site")
            lines.append(f"{pad}  {{")
            lines.append(f"{pad}    OFFSET 0.000000 0.000000 0.000000")
            lines.append(f"{pad}  }}")
        lines.append(pad + "}")

    roots = [j for j in range(J) if parents[j] < 0]
    if len(roots) != 1:
        raise ValueError(f"BVH needs exactly one root joint, found {len(roots)}")
    emit(roots[0], 0)
    lines += ["MOTION", f"Frames: {F}", f"Frame Time: {1.0 / fps:.6f}"]
    W = skel.bone_rotations  # (F, J, 3, 3) world rotation of each joint frame vs rest
    local = W.copy()
    for j in range(J):
        if parents[j] >= 0:
            local[:, j] = np.einsum("fji,fjk->fik", W[:, parents[j]], W[:, j])
    eul = Rotation.from_matrix(local.reshape(-1, 3, 3)).as_euler("ZXY", degrees=True)
    eul = eul.reshape(F, J, 3)
    root = roots[0]
    for t in range(F):
        vals = list(skel.joint_positions[t, root])
        for j in _dfs(roots[0], children):
            vals += list(eul[t, j])
        lines.append(" ".join(f"{v:.6f}" for v in vals))
    with atomic_path(path) as tmp:
        tmp.write_text("\n".join(lines) + "\n")


def _dfs(root: int, children: list[list[int]]) -> list[int]:
    out, stack = [], [root]
    while stack:
        j = stack.pop()
        out.append(j)
        stack.extend(reversed(children[j]))
    return out
