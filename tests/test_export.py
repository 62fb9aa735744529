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
