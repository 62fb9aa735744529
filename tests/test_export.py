"""BVH export: forward kinematics of the written file reproduces a rigid skeleton's joints."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from pointrig.export import write_bvh
from pointrig.pipeline import build_skeleton


def _parse_bvh(text: str):
    names, parents, offsets, order = [], [], [], []
    stack: list[int] = []
    lines = iter(text.splitlines())
    for line in lines:
        tok = line.split()
        if not tok:
            continue
        if tok[0] in ("ROOT", "JOINT"):
            names.append(tok[1])
            parents.append(stack[-1] if stack else -1)
            order.append(len(names) - 1)
        elif tok[0] == "End":
            next(lines), next(lines), next(lines)  # { OFFSET }
        elif tok[0] == "{":
            stack.append(len(names) - 1)
        elif tok[0] == "}":
            stack.pop()
        elif tok[0] == "OFFSET":
            offsets.append([float(v) for v in tok[1:]])
        elif tok[0] == "MOTION":
            break
    next(lines)
    next(lines)
    motion = np.array([[float(v) for v in ln.split()] for ln in lines if ln.strip()])
    return names, np.array(parents), np.array(offsets), order, motion


def test_bvh_forward_kinematics_matches_rigid_chain(rng):
    # a 4-bone chain with branching: 0 root, 1 child of 0, 2 child of 1, 3 child of 0
    parent = np.array([-1, 0, 1, 0])
    c = np.array([[0, 0, 0], [0.3, 0, 0], [0.6, 0.05, 0], [-0.1, 0.4, 0]], float)
    F = 6
    R = np.zeros((F, 4, 3, 3))
    T = np.zeros((F, 4, 3))
    for t in range(F):
        W = [None] * 4
        pos = [None] * 4
        for j in range(4):
            local = Rotation.from_rotvec(rng.normal(scale=0.4, size=3)).as_matrix()
            if parent[j] < 0:
                W[j] = local
                pos[j] = c[j] + rng.normal(size=3)
            else:
                p = parent[j]
                W[j] = W[p] @ local
                pos[j] = pos[p] + W[p] @ (c[j] - c[p])
            R[t, j] = W[j]
            T[t, j] = pos[j] - W[j] @ c[j]
    skel = build_skeleton(np.zeros((1, 3)), parent, c, R, T, None, None)
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as d:
        write_bvh(Path(d) / "a.bvh", skel)
        names, parents, offsets, order, motion = _parse_bvh((Path(d) / "a.bvh").read_text())
    assert len(names) == 4 and motion.shape == (F, 6 + 3 * 3)
    for t in range(F):
        vals = list(motion[t])
        world = {}
        posd = {}
        for j in order:
            if parents[j] < 0:
                p = np.array(vals[:3])
                vals = vals[3:]
                rot = Rotation.from_euler("ZXY", vals[:3], degrees=True).as_matrix()
                vals = vals[3:]
                world[j], posd[j] = rot, p
            else:
                rot = Rotation.from_euler("ZXY", vals[:3], degrees=True).as_matrix()
                vals = vals[3:]
                world[j] = world[parents[j]] @ rot
                posd[j] = posd[parents[j]] + world[parents[j]] @ offsets[j]
        got = np.array([posd[j] for j in range(4)])
        idx = [skel.joint_names.index(n) for n in names]
        np.testing.assert_allclose(got, skel.joint_positions[t, idx], atol=1e-5)


def _read_glb(path):
    """Minimal independent GLB reader: (json doc, accessor getter)."""
    import json
    import struct

    data = path.read_bytes()
    magic, version, length = struct.unpack_from("<4sII", data, 0)
    assert magic == b"glTF" and version == 2 and length == len(data)
    jlen, jtype = struct.unpack_from("<I4s", data, 12)
    assert jtype == b"JSON" and jlen % 4 == 0
    doc = json.loads(data[20:20 + jlen])
    blen, btype = struct.unpack_from("<I4s", data, 20 + jlen)
    assert btype == b"BIN\x00" and blen % 4 == 0
    binary = data[28 + jlen:28 + jlen + blen]
    ncomp = {"SCALAR": 1, "VEC3": 3, "VEC4": 4, "MAT4": 16}
    dtypes = {5126: np.float32, 5123: np.uint16}

    def acc(i):
        a = doc["accessors"][i]
        v = doc["bufferViews"][a["bufferView"]]
        assert v["byteOffset"] % 4 == 0
        arr = np.frombuffer(binary, dtype=dtypes[a["componentType"]],
                            count=a["count"] * ncomp[a["type"]], offset=v["byteOffset"])
        return arr.reshape(a["count"], -1).astype(np.float64)

    return doc, acc


def _chain_skeleton(rng, F=5):
    """A branching 4-bone articulated chain with random motion and blended point weights."""
    parent = np.array([-1, 0, 1, 0])
    c = np.array([[0, 0, 2.0], [0.3, 0, 2.0], [0.6, 0.05, 2.0], [-0.1, 0.4, 2.0]], float)
    R = np.zeros((F, 4, 3, 3))
    T = np.zeros((F, 4, 3))
    for t in range(F):
        W, pos = [None] * 4, [None] * 4
        for j in range(4):
            local = Rotation.from_rotvec(rng.normal(scale=0.5, size=3)).as_matrix()
            if parent[j] < 0:
                W[j], pos[j] = local, c[j] + rng.normal(scale=0.2, size=3)
            else:
                p = parent[j]
                W[j], pos[j] = W[p] @ local, pos[p] + W[p] @ (c[j] - c[p])
            R[t, j], T[t, j] = W[j], pos[j] - W[j] @ c[j]
    q = c[rng.integers(0, 4, 60)] + rng.normal(scale=0.1, size=(60, 3))
    w = rng.random((60, 4)) ** 3
    w /= w.sum(1, keepdims=True)
    return build_skeleton(q, parent, c, R, T, w, None)


def test_gltf_skinning_and_joints_reproduce_the_skeleton(rng, tmp_path):
    from pointrig.export import write_gltf

    skel = _chain_skeleton(rng)
    fps = 25.0
    write_gltf(tmp_path / "a.glb", skel, fps=fps)
    doc, acc = _read_glb(tmp_path / "a.glb")
    nodes = doc["nodes"]
    parent_of = {ch: i for i, n in enumerate(nodes) for ch in n.get("children", [])}
    anim = doc["animations"][0]
    times = acc(anim["samplers"][0]["input"])[:, 0]
    np.testing.assert_allclose(times, np.arange(skel.n_frames) / fps, atol=1e-6)
    keyed = {}
    for ch in anim["channels"]:
        keyed[(ch["target"]["node"], ch["target"]["path"])] = acc(
            anim["samplers"][ch["sampler"]]["output"])
    skin = doc["skins"][0]
    ibm = acc(skin["inverseBindMatrices"]).reshape(-1, 4, 4).transpose(0, 2, 1)
    mesh = doc["meshes"][0]["primitives"][0]
    assert mesh["mode"] == 0
    pos = acc(mesh["attributes"]["POSITION"])
    jidx = acc(mesh["attributes"]["JOINTS_0"]).astype(int)
    wts = acc(mesh["attributes"]["WEIGHTS_0"])
    np.testing.assert_allclose(wts.sum(1), 1.0, atol=1e-6)
    conv = np.eye(4)
    conv[:3, :3] = Rotation.from_euler("x", 180, degrees=True).as_matrix()
    for t in range(skel.n_frames):
        glob = {}

        def world(n):
            if n in glob:
                return glob[n]
            nd = nodes[n]
            m = np.eye(4)
            if (n, "rotation") in keyed:
                m[:3, :3] = Rotation.from_quat(keyed[(n, "rotation")][t]).as_matrix()
            elif "rotation" in nd:
                m[:3, :3] = Rotation.from_quat(nd["rotation"]).as_matrix()
            if (n, "translation") in keyed:
                m[:3, 3] = keyed[(n, "translation")][t]
            elif "translation" in nd:
                m[:3, 3] = nd["translation"]
            glob[n] = (world(parent_of[n]) @ m) if n in parent_of else m
            return glob[n]

        jm = np.stack([world(n) @ ibm[i] for i, n in enumerate(skin["joints"])])
        # skinned points (viewer) vs pointrig's LBS, both in the glTF (y-up) frame
        viewer = np.einsum("mk,mkab,mb->ma", wts, jm[jidx], np.c_[pos, np.ones(len(pos))])[:, :3]
        lbs = np.einsum("mj,jab,mb->ma", skel.weights, skel.bone_rotations[t],
                        skel.rest_points) + skel.weights @ skel.bone_translations[t]
        # the file keeps the 4 largest weights: all 4 bones here, so exact up to float32
        np.testing.assert_allclose(viewer, lbs @ conv[:3, :3].T, atol=2e-5)
        # joint node origins = the articulated skeleton's joints
        origins = np.stack([world(n)[:3, 3] for n in skin["joints"]])
        np.testing.assert_allclose(origins, skel.joint_positions[t] @ conv[:3, :3].T, atol=2e-5)
