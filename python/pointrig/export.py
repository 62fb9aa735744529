"""Exports that open in animation tools: BVH motion capture files and glTF 2.0 (GLB).

Every export describes one animated skeleton, the one of ``skeleton.json``: joint ``j`` is at
``joint_positions[t, j]`` in frame ``t`` and turned by its bone's rotation ``R_j^t`` (step 3's
``T_frame_rest``). Its *joint frame* is ``G_j^t = [R_j^t | p_j^t]`` relative to the rest joint
``c_j``, i.e. the rigid map ``q -> R_j^t (q - c_j) + p_j^t`` (:func:`joint_transforms`). A
skinned mesh in these files moves by linear blend skinning with these joint frames, so its
vertices follow the joints exactly. They differ from step 3's bone transforms ``(R_j, T_j)``
only by where a joint sits between its two bones: ``p_j`` is the mean of the joint as carried
by its parent bone and by its own bone (:func:`pointrig.kinematics.joint_trajectories`), so
the difference is half the joint's gap, ``|p_j - R_j c_j - T_j|``.

Both files are written y-up, as animation tools expect: the camera's frame is y-down,
z-forward, and a turn of 180 degrees about x (``(x, y, z) -> (x, -y, -z)``, :data:`CAMERA_TO_YUP`)
makes the subject stand upright. The GLB keeps camera coordinates inside a root node
``camera_to_gltf`` that carries this turn; the BVH is written in the turned frame.

A BVH file holds the joint hierarchy with rest offsets (``c_j - c_parent``, turned) and, per
frame, every joint's position relative to its parent joint in the parent's frame and its
rotation relative to the parent's (``ZXY`` Euler angles, degrees). Non-root joints carry
position channels too because the joints of ``skeleton.json`` are not rigidly linked (a bone's
length varies a little between frames); with them, forward kinematics
``p_j = p_parent + W_parent l_j`` reproduces ``joint_positions`` exactly. Blender
(File > Import > Motion Capture, default axes), MotionBuilder and most game-engine importers
read it. Units are the input's (metres). ``Frame Time`` is ``1 / fps``.

The GLB file (:func:`write_gltf`) holds the joints as a node hierarchy with a skin, the rest
points as a skinned point mesh (4 weights per point) and one animation. Every joint node is
keyed per frame with its joint frame ``G_j^t`` (as a rotation and translation relative to its
parent node), and the inverse bind matrices are ``translate(-c_j)``, so a glTF viewer's
skinning ``sum_j w_mj G_j^t IBM_j q_m`` reproduces :func:`joint_transforms`'s LBS exactly (up
to float32). Frame ``t`` is keyed at ``t / fps`` seconds; the frame rate is also stored in
``asset.extras.fps``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .io.atomic import atomic_path
from .skeleton import Skeleton

__all__ = ["CAMERA_TO_YUP", "SurfaceMesh", "joint_transforms", "write_bvh", "write_gltf"]

#: The turn from the camera frame (y down, z forward) to the y-up frame of the exports:
#: 180 degrees about x.
CAMERA_TO_YUP = np.diag([1.0, -1.0, -1.0])


@dataclass
class SurfaceMesh:
    """A skinned triangle mesh in the rest pose (camera frame).

    Attributes
    ----------
    vertices
        ``(V, 3)`` float, metres, rest pose.
    faces
        ``(K, 3)`` int, counter-clockwise seen from outside.
    normals
        ``(V, 3)`` float, unit outward normals.
    weights
        ``(V, J)`` float skinning weights on the skeleton's joints (rows sum to 1).
    """

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    weights: np.ndarray


def joint_transforms(skel: Skeleton) -> tuple[np.ndarray, np.ndarray]:
    """The joint frames as ``T_frame_rest`` transforms: ``(R (F, J, 3, 3), T (F, J, 3))`` with
    ``R = bone_rotations`` and ``T_j^t = p_j^t - R_j^t c_j`` (``p = joint_positions``,
    ``c = rest_positions``, metres, camera frame), so that ``R_j^t c_j + T_j^t = p_j^t``.

    The skinned meshes of the exports move by LBS with these (``kinematics.skin``).

    Raises
    ------
    ValueError
        If the skeleton has no bone rotations.
    """
    if skel.bone_rotations is None:
        raise ValueError("the exports need per-frame bone rotations")
    R = np.asarray(skel.bone_rotations, dtype=float)
    c = np.asarray(skel.rest_positions, dtype=float)
    T = skel.joint_positions - np.einsum("fjab,jb->fja", R, c)
    return R, T


def write_bvh(path: str | Path, skel: Skeleton, fps: float = 30.0) -> None:
    """Write ``skel`` as a y-up BVH file, atomically.

    Parameters
    ----------
    path
        Output ``.bvh`` file.
    skel
        A skeleton with ``bone_rotations (F, J, 3, 3)`` (joint ``j`` = head of bone ``j``)
        and ``joint_positions (F, J, 3)`` metres (camera frame); joints in parent-before-child
        order.
    fps
        Frame rate written as ``Frame Time`` (``1 / fps`` seconds).

    Raises
    ------
    ValueError
        If the skeleton has no bone rotations, its joints are not parent-before-child, or
        ``fps <= 0``.
    """
    from scipy.spatial.transform import Rotation

    if skel.bone_rotations is None:
        raise ValueError("BVH export needs per-frame bone rotations")
    if not fps > 0:
        raise ValueError(f"fps must be positive, got {fps}")
    parents, root = _tree(skel, "BVH")
    J, F = skel.n_joints, skel.n_frames
    children: list[list[int]] = [[] for _ in range(J)]
    for j in range(J):
        if parents[j] >= 0:
            children[parents[j]].append(j)
    C = CAMERA_TO_YUP
    rest = np.asarray(skel.rest_positions, dtype=float) @ C.T
    W = np.einsum("ab,fjbc,cd->fjad", C, np.asarray(skel.bone_rotations, dtype=float), C)
    P = skel.joint_positions @ C.T  # (F, J, 3) y-up
    local = W.copy()
    loc = P.copy()
    for j in range(J):
        p = parents[j]
        if p >= 0:
            local[:, j] = np.einsum("fba,fbc->fac", W[:, p], W[:, j])
            loc[:, j] = np.einsum("fba,fb->fa", W[:, p], P[:, j] - P[:, p])
    eul = Rotation.from_matrix(local.reshape(-1, 3, 3)).as_euler("ZXY", degrees=True)
    eul = eul.reshape(F, J, 3)
    lines = ["HIERARCHY"]
    chans = "CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation"

    def emit(j: int, depth: int) -> None:
        pad = "  " * depth
        is_root = parents[j] < 0
        lines.append(f"{pad}{'ROOT' if is_root else 'JOINT'} {skel.joint_names[j]}")
        off = np.zeros(3) if is_root else rest[j] - rest[parents[j]]
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
    lines += ["MOTION", f"Frames: {F}", f"Frame Time: {1.0 / fps:.8f}"]
    order = _dfs(root, children)
    vals = np.concatenate([loc[:, order], eul[:, order]], axis=2).reshape(F, -1)
    for t in range(F):
        lines.append(" ".join(f"{v:.6f}" for v in vals[t]))
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

_FLOAT, _USHORT, _UINT = 5126, 5123, 5125
#: Rotation (x, y, z, w) of the ``camera_to_gltf`` node: 180 degrees about x.
CAMERA_TO_GLTF = (1.0, 0.0, 0.0, 0.0)


def top_weights(W: np.ndarray, k: int = 4) -> tuple[np.ndarray, np.ndarray]:
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


def write_gltf(path: str | Path, skel: Skeleton, fps: float = 30.0,
               mesh: SurfaceMesh | None = None) -> None:
    """Write ``skel`` as a binary glTF 2.0 file (``.glb``), atomically.

    Parameters
    ----------
    path
        Output ``.glb`` file.
    skel
        A skeleton with ``bone_rotations (F, J, 3, 3)`` and ``joint_positions (F, J, 3)``
        (metres, camera frame; joint ``j`` = head of bone ``j``), joints in parent-before-
        child order. Without ``mesh``, and with ``rest_points (M, 3)`` and ``weights (M, J)``
        (or ``labels (M,)``), the rest points are written as a skinned point mesh.
    fps
        Frame rate: frame ``t`` is keyed at ``t / fps`` seconds.
    mesh
        A skinned triangle surface to write instead of the points.

    Raises
    ------
    ValueError
        If the skeleton has no bone rotations, is not parent-before-child, or ``fps <= 0``.
    """
    import json
    import struct

    from scipy.spatial.transform import Rotation

    if skel.bone_rotations is None:
        raise ValueError("glTF export needs per-frame bone rotations")
    if not fps > 0:
        raise ValueError(f"fps must be positive, got {fps}")
    parents, root = _tree(skel, "glTF")
    J, F = skel.n_joints, skel.n_frames
    c = np.asarray(skel.rest_positions, dtype=float)
    R = np.asarray(skel.bone_rotations, dtype=float)
    pos = np.asarray(skel.joint_positions, dtype=float)  # (F, J, 3) node origins, camera frame
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

    def add(arr: np.ndarray, ctype: int, kind: str, minmax: bool = False,
            target: int | None = None) -> int:
        dtype = {_USHORT: np.uint16, _UINT: np.uint32}.get(ctype, np.float32)
        data = np.ascontiguousarray(arr, dtype=dtype)
        while len(blob) % 4:
            blob.append(0)
        view = {"buffer": 0, "byteOffset": len(blob), "byteLength": data.nbytes}
        if target is not None:
            view["target"] = target
        views.append(view)
        blob.extend(data.tobytes())
        acc = {"bufferView": len(views) - 1, "componentType": ctype,
               "count": int(data.shape[0]), "type": kind}
        if minmax:
            flat = data.reshape(acc["count"], -1)
            acc["min"] = [v.item() for v in flat.min(axis=0)]
            acc["max"] = [v.item() for v in flat.max(axis=0)]
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
        "asset": {"version": "2.0", "generator": "pointrig", "extras": {"fps": float(fps)}},
        "scene": 0,
        "scenes": [{"name": "pointrig", "nodes": [0]}],
        "nodes": nodes,
        "skins": [skin],
        "animations": [{"name": "sequence", "samplers": samplers, "channels": channels,
                        "extras": {"fps": float(fps), "frames": F}}],
    }
    prim: dict | None = None
    if mesh is not None:
        idx, w = top_weights(np.asarray(mesh.weights, dtype=float))
        prim = {"attributes": {
            "POSITION": add(mesh.vertices, _FLOAT, "VEC3", minmax=True, target=34962),
            "NORMAL": add(mesh.normals, _FLOAT, "VEC3", target=34962),
            "JOINTS_0": add(idx, _USHORT, "VEC4", target=34962),
            "WEIGHTS_0": add(w, _FLOAT, "VEC4", target=34962),
        }, "indices": add(np.asarray(mesh.faces, dtype=np.uint32).reshape(-1), _UINT,
                          "SCALAR", minmax=True, target=34963), "mode": 4}
        mesh_name = "surface"
    else:
        W = skel.weights
        if W is None and skel.labels is not None and skel.rest_points is not None:
            W = np.eye(J)[np.asarray(skel.labels)]
        if skel.rest_points is not None and W is not None and len(skel.rest_points) == len(W):
            idx, w = top_weights(np.asarray(W, dtype=float))
            prim = {"attributes": {
                "POSITION": add(np.asarray(skel.rest_points, dtype=float), _FLOAT, "VEC3",
                                minmax=True),
                "JOINTS_0": add(idx, _USHORT, "VEC4"),
                "WEIGHTS_0": add(w, _FLOAT, "VEC4"),
            }, "mode": 0}
        mesh_name = "rest_points"
    if prim is not None:
        doc["meshes"] = [{"name": mesh_name, "primitives": [prim]}]
        nodes.append({"name": mesh_name, "mesh": 0, "skin": 0})
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
