"""Shared helpers for the synth tests: a tiny rigged, animated GLB written from scratch."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np


def _pad4(b: bytes, fill: bytes = b"\x00") -> bytes:
    return b + fill * ((4 - len(b) % 4) % 4)


def _write_glb(path: str | Path, doc: dict, body: bytes) -> None:
    """A GLB container (JSON chunk, then the binary chunk) of ``doc`` and ``body``."""
    js = _pad4(json.dumps(doc).encode(), b" ")
    total = 12 + 8 + len(js) + 8 + len(body)
    out = struct.pack("<4sII", b"glTF", 2, total)
    out += struct.pack("<II", len(js), 0x4E4F534A) + js
    out += struct.pack("<II", len(body), 0x004E4942) + body
    Path(path).write_bytes(out)


def write_two_bone_glb(path: Path, angle_deg: float = 90.0, interpolation: str = "LINEAR",
                       duration: float = 1.0) -> dict:
    """A vertical two-bone strip: joint 0 at the origin, joint 1 at (0, 1, 0); the strip spans
    y in [0, 2] (x in [-0.1, 0.1], z = 0). Vertices with y <= 1 follow joint 0, above follow
    joint 1. Joint 1 rotates about +z from 0 to ``angle_deg`` over ``duration`` seconds; joint
    0 translates from (0,0,0) to (0.5,0,0). Returns the geometry for oracles.
    """
    ys = np.array([0.0, 0.5, 1.0, 1.5, 2.0])
    verts = []
    for y in ys:
        verts += [[-0.1, y, 0.0], [0.1, y, 0.0]]
    verts = np.array(verts, dtype=np.float32)
    tris = []
    for i in range(len(ys) - 1):
        a, b, c, d = 2 * i, 2 * i + 1, 2 * i + 2, 2 * i + 3
        tris += [[a, b, c], [b, d, c]]
    tris = np.array(tris, dtype=np.uint16)
    joints = np.zeros((len(verts), 4), dtype=np.uint8)
    joints[:, 0] = (verts[:, 1] > 1.0).astype(np.uint8)
    weights = np.zeros((len(verts), 4), dtype=np.float32)
    weights[:, 0] = 1.0
    # bind globals: joint0 at origin, joint1 at (0,1,0) -> IBM = inverse (translation only)
    ibm = np.stack([np.eye(4), np.eye(4)]).astype(np.float32)
    ibm[1, 1, 3] = -1.0
    ibm_colmajor = np.transpose(ibm, (0, 2, 1)).copy()
    times = np.array([0.0, duration], dtype=np.float32)
    half = np.radians(angle_deg) / 2
    rot = np.array([[0, 0, 0, 1], [0, 0, np.sin(half), np.cos(half)]], dtype=np.float32)
    trans = np.array([[0, 0, 0], [0.5, 0, 0]], dtype=np.float32)
    blobs = [verts.tobytes(), tris.tobytes(), joints.tobytes(), weights.tobytes(),
             ibm_colmajor.tobytes(), times.tobytes(), rot.tobytes(), trans.tobytes()]
    views, offset, body = [], 0, b""
    for blob in blobs:
        views.append({"buffer": 0, "byteOffset": offset, "byteLength": len(blob)})
        padded = _pad4(blob)
        body += padded
        offset += len(padded)
    acc = [
        {"bufferView": 0, "componentType": 5126, "count": len(verts), "type": "VEC3",
         "min": verts.min(0).tolist(), "max": verts.max(0).tolist()},
        {"bufferView": 1, "componentType": 5123, "count": tris.size, "type": "SCALAR"},
        {"bufferView": 2, "componentType": 5121, "count": len(verts), "type": "VEC4"},
        {"bufferView": 3, "componentType": 5126, "count": len(verts), "type": "VEC4"},
        {"bufferView": 4, "componentType": 5126, "count": 2, "type": "MAT4"},
        {"bufferView": 5, "componentType": 5126, "count": 2, "type": "SCALAR",
         "min": [0.0], "max": [duration]},
        {"bufferView": 6, "componentType": 5126, "count": 2, "type": "VEC4"},
        {"bufferView": 7, "componentType": 5126, "count": 2, "type": "VEC3"},
    ]
    doc = {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0, 2]}],
        "nodes": [
            {"name": "root", "children": [1]},
            {"name": "tip", "translation": [0.0, 1.0, 0.0]},
            {"name": "strip", "mesh": 0, "skin": 0},
        ],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "JOINTS_0": 2,
                                                   "WEIGHTS_0": 3}, "indices": 1}]}],
        "skins": [{"joints": [0, 1], "inverseBindMatrices": 4}],
        "animations": [{"name": "bend", "samplers": [
            {"input": 5, "output": 6, "interpolation": interpolation},
            {"input": 5, "output": 7, "interpolation": interpolation}],
            "channels": [{"sampler": 0, "target": {"node": 1, "path": "rotation"}},
                         {"sampler": 1, "target": {"node": 0, "path": "translation"}}]}],
        "accessors": acc,
        "bufferViews": views,
        "buffers": [{"byteLength": len(body)}],
    }
    _write_glb(path, doc, body)
    return {"verts": verts.astype(np.float64), "tris": tris.astype(np.int64),
            "upper": verts[:, 1] > 1.0}


def expected_two_bone(verts: np.ndarray, upper: np.ndarray, u: float, angle_deg: float
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Analytic vertex and joint positions of :func:`write_two_bone_glb` at fraction ``u`` of
    the clip with linear interpolation (slerp of a single-axis rotation is linear in angle)."""
    th = np.radians(angle_deg) * u
    c, s = np.cos(th), np.sin(th)
    Rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    shift = np.array([0.5 * u, 0.0, 0.0])
    out = verts.copy()
    pivot = np.array([0.0, 1.0, 0.0])
    out[upper] = (verts[upper] - pivot) @ Rz.T + pivot
    out += shift
    joints = np.array([[0.0, 0.0, 0.0], [0.0, 1.0, 0.0]]) + shift
    return out, joints


def write_split_two_bone_glb(path: Path, mode: str, angle_deg: float = 90.0) -> dict:
    """The strip of :func:`write_two_bone_glb` (same animation) exported as two meshes: the
    lower half (y <= 1) skinned to the root joint, the upper half (y >= 1.5) either skinned by
    a second skin that lists only the tip joint (``mode="skins"``) or a mesh node without a
    skin, child of the tip joint's node, with its vertices in the tip's frame
    (``mode="rigid"``). Returns the vertices in bind space (lower first) and the upper mask."""
    if mode not in ("skins", "rigid"):
        raise ValueError(mode)
    lower = np.array([[x, y, 0.0] for y in (0.0, 0.5, 1.0) for x in (-0.1, 0.1)],
                     dtype=np.float32)
    upper = np.array([[x, y, 0.0] for y in (1.5, 2.0) for x in (-0.1, 0.1)], dtype=np.float32)
    tl = np.array([[0, 1, 2], [1, 3, 2], [2, 3, 4], [3, 5, 4]], dtype=np.uint16)
    tu = np.array([[0, 1, 2], [1, 3, 2]], dtype=np.uint16)
    j_lo = np.zeros((len(lower), 4), dtype=np.uint8)
    j_up = np.zeros((len(upper), 4), dtype=np.uint8)
    w_lo = np.zeros((len(lower), 4), dtype=np.float32)
    w_lo[:, 0] = 1.0
    w_up = w_lo[: len(upper)].copy()
    ibm0 = np.stack([np.eye(4), np.eye(4)]).astype(np.float32)
    ibm0[1, 1, 3] = -1.0
    ibm1 = ibm0[1:].copy()
    up_pos = upper if mode == "skins" else upper - np.array([0, 1, 0], dtype=np.float32)
    times = np.array([0.0, 1.0], dtype=np.float32)
    half = np.radians(angle_deg) / 2
    rot = np.array([[0, 0, 0, 1], [0, 0, np.sin(half), np.cos(half)]], dtype=np.float32)
    trans = np.array([[0, 0, 0], [0.5, 0, 0]], dtype=np.float32)
    blobs = [lower, tl, j_lo, w_lo, np.transpose(ibm0, (0, 2, 1)).copy(), up_pos, tu, j_up, w_up,
             np.transpose(ibm1, (0, 2, 1)).copy(), times, rot, trans]
    views, offset, body = [], 0, b""
    for blob in blobs:
        raw = np.ascontiguousarray(blob).tobytes()
        views.append({"buffer": 0, "byteOffset": offset, "byteLength": len(raw)})
        padded = _pad4(raw)
        body += padded
        offset += len(padded)
    kinds = [(5126, "VEC3"), (5123, "SCALAR"), (5121, "VEC4"), (5126, "VEC4"), (5126, "MAT4"),
             (5126, "VEC3"), (5123, "SCALAR"), (5121, "VEC4"), (5126, "VEC4"), (5126, "MAT4"),
             (5126, "SCALAR"), (5126, "VEC4"), (5126, "VEC3")]
    counts = [len(lower), tl.size, len(lower), len(lower), 2, len(upper), tu.size, len(upper),
              len(upper), 1, 2, 2, 2]
    acc = [{"bufferView": i, "componentType": c, "count": n, "type": t}
           for i, ((c, t), n) in enumerate(zip(kinds, counts))]
    nodes = [{"name": "root", "children": [1]}, {"name": "tip", "translation": [0.0, 1.0, 0.0]},
             {"name": "lower", "mesh": 0, "skin": 0}]
    prim_up = {"attributes": {"POSITION": 5}, "indices": 6}
    if mode == "skins":
        prim_up["attributes"].update({"JOINTS_0": 7, "WEIGHTS_0": 8})
        nodes.append({"name": "upper", "mesh": 1, "skin": 1})
        roots = [0, 2, 3]
    else:
        nodes[1]["children"] = [3]
        nodes.append({"name": "upper", "mesh": 1})
        roots = [0, 2]
    doc = {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": roots}],
        "nodes": nodes,
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "JOINTS_0": 2,
                                                   "WEIGHTS_0": 3}, "indices": 1}]},
                   {"primitives": [prim_up]}],
        "skins": [{"joints": [0, 1], "inverseBindMatrices": 4},
                  {"joints": [1], "inverseBindMatrices": 9}],
        "animations": [{"name": "bend", "samplers": [
            {"input": 10, "output": 11}, {"input": 10, "output": 12}],
            "channels": [{"sampler": 0, "target": {"node": 1, "path": "rotation"}},
                         {"sampler": 1, "target": {"node": 0, "path": "translation"}}]}],
        "accessors": acc,
        "bufferViews": views,
        "buffers": [{"byteLength": len(body)}],
    }
    _write_glb(path, doc, body)
    verts = np.concatenate([lower, upper]).astype(np.float64)
    return {"verts": verts, "upper": verts[:, 1] > 1.0}
