"""What Blender sees in pointrig's outputs: run by Blender's Python module (``bpy``), prints JSON.

    .venv-blender/bin/python tests/blender_check.py OUT_DIR FPS FRAME [FRAME ...]

Imports ``OUT_DIR/rig.glb`` (File > Import > glTF 2.0) and ``OUT_DIR/skeleton.bvh`` (File >
Import > Motion Capture) with default options into an empty scene whose frame rate is ``FPS``
(as the README tells users), and reports for each: the armature's bone names, the action's
frame range, and at each given frame (0-based, the first frame of the animation is 0) the
bones' head positions in world coordinates; for the glTF also the skinned mesh's rest
vertices and the vertices Blender deforms (world coordinates, Blender's z-up frame).
tests/test_rig.py compares them with skeleton.json and pointrig's own skinning.
"""

from __future__ import annotations

import json
import sys

import bpy


def _reset(fps: float) -> None:
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.fps = round(fps)
    scene.render.fps_base = round(fps) / fps


def _armature():
    arms = [o for o in bpy.context.scene.objects if o.type == "ARMATURE"]
    assert len(arms) == 1, f"expected one armature, found {len(arms)}"
    return arms[0]


def _action_range(arm) -> list[float]:
    act = arm.animation_data.action
    return [float(v) for v in act.frame_range]


def _heads(arm, frames: list[float]) -> dict[str, dict[str, list[float]]]:
    scene = bpy.context.scene
    out = {}
    for f in frames:
        scene.frame_set(int(round(f)))
        out[str(f)] = {pb.name: list(arm.matrix_world @ pb.head) for pb in arm.pose.bones}
    return out


def check_gltf(path: str, fps: float, frames: list[int]) -> dict:
    _reset(fps)
    bpy.ops.import_scene.gltf(filepath=path)
    arm = _armature()
    rng = _action_range(arm)
    at = [rng[0] + t for t in frames]
    # skinned meshes only (the importer adds a bone-display shape too)
    meshes = [o for o in bpy.context.scene.objects if o.type == "MESH"
              and any(m.type == "ARMATURE" for m in o.modifiers)]
    assert len(meshes) == 1, f"expected one skinned mesh, found {len(meshes)}"
    mesh = meshes[0]
    rest = [list(mesh.matrix_world @ v.co) for v in mesh.data.vertices]
    deformed = {}
    scene = bpy.context.scene
    for t, f in zip(frames, at):
        scene.frame_set(int(round(f)))
        dg = bpy.context.evaluated_depsgraph_get()
        ev = mesh.evaluated_get(dg)
        me = ev.to_mesh()
        deformed[str(t)] = [list(ev.matrix_world @ v.co) for v in me.vertices]
        ev.to_mesh_clear()
    return {"bones": [b.name for b in arm.data.bones], "frame_range": rng,
            "heads": {str(t): h for t, h in zip(frames, _heads(arm, at).values())},
            "rest_vertices": rest, "deformed": deformed,
            "scene_fps": scene.render.fps / scene.render.fps_base}


def check_bvh(path: str, fps: float, frames: list[int]) -> dict:
    _reset(fps)
    bpy.ops.import_anim.bvh(filepath=path)
    arm = _armature()
    rng = _action_range(arm)
    at = [rng[0] + t for t in frames]
    return {"bones": [b.name for b in arm.data.bones], "frame_range": rng,
            "heads": {str(t): h for t, h in zip(frames, _heads(arm, at).values())}}


def main(argv: list[str]) -> None:
    out, fps, frames = argv[0], float(argv[1]), [int(v) for v in argv[2:]]
    report = {"blender": bpy.app.version_string,
              "gltf": check_gltf(f"{out}/rig.glb", fps, frames),
              "bvh": check_bvh(f"{out}/skeleton.bvh", fps, frames)}
    print("BLENDER-JSON " + json.dumps(report))


if __name__ == "__main__":
    main(sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else sys.argv[1:])
