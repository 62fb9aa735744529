"""Checks of an output folder against real readers: Blender (through tests/blender_check.py in
.venv-blender) and pygltflib. Used by tests/test_rig.py; ``python tests/rig_helpers.py OUT``
prints the figures of any output folder (the demo's, a suite sequence's)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
BLENDER_PY = ROOT / ".venv-blender" / "bin" / "python"
#: camera frame (y down, z forward) -> Blender's world (z up) after either import with default
#: axes: the exports' y-up turn, then the importers' y-up -> z-up turn
CAMERA_TO_BLENDER = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])


def blender_report(out: Path, fps: float, frames: list[int]) -> dict:
    """Run tests/blender_check.py on ``out`` in Blender's Python module.

    Raises
    ------
    AssertionError
        With the reason, when .venv-blender or its bpy is missing or the import fails.
    """
    if not BLENDER_PY.exists():
        raise AssertionError(
            f"Blender's Python module is not installed: {BLENDER_PY} is missing; run "
            "`bash scripts/setup.sh` (it installs bpy from constraints-blender.txt, ~1 GB)")
    proc = subprocess.run(
        [str(BLENDER_PY), str(ROOT / "tests" / "blender_check.py"), str(out), str(fps),
         *[str(f) for f in frames]], capture_output=True, text=True, timeout=600)
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("BLENDER-JSON ")]
    if proc.returncode != 0 or not lines:
        raise AssertionError(f"Blender check failed (exit {proc.returncode}):\n"
                             f"{proc.stderr[-3000:]}")
    return json.loads(lines[-1][len("BLENDER-JSON "):])


def compare_with_blender(out: Path, frames: list[int] | None = None) -> dict:
    """Figures of Blender's import of ``out`` against skeleton.json and pointrig's skinning:
    ``{"bones", "frames", "gltf_frames", "bvh_frames", "gltf_joint_mm", "bvh_joint_mm",
    "mesh_mm", "blender"}`` (largest errors, millimetres, over the checked frames)."""
    from pointrig.export import joint_transforms
    from pointrig.kinematics import skin
    from pointrig.skeleton import load_skeleton_json

    sk = load_skeleton_json(out / "skeleton.json")
    F = sk.n_frames
    frames = frames if frames is not None else sorted({0, F // 2, F - 1})
    rep = blender_report(out, sk.fps or 30.0, frames)
    fig: dict = {"blender": rep["blender"], "bones": sk.n_joints, "frames": F}
    for kind in ("gltf", "bvh"):
        r = rep[kind]
        assert sorted(r["bones"]) == sorted(sk.joint_names), (kind, r["bones"])
        lo, hi = r["frame_range"]
        fig[f"{kind}_frames"] = int(round(hi - lo)) + 1
        err = 0.0
        for t in frames:
            heads = r["heads"][str(t)]
            got = np.array([heads[n] for n in sk.joint_names])
            want = sk.joint_positions[t] @ CAMERA_TO_BLENDER.T
            err = max(err, float(np.abs(got - want).max()))
        fig[f"{kind}_joint_mm"] = 1000 * err
    # the mesh: Blender's vertices matched to the file's by their rest positions
    mesh = read_rig_glb(out / "rig.glb")
    rest_b = np.array(rep["gltf"]["rest_vertices"])
    from scipy.spatial import cKDTree

    d, order = cKDTree(rest_b).query(mesh["vertices"] @ CAMERA_TO_BLENDER.T)
    assert d.max() < 1e-4, f"Blender's rest mesh differs from the file's by {d.max()} m"
    sk.bone_rotations = np.load(out / "weights.npz")["bone_rotations"]
    R, T = joint_transforms(sk)
    err = 0.0
    for t in frames:
        ours = skin(mesh["vertices"], mesh["weights"], R[t:t + 1], T[t:t + 1])[0]
        got = np.array(rep["gltf"]["deformed"][str(t)])[order]
        err = max(err, float(np.abs(got - ours @ CAMERA_TO_BLENDER.T).max()))
    fig["mesh_mm"] = 1000 * err
    return fig


def read_rig_glb(path: Path) -> dict:
    """The skinned mesh of ``rig.glb`` read with pygltflib: ``vertices (V, 3)``,
    ``normals (V, 3)``, ``faces (K, 3)``, dense ``weights (V, J)`` (camera frame), and the
    document and an accessor reader for structural checks."""
    from pygltflib import GLTF2

    g = GLTF2().load(str(path))
    blob = g.binary_blob()
    ncomp = {"SCALAR": 1, "VEC3": 3, "VEC4": 4, "MAT4": 16}
    dtypes = {5126: np.float32, 5125: np.uint32, 5123: np.uint16, 5121: np.uint8}

    def acc(i: int) -> np.ndarray:
        a = g.accessors[i]
        v = g.bufferViews[a.bufferView]
        n = ncomp[a.type]
        arr = np.frombuffer(blob, dtype=dtypes[a.componentType], count=a.count * n,
                            offset=(v.byteOffset or 0) + (a.byteOffset or 0))
        return arr.reshape(a.count, n)

    prim = g.meshes[0].primitives[0]
    V = acc(prim.attributes.POSITION).astype(float)
    J = len(g.skins[0].joints)
    idx = acc(prim.attributes.JOINTS_0).astype(int)
    w = acc(prim.attributes.WEIGHTS_0).astype(float)
    dense = np.zeros((len(V), J))
    for k in range(idx.shape[1]):
        np.add.at(dense, (np.arange(len(V)), idx[:, k]), w[:, k])
    return {"gltf": g, "acc": acc, "prim": prim, "vertices": V,
            "normals": acc(prim.attributes.NORMAL).astype(float),
            "faces": acc(prim.indices).reshape(-1, 3).astype(int), "weights": dense,
            "joint_slots": idx, "weight_slots": w}


def main(argv: list[str]) -> None:
    out = Path(argv[0])
    from pointrig.rig import surface_distances

    fig = compare_with_blender(out)
    mesh = read_rig_glb(out / "rig.glb")
    rest = np.load(out / "weights.npz")["rest_points"]
    d = surface_distances(rest, mesh["vertices"], mesh["faces"])
    fig.update(faces=len(mesh["faces"]), vertices=len(mesh["vertices"]),
               surface_mean_mm=1000 * float(d.mean()),
               surface_p95_mm=1000 * float(np.percentile(d, 95)))
    timings = json.loads((out / "skeleton.json").read_text())["params"]["timings_s"]
    fig["rig_s"] = timings.get("rig")
    print(json.dumps(fig, indent=1))


if __name__ == "__main__":
    main(sys.argv[1:])
