"""Exports that open in animation tools: BVH motion capture files and glTF 2.0 (GLB).

A BVH file holds the joint hierarchy with rest offsets and, per frame, the root position and
every joint's rotation relative to its parent. Blender (File > Import > Motion Capture),
MotionBuilder and most game-engine importers read it. Units are the input's (metres); set the
importer's scale accordingly.

The rotation of joint ``j`` in frame ``t`` is its bone's ``T_frame_rest`` rotation relative to
its parent's: ``L_j^t = (R_parent^t)^T R_j^t`` (``R`` from step 3 or step 2), so forward
kinematics ``p_j = p_parent + W_parent (c_j - c_parent)`` reproduces the joints to within how
far the parent bone's transform moves its child joint (exact for a rigid articulated body).

The GLB file (:func:`write_gltf`) holds the joints as a node hierarchy with a skin, the rest
points as a skinned point mesh (4 weights per point) and one animation. Every joint node is
keyed per frame with the bone's own transform, ``G_j^t = [R_j^t | R_j^t c_j + T_j^t]`` (as a
rotation and translation relative to its parent node), and the inverse bind matrices are
``translate(-c_j)``, so a glTF viewer's skinning ``sum_j w_mj G_j^t IBM_j q_m`` reproduces
pointrig's LBS ``sum_j w_mj (R_j^t q_m + T_j^t)`` exactly (up to float32). glTF is y-up while
depth-camera points are y-down, z-forward: a parent node ``camera_to_gltf`` turns the scene by
180 degrees about x, so the subject stands upright in Blender, Godot, Unity or three.js.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .io.atomic import atomic_path
from .skeleton import Skeleton

__all__ = ["write_bvh", "write_gltf"]


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
    parents, root = _tree(skel, "BVH")
    J, F = skel.n_joints, skel.n_frames
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

    emit(root, 0)
    lines += ["MOTION", f"Frames: {F}", f"Frame Time: {1.0 / fps:.6f}"]
    W = skel.bone_rotations  # (F, J, 3, 3) world rotation of each joint frame vs rest
    local = W.copy()
    for j in range(J):
        if parents[j] >= 0:
            local[:, j] = np.einsum("fji,fjk->fik", W[:, parents[j]], W[:, j])
    eul = Rotation.from_matrix(local.reshape(-1, 3, 3)).as_euler("ZXY", degrees=True)
    eul = eul.reshape(F, J, 3)
    for t in range(F):
        vals = list(skel.joint_positions[t, root])
        for j in _dfs(root, children):
            vals += list(eul[t, j])
        lines.append(" ".join(f"{v:.6f}" for v in vals))
    with atomic_path(path) as tmp:
        tmp.write_text("\n".join(lines) + "\n")


def _tree(skel: Skeleton, fmt: str) -> tuple[np.ndarray, int]:
    """``(parents (J,), root)`` after checking what both exporters need: joints ordered
    parent before child and exactly one root."""
    parents = np.asarray(skel.parents)
    if any(parents[j] >= j for j in range(len(parents))):
        raise ValueError("joints must be ordered parent before child")
    roots = np.flatnonzero(parents < 0)
    if len(roots) != 1:
        raise ValueError(f"{fmt} export needs exactly one root joint, found {len(roots)}")
    return parents, int(roots[0])


def _dfs(root: int, children: list[list[int]]) -> list[int]:
    out, stack = [], [root]
    while stack:
        j = stack.pop()
        out.append(j)
        stack.extend(reversed(children[j]))
    return out


# --------------------------------------------------------------------------- glTF 2.0 (GLB)

_FLOAT, _USHORT = 5126, 5123
#: Rotation (x, y, z, w) of the ``camera_to_gltf`` node: 180 degrees about x.
CAMERA_TO_GLTF = (1.0, 0.0, 0.0, 0.0)


def _top_weights(W: np.ndarray, k: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` largest weights per row, renormalised: ``(idx (M, k) uint16, w (M, k))``."""
    M, B = W.shape
    if B < k:
        W = np.concatenate([W, np.zeros((M, k - B))], axis=1)
    idx = np.argsort(-W, axis=1, kind="stable")[:, :k]
    w = np.take_along_axis(W, idx, axis=1)
    s = w.sum(axis=1, keepdims=True)
    w = np.where(s > 0, w / np.where(s > 0, s, 1.0), 0.0)
    w[s[:, 0] <= 0, 0] = 1.0
    idx = np.where(w > 0, idx, 0)
    return idx.astype(np.uint16), w


def write_gltf(path: str | Path, skel: Skeleton, fps: float = 30.0) -> None:
    """Write ``skel`` as a binary glTF 2.0 file (``.glb``), atomically.

    Parameters
    ----------
    path
        Output ``.glb`` file.
    skel
        A skeleton with ``bone_rotations (F, J, 3, 3)`` and ``bone_translations (F, J, 3)``
        (``T_frame_rest``, metres; joint ``j`` = head of bone ``j``), joints in parent-before-
        child order. With ``rest_points (M, 3)`` and ``weights (M, J)`` (or ``labels (M,)``)
        the rest points are written as a skinned point mesh.
    fps
        Frame rate: frame ``t`` is keyed at ``t / fps`` seconds.

    Raises
    ------
    ValueError
        If the skeleton has no bone transforms, is not parent-before-child, or ``fps <= 0``.
    """
    import json
    import struct

    from scipy.spatial.transform import Rotation

    if skel.bone_rotations is None or skel.bone_translations is None:
        raise ValueError("glTF export needs per-frame bone rotations and translations")
    if not fps > 0:
        raise ValueError(f"fps must be positive, got {fps}")
    parents, root = _tree(skel, "glTF")
    J, F = skel.n_joints, skel.n_frames
    c = np.asarray(skel.rest_positions, dtype=float)
    R = np.asarray(skel.bone_rotations, dtype=float)
    T = np.asarray(skel.bone_translations, dtype=float)
    pos = np.einsum("fjab,jb->fja", R, c) + T  # (F, J, 3) node origins, camera frame
    loc_r = R.copy()
    loc_t = pos.copy()
    for j in range(J):
        p = parents[j]
        if p >= 0:
            loc_r[:, j] = np.einsum("fba,fbc->fac", R[:, p], R[:, j])
            loc_t[:, j] = np.einsum("fba,fb->fa", R[:, p], pos[:, j] - pos[:, p])
    quat = Rotation.from_matrix(loc_r.reshape(-1, 3, 3)).as_quat().reshape(F, J, 4)
    # keep consecutive keys in the same hemisphere so viewers interpolate the short way
    for t in range(1, F):
        flip = np.einsum("ja,ja->j", quat[t], quat[t - 1]) < 0
        quat[t, flip] *= -1.0

    blob = bytearray()
    views: list[dict] = []
    accessors: list[dict] = []

    def add(arr: np.ndarray, ctype: int, kind: str, minmax: bool = False) -> int:
        data = np.ascontiguousarray(arr, dtype=np.uint16 if ctype == _USHORT else np.float32)
        while len(blob) % 4:
            blob.append(0)
        views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": data.nbytes})
        blob.extend(data.tobytes())
        acc = {"bufferView": len(views) - 1, "componentType": ctype,
               "count": int(data.shape[0]), "type": kind}
        if minmax:
            flat = data.reshape(data.shape[0], -1)
            acc["min"] = [float(v) for v in flat.min(axis=0)]
            acc["max"] = [float(v) for v in flat.max(axis=0)]
        accessors.append(acc)
        return len(accessors) - 1

    names = list(skel.joint_names)
    nodes: list[dict] = [{"name": "camera_to_gltf", "rotation": list(CAMERA_TO_GLTF),
                          "children": [1 + root]}]
    for j in range(J):
        rest_t = c[j] if parents[j] < 0 else c[j] - c[parents[j]]
        node = {"name": names[j], "translation": [float(v) for v in rest_t]}
        kids = [1 + int(k) for k in np.flatnonzero(parents == j)]
        if kids:
            node["children"] = kids
        nodes.append(node)

    times = add(np.arange(F, dtype=float) / fps, _FLOAT, "SCALAR", minmax=True)
    samplers, channels = [], []
    for j in range(J):
        for path_, arr, kind in (("rotation", quat[:, j], "VEC4"),
                                 ("translation", loc_t[:, j], "VEC3")):
            samplers.append({"input": times, "output": add(arr, _FLOAT, kind),
                             "interpolation": "LINEAR"})
            channels.append({"sampler": len(samplers) - 1,
                             "target": {"node": 1 + j, "path": path_}})

    ibm = np.broadcast_to(np.eye(4), (J, 4, 4)).copy()
    ibm[:, :3, 3] = -c
    skin = {"joints": [1 + j for j in range(J)],
            "inverseBindMatrices": add(np.transpose(ibm, (0, 2, 1)).reshape(J, 16), _FLOAT,
                                       "MAT4"),
            "skeleton": 0}
    doc: dict = {
        "asset": {"version": "2.0", "generator": "pointrig"},
        "scene": 0,
        "scenes": [{"name": "pointrig", "nodes": [0]}],
        "nodes": nodes,
        "skins": [skin],
        "animations": [{"name": "sequence", "samplers": samplers, "channels": channels}],
    }
    W = skel.weights
    if W is None and skel.labels is not None and skel.rest_points is not None:
        W = np.eye(J)[np.asarray(skel.labels)]
    if skel.rest_points is not None and W is not None and len(skel.rest_points) == len(W):
        idx, w = _top_weights(np.asarray(W, dtype=float))
        prim = {"attributes": {
            "POSITION": add(np.asarray(skel.rest_points, dtype=float), _FLOAT, "VEC3",
                            minmax=True),
            "JOINTS_0": add(idx, _USHORT, "VEC4"),
            "WEIGHTS_0": add(w, _FLOAT, "VEC4"),
        }, "mode": 0}
        doc["meshes"] = [{"name": "rest_points", "primitives": [prim]}]
        nodes.append({"name": "rest_points", "mesh": 0, "skin": 0})
        nodes[0]["children"].append(len(nodes) - 1)
    while len(blob) % 4:
        blob.append(0)
    doc["buffers"] = [{"byteLength": len(blob)}]
    doc["bufferViews"] = views
    doc["accessors"] = accessors
    js = json.dumps(doc, separators=(",", ":")).encode()
    js += b" " * (-len(js) % 4)
    out = bytearray()
    out += struct.pack("<4sII", b"glTF", 2, 12 + 8 + len(js) + 8 + len(blob))
    out += struct.pack("<I4s", len(js), b"JSON") + js
    out += struct.pack("<I4s", len(blob), b"BIN\x00") + bytes(blob)
    with atomic_path(path) as tmp:
        tmp.write_bytes(bytes(out))
