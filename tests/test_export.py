"""BVH and GLB exports: read back independently, they reproduce skeleton.json's joints."""

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


#: the y-up turn of the exports, written out here: 180 degrees about x
YUP = np.diag([1.0, -1.0, -1.0])


def _bvh_world_joints(names, parents, offsets, order, motion):
    """Forward kinematics of a parsed BVH whose joints all have 6 channels (position, then
    ZXY rotation): ``(F, J, 3)`` world joint positions in file order."""
    F, J = len(motion), len(names)
    out = np.zeros((F, J, 3))
    for t in range(F):
        vals = motion[t].reshape(J, 6)
        world = {}
        for k, j in enumerate(order):
            rot = Rotation.from_euler("ZXY", vals[k, 3:], degrees=True).as_matrix()
            if parents[j] < 0:
                world[j] = rot
                out[t, j] = vals[k, :3]
            else:
                p = parents[j]
                world[j] = world[p] @ rot
                out[t, j] = out[t, p] + world[p] @ vals[k, :3]
    return out


def test_bvh_forward_kinematics_reproduces_skeleton_json_y_up(rng, tmp_path):
    """Non-rigid joints (each joint between its two bones' predictions): the BVH's forward
    kinematics equal skeleton.json's joint_positions turned y-up, at every frame, and its rest
    offsets are the turned rest joints."""
    import json

    skel = _chain_skeleton(rng, F=7, gap=0.02)
    skel.save_json(tmp_path / "skeleton.json")
    write_bvh(tmp_path / "a.bvh", skel, fps=25.0)
    text = (tmp_path / "a.bvh").read_text()
    names, parents, offsets, order, motion = _parse_bvh(text)
    assert "Frame Time: 0.04000000" in text
    assert len(names) == 4 and motion.shape == (7, 4 * 6)
    doc = json.loads((tmp_path / "skeleton.json").read_text())
    jp = np.array(doc["joint_positions"])
    idx = [[j["name"] for j in doc["joints"]].index(n) for n in names]
    got = _bvh_world_joints(names, parents, offsets, order, motion)
    np.testing.assert_allclose(got, jp[:, idx] @ YUP.T, atol=1e-5)
    rest = np.array([j["rest_position"] for j in doc["joints"]])[idx] @ YUP.T
    for j in range(1, 4):
        np.testing.assert_allclose(offsets[j], rest[j] - rest[parents[j]], atol=1e-6)
    # the rigid joints of a gap-free chain are reproduced as well (the old contract)
    rigid = _chain_skeleton(rng, F=4, gap=0.0)
    write_bvh(tmp_path / "b.bvh", rigid)
    parsed = _parse_bvh((tmp_path / "b.bvh").read_text())
    idx = [rigid.joint_names.index(n) for n in parsed[0]]
    np.testing.assert_allclose(_bvh_world_joints(*parsed), rigid.joint_positions[:, idx] @ YUP.T,
                               atol=1e-5)


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


def _chain_skeleton(rng, F=5, gap=0.0):
    """A branching 4-bone articulated chain with random motion and blended point weights;
    ``gap > 0`` moves every bone off the rigid chain by about that many metres, so a joint's
    two bones disagree on it (as step 3's bones do)."""
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
            R[t, j], T[t, j] = W[j], pos[j] - W[j] @ c[j] + rng.normal(scale=gap, size=3)
    q = c[rng.integers(0, 4, 60)] + rng.normal(scale=0.1, size=(60, 3))
    w = rng.random((60, 4)) ** 3
    w /= w.sum(1, keepdims=True)
    return build_skeleton(q, parent, c, R, T, w, None)


def test_gltf_skinning_and_joints_reproduce_the_skeleton(rng, tmp_path):
    from pointrig.export import joint_transforms, write_gltf
    from pointrig.kinematics import skin as lbs_skin

    skel = _chain_skeleton(rng, gap=0.02)
    fps = 25.0
    # the joints are not where step 3's bones carry them (else this checks nothing new)
    own = np.einsum("fjab,jb->fja", skel.bone_rotations, skel.rest_positions) \
        + skel.bone_translations
    assert np.abs(own - skel.joint_positions).max() > 0.005
    write_gltf(tmp_path / "a.glb", skel, fps=fps)
    doc, acc = _read_glb(tmp_path / "a.glb")
    assert doc["asset"]["extras"]["fps"] == fps
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
        Rj, Tj = joint_transforms(skel)
        lbs = lbs_skin(skel.rest_points, skel.weights, Rj[t:t + 1], Tj[t:t + 1])[0]
        # the file keeps the 4 largest weights: all 4 bones here, so exact up to float32
        np.testing.assert_allclose(viewer, lbs @ conv[:3, :3].T, atol=2e-5)
        # joint node origins = the articulated skeleton's joints
        origins = np.stack([world(n)[:3, 3] for n in skin["joints"]])
        np.testing.assert_allclose(origins, skel.joint_positions[t] @ conv[:3, :3].T, atol=2e-5)
