"""The whole method: registration (§4) -> skeletal structure (§5) -> joint learning (§6).

:func:`extract` runs the steps with a registration checkpoint (reused when the input and the
step-1 parameters match, so changing a later step's parameter does not redo step 1) and
writes the outputs atomically:

- ``skeleton.json``  the ``pointrig.skeleton/1`` contract (see the README);
- ``weights.npz``    rest points, skinning weights ``(M, B)``, labels, bone transforms;
- ``registration.npz``  the step-1 checkpoint;
- ``skeleton.bvh``   the animated skeleton as motion capture (Blender, MotionBuilder);
- ``skeleton.glb``   glTF 2.0: joints, skin, the rest points as a skinned point mesh and the
  animation (Blender, Godot, Unity, three.js), see :func:`pointrig.export.write_gltf`;
- ``rig.glb``        the skinned surface of the subject on the same joints (``[rig] mesh``,
  the ``rig`` extra; :mod:`pointrig.rig`); ``rig.usda`` the same as UsdSkel (``[rig] usd``,
  the ``usd`` extra; :mod:`pointrig.usd`);
- ``skeleton.png``, ``skeleton.gif``  pictures (optional).

The output stage that turns step 3's bones into the written skeleton (joint selection,
output tree, splits, joint depth, bone rolls) is :mod:`pointrig.output`;
:func:`output_skeleton` and :func:`build_skeleton` are re-exported here.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from .config import PipelineConfig
from .errors import PointrigError
from .export import write_bvh, write_gltf
from .naming import apply_names, read_name_mapping
from .output import build_skeleton, output_skeleton
from .preprocess import remove_sparse_frames
from .rig import rig_available
from .sequence import PointSequence, check_units
from .skeleton import Skeleton
from .usd import usd_available

__all__ = ["ExtractResult", "build_skeleton", "extract", "output_skeleton"]

log = logging.getLogger(__name__)

#: progress(step, done, total, detail)
Progress = Callable[[str, int, int, str], None]
StopAfter = Literal["registration", "structure", "joints"]


@dataclass
class ExtractResult:
    """What :func:`extract` produced."""

    skeleton: Skeleton | None
    registration: Any
    structure: Any = None
    joints: Any = None
    timings: dict[str, float] = field(default_factory=dict)
    reused_registration: bool = False
    files: dict[str, Path] = field(default_factory=dict)
    #: the last :func:`pointrig.registration.refine_registration` result (``refine_rounds``
    #: > 0 and step 3 run), else ``None``
    refined_registration: Any = None
    #: ``(F,)`` fraction of each input frame's points removed as sparse before step 1
    #: (``[preprocess] sparse_ratio``)
    sparse_removed: np.ndarray | None = None
    #: the ``F`` observed clouds ``(N_t, 3)`` after that clean-up, as steps 1-3 and the
    #: joint-depth pass read them (metres)
    frames: list[np.ndarray] | None = None
    #: ``(mesh, stats)`` of ``rig.glb`` (:func:`pointrig.rig.build_surface`) when written
    rig: tuple[Any, Any] | None = None


def extract(
    seq: PointSequence,
    config: PipelineConfig | None = None,
    out_dir: str | Path | None = None,
    *,
    resume: bool = True,
    stop_after: StopAfter = "joints",
    pictures: bool = True,
    progress: Progress | None = None,
    bone_names: str | Path | None = None,
) -> ExtractResult:
    """Run the pipeline on a sequence and (if ``out_dir``) write the outputs.

    Parameters
    ----------
    seq
        The input frames, ``(N_t, 3)`` metres each.
    config
        All parameters (default: Table 1 defaults and pointrig's improvements).
    out_dir
        Output folder; ``None`` writes nothing.
    resume
        Reuse ``out_dir/registration.npz`` when its key (input + step-1 parameters) matches.
    stop_after
        ``"registration"``, ``"structure"`` (write the step-2 skeleton) or ``"joints"``.
    pictures
        Also write ``skeleton.png`` and ``skeleton.gif``.
    progress
        Called as ``progress(step, done, total, detail)``.
    bone_names
        A JSON file ``{joint name: new name}`` renaming joints after ``[rig] names``
        (:func:`pointrig.naming.apply_names`).

    Raises
    ------
    InputError
        When a frame spans more than ``config.preprocess.max_extent`` metres (input not in
        metres, :func:`pointrig.sequence.check_units`), before anything is written.
    """
    config = config or PipelineConfig()
    check_units(seq, config.preprocess.max_extent)
    mapping = None if bone_names is None else read_name_mapping(bone_names)
    with_rig = out_dir is not None and stop_after == "joints" and rig_available(config.rig.mesh)
    with_usd = with_rig and usd_available(config.rig.usd)
    out = None if out_dir is None else Path(out_dir)
    timings: dict[str, float] = {}
    n_input = [int(c) for c in seq.counts]
    seq, removed = _clean_input(seq, config, timings)
    reg, reused, ckpt = _step1(seq, config, out, resume, timings, progress)
    result = ExtractResult(None, reg, timings=timings, reused_registration=reused,
                           sparse_removed=removed, frames=list(seq.frames))
    if ckpt is not None:
        result.files["registration"] = ckpt
    if stop_after == "registration":
        return result
    st = _step2(reg.rest_points, reg.points, config, timings, progress, "bones")
    result.structure = st
    if stop_after == "structure":
        weights = np.eye(len(st.bone_parent))[st.labels]
        labels, joints_rest, R, T = st.labels, st.joints_rest, st.R, st.T
    else:
        st, jr, refined = _step3_with_refinement(seq, reg, st, config, timings, progress)
        result.structure, result.refined_registration, result.joints = st, refined, jr
        weights, labels = jr.weights, np.argmax(jr.weights, axis=1)
        joints_rest, R, T = jr.joints_rest, jr.R, jr.T
    final = result.refined_registration or reg
    result.skeleton = output_skeleton(
        reg.rest_points, labels, st.bone_parent, joints_rest, R, T, weights, config,
        st.view_camera, observed=(seq.frames, final.points) if stop_after == "joints" else None,
        timings=timings)
    result.skeleton.fps = config.rig.fps / config.preprocess.frame_stride
    apply_names(result.skeleton, config.rig.names, mapping, bone_names or "--bone-names")
    if out is not None:
        _write_outputs(out, seq, reg, result, config, stop_after, n_input, pictures, with_rig,
                       with_usd)
    return result


def _report(progress: Progress | None, step: str) -> Callable[[int, int], None]:
    """``progress`` as a step's ``(done, total)`` callback (a no-op without ``progress``)."""
    return lambda done, total: progress(step, done, total, "") if progress else None


def _clean_input(seq: PointSequence, config: PipelineConfig, timings: dict[str, float]
                 ) -> tuple[PointSequence, np.ndarray]:
    """Input clean-up: sparse points (flying pixels, outliers) out of every frame
    (:func:`pointrig.preprocess.remove_sparse_frames`); the cleaned sequence and the ``(F,)``
    fraction of each frame's points removed. Its seconds go to ``timings["clean-up"]``."""
    t0 = time.perf_counter()
    seq, removed = remove_sparse_frames(seq, config.preprocess.sparse_neighbors,
                                        config.preprocess.sparse_ratio)
    timings["clean-up"] = time.perf_counter() - t0
    if removed.any():
        log.info("removed %.1f %% of the points as sparse (most %.1f %%, frame %d)",
                 100 * removed.mean(), 100 * removed.max(), int(np.argmax(removed)))
    return seq, removed


def _step1(seq: PointSequence, config: PipelineConfig, out: Path | None, resume: bool,
           timings: dict[str, float], progress: Progress | None) -> tuple[Any, bool, Path | None]:
    """Step 1, registration (§4), with its checkpoint ``out/registration.npz``: reused when its
    key (input + step-1 parameters) matches and ``resume``, else computed and written. Returns
    the registration, whether it was reused, and the checkpoint's path (``None`` without
    ``out``). Its seconds go to ``timings["registration"]``."""
    from . import registration as reg_mod

    t0 = time.perf_counter()
    reg = None
    ckpt = None if out is None else out / "registration.npz"
    if resume and ckpt is not None and ckpt.exists():
        try:
            cached = reg_mod.RegistrationResult.load(ckpt)
            if cached.key == reg_mod.cache_key(seq, config.registration):
                reg = cached
                log.info("reusing registration checkpoint %s", ckpt)
        except Exception as exc:  # noqa: BLE001 - a stale or damaged checkpoint is recomputed
            log.warning("ignoring registration checkpoint %s: %s", ckpt, exc)
    reused = reg is not None
    if reg is None:
        reg = reg_mod.register_sequence(seq, config.registration,
                                        progress=_report(progress, "registration"))
        if ckpt is not None:
            reg.save(ckpt)
    timings["registration"] = time.perf_counter() - t0
    return reg, reused, ckpt


def _step2(rest_points: np.ndarray, points: np.ndarray, config: PipelineConfig,
           timings: dict[str, float], progress: Progress | None, detail: str) -> Any:
    """Step 2, skeletal structure (§5), on the rest points ``(M, 3)`` and their registered
    positions ``(F, M, 3)`` (metres); its seconds are added to ``timings["structure"]`` and
    the bone count reported with ``detail``."""
    from . import structure as struct_mod

    t0 = time.perf_counter()
    st = struct_mod.extract_structure(rest_points, points, config.structure)
    timings["structure"] = timings.get("structure", 0.0) + time.perf_counter() - t0
    if progress:
        progress("structure", 1, 1, f"{len(st.bone_parent)} {detail}")
    return st


def _step3_with_refinement(seq: PointSequence, reg: Any, st: Any, config: PipelineConfig,
                           timings: dict[str, float], progress: Progress | None
                           ) -> tuple[Any, Any, Any]:
    """Step 3, joint learning (§6), then ``[registration] refine_rounds`` rounds of
    refinement from the skeleton: re-register with the posed rest points
    (:func:`pointrig.registration.refine_registration`), redo step 2 and step 3 on it.
    Returns the last structure, joints result and refined registration (``None`` without
    rounds); seconds go to ``timings["joints"]``, ``["refinement"]`` and ``["structure"]``."""
    from . import joints as joints_mod
    from . import registration as reg_mod

    rest_index = reg.params.get("rest_frame_index") if reg.params else None

    def step3(r: Any, structure: Any) -> Any:
        t0 = time.perf_counter()
        out3 = joints_mod.learn_joints(
            seq.frames, r.rest_points, r.points, structure, config.joints,
            progress=_report(progress, "joints"), rest_index=None if rest_index is None
            else int(rest_index), track_progress=_report(progress, "tracking"))
        timings["joints"] = timings.get("joints", 0.0) + time.perf_counter() - t0
        return out3

    jr = step3(reg, st)
    refined = None
    for rnd in range(config.registration.refine_rounds):
        t0 = time.perf_counter()
        posed = joints_mod.posed_rest_points(reg.rest_points, st.labels, jr.R, jr.T)
        refined = reg_mod.refine_registration(seq, reg, posed, config.registration,
                                              progress=_report(progress, f"refinement {rnd + 1}"))
        timings["refinement"] = timings.get("refinement", 0.0) + time.perf_counter() - t0
        st = _step2(refined.rest_points, refined.points, config, timings, progress,
                    "bones (refined)")
        jr = step3(refined, st)
    return st, jr, refined


def _write_outputs(out: Path, seq: PointSequence, reg: Any, result: ExtractResult,
                   config: PipelineConfig, stop_after: StopAfter, n_input: list[int],
                   pictures: bool, with_rig: bool = False, with_usd: bool = False) -> None:
    """Write ``result.skeleton`` into ``out``: ``skeleton.json`` (with the input's description
    and every parameter), ``weights.npz``, ``skeleton.bvh``, ``skeleton.glb``, with
    ``with_rig`` the skinned surface ``rig.glb`` (and with ``with_usd`` ``rig.usda``; their
    seconds in ``timings["rig"]``; a surface that cannot be built is skipped with a warning
    under ``[rig] mesh = "auto"``) and, with ``pictures``, ``skeleton.png``, ``skeleton.gif``
    (and ``rig.png``: the surface in three poses); the paths go to ``result.files``."""
    skel = result.skeleton
    fps = skel.fps or 30.0
    if with_rig:
        from .rig import build_surface

        t0 = time.perf_counter()
        final = result.refined_registration or reg
        rest_frame = int((reg.params or {}).get("rest_frame_index", -1))
        try:
            result.rig = build_surface(skel, config.rig, result.frames, final.points,
                                       rest_frame)
        except PointrigError as exc:
            if config.rig.mesh == "on":
                raise
            log.warning("rig.glb not written: %s", exc)
        if result.rig is not None:
            write_gltf(out / "rig.glb", skel, fps=fps, mesh=result.rig[0])
            result.files["rig"] = out / "rig.glb"
            if with_usd:
                from .usd import write_usd

                write_usd(out / "rig.usda", skel, result.rig[0], fps=fps)
                result.files["usd"] = out / "rig.usda"
        result.timings["rig"] = time.perf_counter() - t0
    source = {"input": str(seq.source), "format": seq.fmt, "frames": len(seq),
              "points_per_frame": n_input,
              "points_used_per_frame": [int(c) for c in seq.counts],
              "rest_frame": int((reg.params or {}).get("rest_frame_index", -1)),
              "stopped_after": stop_after, **seq.meta}
    params = config.to_dict()
    params["timings_s"] = {k: round(v, 3) for k, v in result.timings.items()}
    skel.save_json(out / "skeleton.json", source=source, params=params)
    skel.save_weights(out / "weights.npz")
    write_bvh(out / "skeleton.bvh", skel, fps=fps)
    write_gltf(out / "skeleton.glb", skel, fps=fps)
    result.files["skeleton"] = out / "skeleton.json"
    result.files["weights"] = out / "weights.npz"
    result.files["bvh"] = out / "skeleton.bvh"
    result.files["gltf"] = out / "skeleton.glb"
    if pictures:
        _write_pictures(out, seq, result.refined_registration or reg, skel)
        result.files["png"] = out / "skeleton.png"
        result.files["gif"] = out / "skeleton.gif"
        if result.rig is not None:
            from .export import joint_transforms
            from .viz import save_rig_png

            mesh = result.rig[0]
            R, T = joint_transforms(skel)
            save_rig_png(out / "rig.png", mesh.vertices, mesh.faces, mesh.weights, R, T,
                         skel.joint_positions, skel.parents)
            result.files["rig_png"] = out / "rig.png"


def _write_pictures(out: Path, seq: PointSequence, reg: Any, skel: Skeleton) -> None:
    """Skeleton over the registered points coloured by bone (PNG) and the animation (GIF)."""
    from .viz import palette, save_sequence_gif, save_skeleton_png

    cols = palette(max(skel.n_joints, 1))
    labels = skel.labels if skel.labels is not None else np.zeros(len(reg.rest_points), int)
    pc = [cols[labels]] * len(seq)
    frames = [reg.points[t] for t in range(len(seq))]
    save_skeleton_png(out / "skeleton.png", frames, skel.joint_positions, skel.parents,
                      point_colors=pc)
    save_sequence_gif(out / "skeleton.gif", frames, skel.joint_positions, skel.parents,
                      point_colors=pc)
