"""The whole method: registration (§4) -> skeletal structure (§5) -> joint learning (§6).

:func:`extract` runs the steps with a registration checkpoint (reused when the input and the
step-1 parameters match, so changing a later step's parameter does not redo step 1) and
writes the outputs as one set, whole or absent (:class:`pointrig.io.outdir.OutputDir`: every
file is staged, then moved into the folder and named in ``manifest.json``, written last; the
folder is checked and locked before step 1):

- ``skeleton.json``  the ``pointrig.skeleton/1`` contract (see the README);
- ``weights.npz``    rest points, skinning weights ``(M, B)``, labels, bone transforms;
- ``registration.npz``  the step-1 checkpoint;
- ``skeleton.bvh``   the animated skeleton as motion capture (Blender, MotionBuilder);
- ``skeleton.glb``   glTF 2.0: joints, skin, the rest points as a skinned point mesh and the
  animation (Blender, Godot, Unity, three.js), see :func:`pointrig.export.write_gltf`;
- ``rig.glb``        the skinned surface of the subject on the same joints (``[rig] mesh``,
  the ``rig`` extra; :mod:`pointrig.rig`); ``rig.usda`` the same as UsdSkel (``[rig] usd``,
  the ``usd`` extra; :mod:`pointrig.usd`);
- ``skeleton.png``, ``skeleton.gif``  pictures (optional);
- ``report.html``    the page to look at the run: a 3D view of the points and the skeleton
  that plays the sequence, the seconds of each stage and the warnings (``[rig] report``, the
  ``report`` extra; :mod:`pointrig.report`);
- ``manifest.json``  the files of the set with their sizes and SHA-256, written last.

The output stage that turns step 3's bones into the written skeleton (joint selection,
output tree, splits, joint depth, bone rolls) is :mod:`pointrig.output`;
:func:`output_skeleton` and :func:`build_skeleton` are re-exported here.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from .config import PipelineConfig
from .errors import InputError, OutputError, PointrigError
from .export import write_bvh, write_gltf
from .geometry import reuse_normals
from .io.outdir import PARTIAL, OutputDir, fault_point
from .naming import apply_names, read_name_mapping
from .output import build_skeleton, output_skeleton
from .preprocess import OUTLIER_SUSPECT, remove_sparse_frames
from .report import report_available
from .rig import rig_available
from .sequence import PointSequence, check_units
from .skeleton import Skeleton
from .usd import usd_available

__all__ = ["ExtractResult", "build_skeleton", "expected_output_bytes", "extract",
           "output_skeleton"]

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
    #: joint-depth pass read them (metres); on disk, read on demand, when the input's frames
    #: were (:class:`pointrig.sequence.SpilledFrames`)
    frames: Sequence[np.ndarray] | None = None
    #: the clean-up's look at outliers (recorded in ``skeleton.json`` as ``source.outliers``):
    #: ``suspect_frames`` (the frames that looked mostly like outliers, cleaned again against
    #: their dense points), ``left_max`` (the largest fraction of a cleaned frame's points that
    #: still look like outliers)
    outliers: dict[str, Any] = field(default_factory=dict)
    #: what the run warned about, one line each (also in ``skeleton.json`` ``source.warnings``)
    warnings: list[str] = field(default_factory=list)
    #: ``(mesh, stats)`` of ``rig.glb`` (:func:`pointrig.rig.build_surface`) when written
    rig: tuple[Any, Any] | None = None


def extract(
    seq: PointSequence,
    config: PipelineConfig | None = None,
    out_dir: str | Path | OutputDir | None = None,
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
        Output folder (or one already opened, :class:`pointrig.io.outdir.OutputDir`);
        ``None`` writes nothing.
    resume
        Reuse ``out_dir/registration.npz`` (or the one an interrupted run into ``out_dir``
        left) when its key (input + step-1 parameters) matches.
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
    OutputError
        Before step 1, when ``out_dir`` is a file, not writable, short of free space or
        locked by another run; later, when a write fails (the folder's previous set stays).
    """
    config = config or PipelineConfig()
    check_units(seq, config.preprocess.max_extent)
    mapping = None if bone_names is None else read_name_mapping(bone_names)
    with_rig = out_dir is not None and stop_after == "joints" and rig_available(config.rig.mesh)
    with_usd = with_rig and usd_available(config.rig.usd)
    with_report = out_dir is not None and stop_after != "registration" \
        and report_available(config.rig.report)
    args = (resume, stop_after, pictures, progress, _Naming(mapping, bone_names), with_rig,
            with_usd, with_report)
    with _compute_once():
        if out_dir is None:
            return _extract(seq, config, None, *args)
        if isinstance(out_dir, OutputDir):  # already checked and locked by the caller
            return _extract_into(out_dir, seq, config, *args)
        with OutputDir(out_dir) as od:
            return _extract_into(od, seq, config, *args)


@contextmanager
def _compute_once() -> Iterator[None]:
    """The run's settings that save work and leave every result as it is: a frame's normals
    estimated once for the steps that use them (:func:`pointrig.geometry.reuse_normals`), and
    the BLAS (numpy's and scipy's OpenBLAS) on one thread: its products here are small, the
    pipeline's parallel parts are its own pools and the Rust core, and idle BLAS threads
    spin-wait on the cores those need."""
    from threadpoolctl import threadpool_limits

    with reuse_normals(), threadpool_limits(1, user_api="blas"):
        yield


def _extract_into(od: OutputDir, seq: PointSequence, config: PipelineConfig, resume: bool,
                  stop_after: StopAfter, pictures: bool, progress: Progress | None,
                  naming: _Naming, with_rig: bool, with_usd: bool,
                  with_report: bool) -> ExtractResult:
    """:func:`extract` into the locked output folder ``od``: the free space checked first,
    the outputs staged, then committed as one set."""
    od.require_space(expected_output_bytes(seq, pictures, config.registration.n_rest_points,
                                           report=with_report))
    result = _extract(seq, config, od, resume, stop_after, pictures, progress, naming,
                      with_rig, with_usd, with_report)
    fault_point("before-commit")
    try:
        final = od.commit()
    except OSError as exc:
        raise OutputError(f"cannot move the outputs into place: {exc.strerror or exc}",
                          od.path) from None
    result.files = {key: final[path.name] for key, path in result.files.items()}
    return result


def expected_output_bytes(seq: PointSequence, pictures: bool = True,
                          n_rest_points: int | None = None, report: bool = False) -> int:
    """A generous estimate of the bytes :func:`extract` writes for ``seq``: the registration
    checkpoint, the weights and the glTF hold a few float64 3-vectors per rest point and frame
    (``n_rest_points``, at most a frame's size), plus the pictures (their GIF a frame each) and
    ``report.html`` (plotly's JavaScript, about 5 MB, and up to 2000 points a frame)."""
    n = int(np.max(seq.counts)) if len(seq) else 0
    if n_rest_points is not None:
        n = min(n, n_rest_points)
    f = len(seq)
    return (48 * f * n + 64 * n + ((8 << 20) + (64 << 10) * f if pictures else 0)
            + ((6 << 20) + (64 << 10) * f if report else 0) + (1 << 20))


@contextmanager
def _writing(out: Path) -> Iterator[None]:
    """Turn a failed write (a full disk, a permission) into one :class:`OutputError` line."""
    try:
        yield
    except OSError as exc:
        if isinstance(exc, OutputError):
            raise
        raise OutputError(f"cannot write the outputs: {exc.strerror or exc}", out) from None


@dataclass
class _Naming:
    """The ``--bone-names`` mapping and where it came from (for its errors)."""

    mapping: dict[str, str] | None
    source: str | Path | None


def _extract(seq: PointSequence, config: PipelineConfig, od: OutputDir | None, resume: bool,
             stop_after: StopAfter, pictures: bool, progress: Progress | None, naming: _Naming,
             with_rig: bool, with_usd: bool, with_report: bool = False) -> ExtractResult:
    """The body of :func:`extract`; outputs go to ``od``'s staging folder (none without)."""
    out = None if od is None else od.stage
    timings: dict[str, float] = {}
    n_input = [int(c) for c in seq.counts]
    seq, removed, outliers, warnings = _clean_input(seq, config, timings)
    reg, reused, ckpt = _step1(seq, config, od, resume, timings, progress)
    fault_point("registered")
    result = ExtractResult(None, reg, timings=timings, reused_registration=reused,
                           sparse_removed=removed, frames=seq.frames, outliers=outliers,
                           warnings=warnings)
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
    apply_names(result.skeleton, config.rig.names, naming.mapping,
                naming.source or "--bone-names")
    if out is not None:
        with _writing(out):
            _write_outputs(out, seq, reg, result, config, stop_after, n_input, pictures,
                           with_rig, with_usd, with_report)
    return result


def _report(progress: Progress | None, step: str) -> Callable[[int, int], None]:
    """``progress`` as a step's ``(done, total)`` callback (a no-op without ``progress``)."""
    return lambda done, total: progress(step, done, total, "") if progress else None


def _clean_input(seq: PointSequence, config: PipelineConfig, timings: dict[str, float]
                 ) -> tuple[PointSequence, np.ndarray, dict[str, Any], list[str]]:
    """Input clean-up: sparse points (flying pixels, outliers) out of every frame
    (:func:`pointrig.preprocess.remove_sparse_frames`); the cleaned sequence, the ``(F,)``
    fraction of each frame's points removed, the outlier record of
    :attr:`ExtractResult.outliers` and the warnings (logged) when frames look mostly like
    outliers. Its seconds go to ``timings["clean-up"]``."""
    t0 = time.perf_counter()
    report: dict[str, np.ndarray] = {}
    seq, removed = remove_sparse_frames(seq, config.preprocess.sparse_neighbors,
                                        config.preprocess.sparse_ratio, report=report)
    timings["clean-up"] = time.perf_counter() - t0
    if removed.any():
        log.info("removed %.1f %% of the points as sparse (most %.1f %%, frame %d)",
                 100 * removed.mean(), 100 * removed.max(), int(np.argmax(removed)))
    suspect = np.flatnonzero(report["suspect"])
    left = report["outliers_left"]
    outliers = {"suspect_frames": [int(t) for t in suspect],
                "left_max": round(float(left.max(initial=0.0)), 4)}
    warnings = []
    if len(suspect):
        warnings.append(
            f"{len(suspect)} of {len(seq)} frames looked mostly like outliers (a scatter of "
            f"sparse points; first frame {int(suspect[0])}): cleaned again against their "
            "densest points; check the input (crop the scene, the sensor's filters)")
    if left.max(initial=0.0) > OUTLIER_SUSPECT:
        t = int(np.argmax(left))
        warnings.append(
            f"frame {t} still looks mostly like outliers after the clean-up "
            f"({100 * left[t]:.0f} % of its points): the skeleton is likely wrong")
    for w in warnings:
        log.warning("%s", w)
    return seq, removed, outliers, warnings


def _step1(seq: PointSequence, config: PipelineConfig, od: OutputDir | None, resume: bool,
           timings: dict[str, float], progress: Progress | None) -> tuple[Any, bool, Path | None]:
    """Step 1, registration (§4), with its checkpoint ``registration.npz``: the one an
    interrupted run staged or the committed one in the output folder is reused when its key
    (input + step-1 parameters) matches and ``resume``, else step 1 runs and its checkpoint is
    staged. Returns the registration, whether it was reused, and the staged checkpoint's path
    (``None`` without ``od``). Its seconds go to ``timings["registration"]``."""
    from . import registration as reg_mod

    t0 = time.perf_counter()
    reg = None
    name = "registration.npz"
    for cand in (od.resume_candidates(name) if od is not None and resume else []):
        try:
            cached = reg_mod.RegistrationResult.load(cand)
            if cached.key == reg_mod.cache_key(seq, config.registration):
                reg = cached
                log.info("reusing registration checkpoint %s", cand)
                if cand.parent != od.stage:
                    with _writing(od.path):
                        od.carry(name)
                break
        except Exception as exc:  # noqa: BLE001 - a stale or damaged checkpoint is recomputed
            why = exc.problem if isinstance(exc, InputError) else exc
            log.warning("ignoring registration checkpoint %s (%s); step 1 runs again", cand,
                        why)
    reused = reg is not None
    ckpt = None if od is None else od.staged(name)
    if reg is None:
        partial, on_frame = _step1_partial(seq, config, od, resume)
        reg = reg_mod.register_sequence(seq, config.registration,
                                        progress=_report(progress, "registration"),
                                        partial=partial, on_frame=on_frame)
        if ckpt is not None:
            with _writing(od.path):
                reg.save(ckpt)
            od.staged(PARTIAL).unlink(missing_ok=True)
    timings["registration"] = time.perf_counter() - t0
    return reg, reused, ckpt


#: Step 1 saves the frames registered so far (``registration.partial.npz`` in the staging
#: folder) after every this many frames, so that an interrupted run resumes where it stopped.
STEP1_CHECKPOINT_EVERY = 10


def _step1_partial(seq: PointSequence, config: PipelineConfig, od: OutputDir | None,
                   resume: bool) -> tuple[Any, Callable[[Any], None] | None]:
    """The frames an interrupted step 1 registered (its ``registration.partial.npz``, when its
    key matches and ``resume``) and the callback that saves the state every
    :data:`STEP1_CHECKPOINT_EVERY` frames (``None`` without ``od``)."""
    from . import registration as reg_mod

    key = reg_mod.cache_key(seq, config.registration)
    partial = reg_mod.PartialRegistration(key)
    if od is None:
        return partial, None
    for cand in od.resume_candidates(PARTIAL) if resume else []:
        try:
            found = reg_mod.PartialRegistration.load(cand)
        except InputError as exc:
            log.warning("ignoring partial registration %s (%s)", cand, exc.problem)
            continue
        if found.key == key:
            partial = found
            log.info("resuming step 1 from %s (%d frames registered)", cand, found.n_frames())
            break
    path = od.staged(PARTIAL)
    saving = threading.Lock()
    last = [partial.n_frames()]

    def on_frame(state: Any) -> None:
        with saving:
            n = state.n_frames()
            if n - last[0] < STEP1_CHECKPOINT_EVERY:
                return
            with _writing(od.path):
                state.save(path)
            last[0] = n
            fault_point("step1-saved")

    return partial, on_frame


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
                   pictures: bool, with_rig: bool = False, with_usd: bool = False,
                   with_report: bool = False) -> None:
    """Write ``result.skeleton`` into ``out``: ``skeleton.json`` (with the input's description
    and every parameter), ``weights.npz``, ``skeleton.bvh``, ``skeleton.glb``, with
    ``with_rig`` the skinned surface ``rig.glb`` (and with ``with_usd`` ``rig.usda``; their
    seconds in ``timings["rig"]``; a surface that cannot be built is skipped with a warning
    under ``[rig] mesh = "auto"``) and, with ``pictures``, ``skeleton.png``, ``skeleton.gif``
    (and ``rig.png``: the surface in three poses) and, with ``with_report``, ``report.html``
    (:func:`pointrig.report.write_report`); the paths go to ``result.files``."""
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
              "stopped_after": stop_after, "outliers": result.outliers,
              "warnings": result.warnings, **seq.meta}
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
    if with_report:
        from .report import write_report

        write_report(out / "report.html", skel, result.frames or list(seq.frames),
                     params["timings_s"], result.warnings,
                     title=_title(seq), max_points=config.rig.report_points)
        result.files["report"] = out / "report.html"


def _title(seq: PointSequence) -> str:
    """The input's name for the report: its last two path parts (``take_3/frames``)."""
    parts = Path(str(seq.source)).parts[-2:]
    return "/".join(parts) or "pointrig"


def _write_pictures(out: Path, seq: PointSequence, reg: Any, skel: Skeleton) -> None:
    """Skeleton over the registered points coloured by bone (PNG) and the animation (GIF)."""
    from .viz import palette, save_sequence_gif, save_skeleton_png

    cols = palette(max(skel.n_joints, 1))
    labels = skel.labels if skel.labels is not None else np.zeros(len(reg.rest_points), int)
    pc = [cols[labels]] * len(seq)
    frames = [reg.points[t] for t in range(len(seq))]
    save_skeleton_png(out / "skeleton.png", frames, skel.joint_positions, skel.parents,
                      point_colors=pc)
    fault_point("pictures")
    save_sequence_gif(out / "skeleton.gif", frames, skel.joint_positions, skel.parents,
                      point_colors=pc)
