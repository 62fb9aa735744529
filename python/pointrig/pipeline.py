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
- ``skeleton.png``, ``skeleton.gif``  pictures (optional).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from .config import PipelineConfig
from .export import write_bvh, write_gltf
from .kinematics import joint_trajectories, minimal_twist, tree_order
from .preprocess import remove_sparse_frames
from .sequence import PointSequence, check_units
from .skeleton import Skeleton
from .view import view_depth_joints

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


def build_skeleton(rest_points: np.ndarray, bone_parent: np.ndarray, joints_rest: np.ndarray,
                   R: np.ndarray, T: np.ndarray, weights: np.ndarray | None,
                   labels: np.ndarray | None) -> Skeleton:
    """Assemble a :class:`Skeleton` with joints in parent-before-child order.

    Joint ``b`` is the head of bone ``b`` (see :mod:`pointrig.kinematics`); skeleton bones
    are the segments parent joint -> child joint.
    """
    order = tree_order(bone_parent)
    inv = np.empty_like(order)
    inv[order] = np.arange(len(order))
    parents = np.array([inv[bone_parent[b]] if bone_parent[b] >= 0 else -1 for b in order])
    jr = joints_rest[order]
    Ro, To = R[:, order], T[:, order]
    jp = joint_trajectories(jr, Ro, To, parents)
    non_root = [j for j in range(len(order)) if parents[j] >= 0]
    return Skeleton(
        joint_names=[f"j{j}" for j in range(len(order))],
        parents=parents,
        rest_positions=jr,
        joint_positions=jp,
        bone_heads=np.array([parents[j] for j in non_root], dtype=np.int64),
        bone_tails=np.array(non_root, dtype=np.int64),
        bone_rotations=Ro,
        bone_translations=To,
        weights=None if weights is None else weights[:, order],
        rest_points=rest_points,
        labels=None if labels is None else inv[labels],
        bone_names=[f"b{j}" for j in non_root],
    )


def _split_weights(weights: np.ndarray, labels: np.ndarray, source: np.ndarray) -> np.ndarray:
    """``(M, B')`` skinning weights after :func:`pointrig.structure.split_bent_leaves` or
    :func:`pointrig.structure.split_disconnected_bones`: each new bone ``b >= B`` takes its
    source bone's weight of the points now labelled ``b`` (the two move alike, so the skinned
    points do not change)."""
    W = np.asarray(weights, dtype=float)
    B = W.shape[1]
    out = np.zeros((W.shape[0], len(source)))
    out[:, :B] = W
    for b in range(B, len(source)):
        moved = labels == b
        out[moved, b] = W[moved, source[b]]
        out[moved, source[b]] = 0.0
    return out


def output_skeleton(rest_points: np.ndarray, labels: np.ndarray, bone_parent: np.ndarray,
                    joints_rest: np.ndarray, R: np.ndarray, T: np.ndarray,
                    weights: np.ndarray | None, config: PipelineConfig,
                    view_camera: np.ndarray | None,
                    observed: tuple[Sequence[np.ndarray], np.ndarray] | None = None,
                    timings: dict[str, float] | None = None) -> Skeleton:
    """The skeleton as :func:`extract` outputs it, from step 2's or step 3's bones.

    The one place of the output stage, so that a benchmark that reruns step 3 on cached
    inputs scores what the pipeline writes: after step 3 (``observed`` given) first the joints
    the raw frames support (:func:`pointrig.selection.select_joints`, ``[structure]
    joint_penalty``), then the output tree (a leaf root moves to the body's
    centre, :func:`pointrig.structure.output_tree`), then, after step 3 (``observed`` given),
    one bone per separate piece of a bone that carries two subtrees
    (:func:`pointrig.structure.split_disconnected_bones`, ``[structure] split_disconnected``)
    and a joint where a leaf bone bends (:func:`pointrig.structure.split_bent_leaves`,
    ``[structure] leaf_split_*``; the new bones take their source bone's motion), the joints
    to their parts' axis depth along the camera ray (``[joints] joint_depth``,
    :func:`pointrig.view.view_depth_joints`) and the bones' rolls
    (``[joints] bone_twist``, :func:`pointrig.kinematics.minimal_twist`), then
    :func:`build_skeleton`.

    Parameters
    ----------
    rest_points
        ``(M, 3)`` rest points, metres.
    labels
        ``(M,)`` bone of each rest point.
    bone_parent
        ``(B,)`` parent bone, ``-1`` for the root.
    joints_rest
        ``(B, 3)`` rest-pose head joint of each bone, metres.
    R, T
        ``(F, B, 3, 3)`` and ``(F, B, 3)``: ``T_frame_rest`` of every bone per frame, metres.
    weights
        ``(M, B)`` skinning weights, or ``None``.
    config
        The pipeline's parameters (``structure`` and ``joints`` are read).
    view_camera
        ``(3,)`` camera position (metres) when the input is one view, else ``None`` (no depth
        pass).
    observed
        After step 3: ``(frames, registered)``, the ``F`` observed clouds ``(N_t, 3)`` and the
        final registration's ``(F, M, 3)`` points (metres) that the depth pass reads; ``None``
        for a step-2 skeleton (output tree only).
    timings
        If given, the depth pass's seconds are stored under ``"joint_depth"``.
    """
    from . import structure as struct_mod
    from .selection import select_joints

    if observed is not None and config.structure.joint_penalty > 0:
        t0 = time.perf_counter()
        sel = select_joints(observed[0], rest_points, labels, bone_parent, R, T,
                            penalty_scale=config.structure.joint_penalty,
                            max_frames=config.structure.joint_frames)
        if sel.removed:
            log.info("removed %d of %d joints the raw frames do not support",
                     len(sel.removed), len(bone_parent))
        labels, bone_parent, R, T = sel.labels, sel.bone_parent, sel.R, sel.T
        joints_rest = np.asarray(joints_rest)[sel.keep]
        if weights is not None:
            weights = sel.merge_weights(weights)
        if timings is not None:
            timings["joint_selection"] = time.perf_counter() - t0
    parent, joints_rest = struct_mod.output_tree(rest_points, labels, bone_parent, joints_rest,
                                                 config.structure, view_camera)
    if observed is not None:
        # new bones take their source bone's motion and weights: first the separate pieces
        # of a bone, then the bends of the leaves
        for split in (struct_mod.split_disconnected_bones, struct_mod.split_bent_leaves):
            labels, parent, joints_rest, source = split(rest_points, labels, parent,
                                                        joints_rest, observed[1],
                                                        config.structure)
            if len(source) > R.shape[1]:
                R, T = R[:, source], T[:, source]
                if weights is not None:
                    weights = _split_weights(weights, labels, source)
    if observed is not None and config.joints.joint_depth == "chord" \
            and view_camera is not None:
        t0 = time.perf_counter()
        joints_rest, _ = view_depth_joints(
            observed[0], observed[1], labels, parent, joints_rest, R, T, view_camera,
            n_frames=config.joints.depth_frames)
        if timings is not None:
            timings["joint_depth"] = time.perf_counter() - t0
    if observed is not None and config.joints.bone_twist == "minimal":
        R, T = minimal_twist(R, T, joints_rest, parent, rest_points, labels,
                             config.joints.twist_min_elongation,
                             config.joints.twist_min_roll_deg)
    return build_skeleton(rest_points, parent, joints_rest, R, T, weights, labels)


def extract(
    seq: PointSequence,
    config: PipelineConfig | None = None,
    out_dir: str | Path | None = None,
    *,
    resume: bool = True,
    stop_after: StopAfter = "joints",
    pictures: bool = True,
    progress: Progress | None = None,
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

    Raises
    ------
    InputError
        When a frame spans more than ``config.preprocess.max_extent`` metres (input not in
        metres, :func:`pointrig.sequence.check_units`), before anything is written.
    """
    from . import joints as joints_mod
    from . import registration as reg_mod
    from . import structure as struct_mod

    config = config or PipelineConfig()
    check_units(seq, config.preprocess.max_extent)
    out = None if out_dir is None else Path(out_dir)
    timings: dict[str, float] = {}
    n_input = [int(c) for c in seq.counts]

    # ---- input clean-up: sparse points (flying pixels, outliers) out of every frame -----
    t0 = time.perf_counter()
    seq, removed = remove_sparse_frames(seq, config.preprocess.sparse_neighbors,
                                        config.preprocess.sparse_ratio)
    timings["clean-up"] = time.perf_counter() - t0
    if removed.any():
        log.info("removed %.1f %% of the points as sparse (most %.1f %%, frame %d)",
                 100 * removed.mean(), 100 * removed.max(), int(np.argmax(removed)))

    def report(step: str) -> Callable[[int, int], None]:
        return lambda done, total: progress(step, done, total, "") if progress else None

    # ---- step 1: registration (with checkpoint) ---------------------------------------
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
        reg = reg_mod.register_sequence(seq, config.registration, progress=report("registration"))
        if ckpt is not None:
            reg.save(ckpt)
    timings["registration"] = time.perf_counter() - t0
    result = ExtractResult(None, reg, timings=timings, reused_registration=reused,
                           sparse_removed=removed, frames=list(seq.frames))
    if ckpt is not None:
        result.files["registration"] = ckpt
    if stop_after == "registration":
        return result

    # ---- step 2: skeletal structure ------------------------------------------------------
    t0 = time.perf_counter()
    st = struct_mod.extract_structure(reg.rest_points, reg.points, config.structure)
    timings["structure"] = time.perf_counter() - t0
    result.structure = st
    if progress:
        progress("structure", 1, 1, f"{len(st.bone_parent)} bones")
    if stop_after == "structure":
        weights = np.eye(len(st.bone_parent))[st.labels]
        labels, joints_rest, R, T = st.labels, st.joints_rest, st.R, st.T
    else:
        # ---- step 3: joint learning ------------------------------------------------------
        rest_index = reg.params.get("rest_frame_index") if reg.params else None

        def step3(r: Any, structure: Any) -> Any:
            t0 = time.perf_counter()
            out3 = joints_mod.learn_joints(
                seq.frames, r.rest_points, r.points, structure, config.joints,
                progress=report("joints"), rest_index=None if rest_index is None
                else int(rest_index), track_progress=report("tracking"))
            timings["joints"] = timings.get("joints", 0.0) + time.perf_counter() - t0
            return out3

        jr = step3(reg, st)
        # ---- refinement from the skeleton (RegistrationConfig.refine_rounds) -------------
        for rnd in range(config.registration.refine_rounds):
            t0 = time.perf_counter()
            posed = joints_mod.posed_rest_points(reg.rest_points, st.labels, jr.R, jr.T)
            refined = reg_mod.refine_registration(seq, reg, posed, config.registration,
                                                  progress=report(f"refinement {rnd + 1}"))
            timings["refinement"] = timings.get("refinement", 0.0) + time.perf_counter() - t0
            t0 = time.perf_counter()
            st = struct_mod.extract_structure(refined.rest_points, refined.points,
                                              config.structure)
            timings["structure"] += time.perf_counter() - t0
            if progress:
                progress("structure", 1, 1, f"{len(st.bone_parent)} bones (refined)")
            jr = step3(refined, st)
            result.structure = st
            result.refined_registration = refined
        result.joints = jr
        weights, labels = jr.weights, np.argmax(jr.weights, axis=1)
        joints_rest, R, T = jr.joints_rest, jr.R, jr.T
    final = result.refined_registration or reg
    skel = output_skeleton(reg.rest_points, labels, st.bone_parent, joints_rest, R, T, weights,
                           config, st.view_camera,
                           observed=(seq.frames, final.points) if stop_after == "joints"
                           else None, timings=timings)
    result.skeleton = skel

    if out is not None:
        source = {"input": str(seq.source), "format": seq.fmt, "frames": len(seq),
                  "points_per_frame": n_input,
                  "points_used_per_frame": [int(c) for c in seq.counts],
                  "rest_frame": int((reg.params or {}).get("rest_frame_index", -1)),
                  "stopped_after": stop_after, **seq.meta}
        params = config.to_dict()
        params["timings_s"] = {k: round(v, 3) for k, v in timings.items()}
        skel.save_json(out / "skeleton.json", source=source, params=params)
        skel.save_weights(out / "weights.npz")
        write_bvh(out / "skeleton.bvh", skel)
        write_gltf(out / "skeleton.glb", skel)
        result.files["skeleton"] = out / "skeleton.json"
        result.files["weights"] = out / "weights.npz"
        result.files["bvh"] = out / "skeleton.bvh"
        result.files["gltf"] = out / "skeleton.glb"
        if pictures:
            _write_pictures(out, seq, result.refined_registration or reg, skel)
            result.files["png"] = out / "skeleton.png"
            result.files["gif"] = out / "skeleton.gif"
    return result


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
