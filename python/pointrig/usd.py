"""The rig as UsdSkel (``rig.usda``): the skeleton, the skinned surface and the animation.

Needs the ``usd`` extra (``pip install 'pointrig[usd]'``: usd-core, Pixar's USD library).

The stage is y-up, metres (``metersPerUnit = 1``), ``timeCodesPerSecond = fps`` with frame
``t`` at time code ``t``. Coordinates are the camera frame turned by
:data:`pointrig.export.CAMERA_TO_YUP` (``C``). Prims:

- ``/Rig`` (SkelRoot) holding ``/Rig/Skeleton`` (the joints as paths ``root/spine_1/...``;
  bind transforms ``translate(C c_j)``, rest transforms the rest offsets), its animation
  ``/Rig/Skeleton/Motion`` (per frame each joint's rotation and translation relative to its
  parent: the joint frames of :func:`pointrig.export.joint_transforms`, turned) and
- ``/Rig/Surface`` (Mesh) bound to the skeleton with 4 joint weights per vertex.

UsdSkel's skinning of the mesh is then ``sum_j w_j C (R_j (v - c_j) + p_j)``: pointrig's LBS
with the joint frames, turned, and its joints are ``C joint_positions``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .errors import PointrigError
from .export import CAMERA_TO_YUP, SurfaceMesh, _tree, top_weights
from .io.atomic import atomic_path
from .skeleton import Skeleton

__all__ = ["usd_available", "write_usd"]

_EXTRA = "rig.usda needs the usd extra: pip install 'pointrig[usd]'"


def usd_available(mode: str) -> bool:
    """Whether usd-core is importable; ``mode`` ``"on"`` makes its absence an error,
    ``"off"`` answers ``False``.

    Raises
    ------
    PointrigError
        With ``mode == "on"`` and usd-core missing.
    """
    from .rig import extra_available

    return extra_available(mode, ("pxr.UsdSkel",), _EXTRA)


def _joint_paths(names: list[str], parents: np.ndarray) -> list[str]:
    paths: list[str] = []
    for j, n in enumerate(names):
        paths.append(n if parents[j] < 0 else f"{paths[parents[j]]}/{n}")
    return paths


def write_usd(path: str | Path, skel: Skeleton, mesh: SurfaceMesh, fps: float = 30.0) -> None:
    """Write the skeleton, its skinned surface and animation as a UsdSkel stage, atomically.

    Parameters
    ----------
    path
        Output ``.usda`` (text) or ``.usdc`` (binary) file.
    skel
        A skeleton with ``bone_rotations (F, J, 3, 3)`` and ``joint_positions (F, J, 3)``
        (metres, camera frame), joints parent before child; names must be valid USD
        identifiers after replacing other characters by ``_``.
    mesh
        The rest-pose surface with ``(V, J)`` weights.
    fps
        Frame rate, Hz: frame ``t`` at time code ``t``, ``timeCodesPerSecond = fps``.

    Raises
    ------
    PointrigError
        Without usd-core.
    ValueError
        If the skeleton has no bone rotations or is not parent-before-child.
    """
    import re

    try:
        from pxr import Gf, Usd, UsdGeom, UsdSkel, Vt
    except ImportError:
        raise PointrigError(_EXTRA) from None
    from scipy.spatial.transform import Rotation

    if skel.bone_rotations is None:
        raise ValueError("USD export needs per-frame bone rotations")
    parents, _ = _tree(skel, "USD")
    J, F = skel.n_joints, skel.n_frames
    C = CAMERA_TO_YUP
    c = np.asarray(skel.rest_positions, dtype=float) @ C.T
    Rw = np.einsum("ab,fjbc,cd->fjad", C, np.asarray(skel.bone_rotations, dtype=float), C)
    P = np.asarray(skel.joint_positions, dtype=float) @ C.T
    loc_r, loc_t = Rw.copy(), P.copy()
    for j in range(J):
        p = parents[j]
        if p >= 0:
            loc_r[:, j] = np.einsum("fba,fbc->fac", Rw[:, p], Rw[:, j])
            loc_t[:, j] = np.einsum("fba,fb->fa", Rw[:, p], P[:, j] - P[:, p])
    quat = Rotation.from_matrix(loc_r.reshape(-1, 3, 3)).as_quat().reshape(F, J, 4)  # xyzw
    names = [re.sub(r"[^A-Za-z0-9_]", "_", n) or "joint" for n in skel.joint_names]
    names = [("_" + n) if n[0].isdigit() else n for n in names]
    joints = _joint_paths(names, parents)

    def mat(t: np.ndarray) -> Gf.Matrix4d:
        m = Gf.Matrix4d(1.0)
        m.SetTranslateOnly(Gf.Vec3d(*(float(v) for v in t)))
        return m

    with atomic_path(path) as tmp:
        stage = Usd.Stage.CreateNew(str(tmp))
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
        UsdGeom.SetStageMetersPerUnit(stage, 1.0)
        stage.SetTimeCodesPerSecond(float(fps))
        stage.SetFramesPerSecond(float(fps))
        stage.SetStartTimeCode(0)
        stage.SetEndTimeCode(max(F - 1, 0))
        root = UsdSkel.Root.Define(stage, "/Rig")
        stage.SetDefaultPrim(root.GetPrim())
        sk = UsdSkel.Skeleton.Define(stage, "/Rig/Skeleton")
        sk.CreateJointsAttr(Vt.TokenArray(joints))
        sk.CreateJointNamesAttr(Vt.TokenArray(list(skel.joint_names)))
        sk.CreateBindTransformsAttr(Vt.Matrix4dArray([mat(c[j]) for j in range(J)]))
        rest_local = [c[j] if parents[j] < 0 else c[j] - c[parents[j]] for j in range(J)]
        sk.CreateRestTransformsAttr(Vt.Matrix4dArray([mat(v) for v in rest_local]))
        anim = UsdSkel.Animation.Define(stage, "/Rig/Skeleton/Motion")
        anim.CreateJointsAttr(Vt.TokenArray(joints))
        t_attr = anim.CreateTranslationsAttr()
        r_attr = anim.CreateRotationsAttr()
        anim.CreateScalesAttr(Vt.Vec3hArray([Gf.Vec3h(1, 1, 1)] * J))
        for t in range(F):
            t_attr.Set(Vt.Vec3fArray([Gf.Vec3f(*(float(v) for v in loc_t[t, j]))
                                      for j in range(J)]), Usd.TimeCode(t))
            r_attr.Set(Vt.QuatfArray([Gf.Quatf(float(q[3]), float(q[0]), float(q[1]),
                                               float(q[2])) for q in quat[t]]),
                       Usd.TimeCode(t))
        UsdSkel.BindingAPI.Apply(sk.GetPrim()).CreateAnimationSourceRel().SetTargets(
            [anim.GetPath()])
        m = UsdGeom.Mesh.Define(stage, "/Rig/Surface")
        v = np.asarray(mesh.vertices, dtype=float) @ C.T
        n = np.asarray(mesh.normals, dtype=float) @ C.T
        f = np.asarray(mesh.faces, dtype=np.int64)
        m.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(v.astype(np.float32)))
        m.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(n.astype(np.float32)))
        m.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
        m.CreateFaceVertexCountsAttr(Vt.IntArray([3] * len(f)))
        m.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(f.reshape(-1).astype(np.int32)))
        m.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)
        m.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        lo, hi = v.min(axis=0), v.max(axis=0)
        m.CreateExtentAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, lo)), Gf.Vec3f(*map(float, hi))]))
        idx, w = top_weights(np.asarray(mesh.weights, dtype=float))
        bind = UsdSkel.BindingAPI.Apply(m.GetPrim())
        bind.CreateSkeletonRel().SetTargets([sk.GetPath()])
        bind.CreateJointIndicesPrimvar(False, 4).Set(
            Vt.IntArray.FromNumpy(idx.reshape(-1).astype(np.int32)))
        bind.CreateJointWeightsPrimvar(False, 4).Set(
            Vt.FloatArray.FromNumpy(w.reshape(-1).astype(np.float32)))
        bind.CreateGeomBindTransformAttr(Gf.Matrix4d(1.0))
        stage.GetRootLayer().Save()
        del stage
