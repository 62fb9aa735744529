"""Synthetic depth-camera sequences with ground truth: pose a source (procedural figure or
rigged glTF), place a camera, render depth with a z-buffer, corrupt it like a Kinect, and
back-project to camera-frame point clouds.

The ground truth (:class:`SynthSequence`) holds the joints ``(F, J, 3)`` with names and
parents, the bone transforms, and exact surface samples ``(F, S, 3)`` that are the same
material points in every frame (a perfect registration, §4 of the paper), all in the camera
frame (metres).
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ConfigError
from .camera import Camera
from .figures import FIGURES, make_figure, rodrigues
from .noise import NoiseConfig, apply_depth_noise, lateral_offsets, outliers_in_box
from .render import depth_to_points, rasterize

__all__ = ["SynthSequence", "synthesize", "load_gt", "Posed"]

log = logging.getLogger(__name__)

#: Number of exact surface samples ``S`` by default.
DEFAULT_SURFACE_POINTS = 3000
#: Floor/wall half-extent around the subject, metres.
SCENE_HALF_EXTENT = 4.0
#: The floor stops this far in front of the camera (metres).
FLOOR_NEAR = 0.05


@dataclass
class Posed:
    """A posed, skinned triangle mesh over ``F`` frames in the world frame (internal)."""

    name: str
    vertices: np.ndarray  # (F, V, 3)
    triangles: np.ndarray  # (T, 3)
    weights: np.ndarray  # (V, J)
    joints: np.ndarray  # (F, J, 3)
    joint_names: list[str]
    parents: np.ndarray  # (J,)
    R: np.ndarray  # (F, J, 3, 3) T_frame_rest, world
    T: np.ndarray  # (F, J, 3)
    rest_vertices: np.ndarray  # (V, 3)
    surface_tri: np.ndarray  # (S,)
    surface_bary: np.ndarray  # (S, 3)
    facing: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    info: dict[str, Any] = field(default_factory=dict)


@dataclass
class SynthSequence:
    """A synthetic depth-camera sequence with ground truth; everything in the camera frame.

    Attributes
    ----------
    frames
        ``F`` arrays ``(N_t, 3)`` float64, corrupted camera-frame points, metres.
    point_labels
        ``F`` arrays ``(N_t,)`` int: the dominant joint/bone of the surface each point was
        rendered from, ``-1`` for outliers, floor and background.
    gt_joints
        ``(F, J, 3)`` ground-truth joint positions, metres.
    joint_names
        ``J`` names.
    joint_parents
        ``(J,)`` int, ``-1`` for the root.
    surface
        ``(F, S, 3)`` exact (noise-free) surface samples; sample ``s`` is the same material point
        in every frame (visible or not).
    surface_labels
        ``(S,)`` dominant joint/bone of each sample.
    surface_weights
        ``(S, J)`` LBS weights of each sample (rows sum to 1).
    bone_rotations, bone_translations
        ``(F, J, 3, 3)``, ``(F, J, 3)``: ``T_frame_rest`` per bone mapping rest-pose (world
        frame) points to the camera frame at frame ``t``.
    rest_surface
        ``(S, 3)`` the samples in the rest pose (world frame).
    skinned
        ``(J,)`` bool: whether the joint's bone carries skin (dominates some vertex).
    camera
        The placed camera.
    noise
        The noise settings used.
    fps
        Frame rate, Hz.
    source
        Figure name or glTF path.
    params
        The motion options used.
    """

    frames: list[np.ndarray]
    point_labels: list[np.ndarray]
    gt_joints: np.ndarray
    joint_names: list[str]
    joint_parents: np.ndarray
    surface: np.ndarray
    surface_labels: np.ndarray
    surface_weights: np.ndarray
    bone_rotations: np.ndarray
    bone_translations: np.ndarray
    rest_surface: np.ndarray
    skinned: np.ndarray
    camera: Camera
    noise: NoiseConfig
    fps: float
    source: str
    params: dict[str, Any] = field(default_factory=dict)

    @property
    def n_frames(self) -> int:
        """Number of frames ``F``."""
        return len(self.frames)

    def to_point_sequence(self):
        """The frames as a :class:`pointrig.sequence.PointSequence`."""
        from ..sequence import PointSequence

        return PointSequence(list(self.frames), f"synth:{self.source}",
                             [f"frame_{t:04d}" for t in range(self.n_frames)], "memory")

    def eval_kwargs(self) -> dict[str, Any]:
        """The ground truth as keyword arguments of :func:`pointrig.evaluate.evaluate` (names,
        skin, surface samples, bone transforms and rest samples), as ``pointrig evaluate``
        reads them from ``gt.npz``."""
        return {"gt_names": list(self.joint_names), "skinned": self.skinned,
                "surface": self.surface, "surface_labels": self.surface_labels,
                "bone_rotations": self.bone_rotations,
                "bone_translations": self.bone_translations, "rest_surface": self.rest_surface}

    def gt_arrays(self) -> dict[str, Any]:
        """The arrays written to ``gt.npz``."""
        cam = self.camera
        return {
            "joints": self.gt_joints,
            "names": np.array(self.joint_names, dtype=str),
            "parents": self.joint_parents,
            "skinned": self.skinned,
            "surface": self.surface,
            "surface_labels": self.surface_labels,
            "surface_weights": self.surface_weights.astype(np.float32),
            "rest_surface": self.rest_surface,
            "bone_rotations": self.bone_rotations,
            "bone_translations": self.bone_translations,
            "fps": np.float64(self.fps),
            "intrinsics": np.array([cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height],
                                   dtype=np.float64),
            "extrinsic_rotation": np.asarray(cam.rotation, dtype=np.float64),
            "extrinsic_translation": np.asarray(cam.translation, dtype=np.float64),
            "source": np.array(self.source),
            "meta": np.array(json.dumps({"noise": self.noise.to_dict(), "params": self.params})),
        }

    def write(self, out_dir: str | Path, binary: bool = True, float32: bool = False) -> Path:
        """Write ``out_dir/frames/frame_0000.ply ...`` and ``out_dir/gt.npz``; return
        ``out_dir``.

        Frames are binary little-endian PLY in float64 (``float32=True`` halves the size; the
        rounding is below 1 micrometre at Kinect ranges), or ascii with ``binary=False``.
        """
        from ..io import write_npz, write_ply
        from ..io.atomic import atomic_path

        out = Path(out_dir)
        fdir = out / "frames"
        fdir.mkdir(parents=True, exist_ok=True)
        for old in fdir.glob("frame_*.ply"):
            old.unlink()
        for t, pts in enumerate(self.frames):
            path = fdir / f"frame_{t:04d}.ply"
            if float32 and binary:
                header = ("ply\nformat binary_little_endian 1.0\n"
                          f"element vertex {len(pts)}\nproperty float x\nproperty float y\n"
                          "property float z\nend_header\n")
                with atomic_path(path) as tmp, open(tmp, "wb") as fh:
                    fh.write(header.encode("ascii"))
                    fh.write(np.ascontiguousarray(pts, dtype="<f4").tobytes())
            else:
                write_ply(path, pts, binary=binary)
        write_npz(out / "gt.npz", **self.gt_arrays())
        return out


def load_gt(path: str | Path) -> dict[str, Any]:
    """Read a ``gt.npz`` (or a sequence folder holding one).

    Returns a dict with at least ``joints (F, J, 3)``, ``names`` (list of str), ``parents
    (J,)``, and, when present, ``surface (F, S, 3)``, ``surface_labels (S,)``, ``skinned (J,)``.

    Raises
    ------
    InputError
        Missing file or missing/malformed arrays.
    """
    from ..errors import InputError

    p = Path(path)
    if p.is_dir() or (not p.exists() and p.suffix == ""):
        p = p / "gt.npz"
    if not p.exists():
        raise InputError("ground-truth file not found", p)
    try:
        with np.load(p, allow_pickle=False) as z:
            d = {k: z[k] for k in z.files}
    except (ValueError, OSError, EOFError) as exc:
        raise InputError(f"not a readable .npz file: {exc}", p) from None
    for key in ("joints", "parents"):
        if key not in d:
            raise InputError(f"ground truth lacks the array {key!r}", p)
    joints = np.asarray(d["joints"], dtype=np.float64)
    if joints.ndim != 3 or joints.shape[2] != 3:
        raise InputError(f"ground-truth joints must be (F, J, 3), got {joints.shape}", p)
    J = joints.shape[1]
    parents = np.asarray(d["parents"]).astype(np.int64).reshape(-1)
    if parents.shape != (J,) or ((parents < -1) | (parents >= J)).any():
        raise InputError(f"ground-truth parents must be (J,) = ({J},) in [-1, J)", p)
    names = [str(n) for n in d.get("names", [f"j{i}" for i in range(J)])]
    if len(names) != J:
        raise InputError(f"ground truth has {len(names)} names for {J} joints", p)
    d["joints"] = joints
    d["parents"] = parents
    d["names"] = names
    d["path"] = str(p)
    return d


def _placement(n_frames: int, walk: float, yaw: float) -> tuple[np.ndarray, np.ndarray]:
    """World placement per frame: yaw about ``y`` and a walk along world ``x`` centred on 0."""
    Rp = np.broadcast_to(rodrigues(np.array([0.0, 1.0, 0.0]), np.radians(yaw)),
                         (n_frames, 3, 3)).copy()
    tp = np.zeros((n_frames, 3))
    if walk and n_frames > 1:
        tp[:, 0] = np.linspace(-walk / 2, walk / 2, n_frames)
    return Rp, tp


def pose_figure(name: str, n_frames: int, fps: float, speed: float, amplitude: float,
                walk: float, yaw: float, seed: int, surface_points: int) -> Posed:
    """Pose a procedural figure over ``n_frames`` (world frame)."""
    fig = make_figure(name, seed=seed)
    angles = fig.angles(n_frames, fps=fps, speed=speed, amplitude=amplitude, seed=seed)
    Rp, tp = _placement(n_frames, walk, yaw)
    R, T = fig.forward(angles, Rp, tp)
    verts = fig.skin(R, T)
    tri, bary, _ = fig.sample_surface(surface_points, seed=seed)
    return Posed(name, verts, fig.triangles, fig.weights, fig.joints(R, T),
                 list(fig.joint_names), fig.parents.copy(), R, T, fig.vertices, tri, bary,
                 fig.facing, {"figure": name, "triangles": int(len(fig.triangles))})


def _scene_quads(lo: np.ndarray, hi: np.ndarray, facing: np.ndarray, noise: NoiseConfig,
                 eye: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World-frame floor and wall quads as vertices ``(V, 3)`` and triangles ``(T, 3)``.

    The floor ends :data:`FLOOR_NEAR` in front of the camera position ``eye`` (the rasteriser
    does not clip triangles crossing the camera plane)."""
    verts, tris = [], []
    c = (lo + hi) / 2
    e = SCENE_HALF_EXTENT
    f = facing / np.linalg.norm(facing)
    side = np.cross(np.array([0.0, 1.0, 0.0]), f)
    side /= np.linalg.norm(side)
    if noise.floor:
        y = lo[1] - 0.002
        s_near = min(e, float((eye - c) @ f) - FLOOR_NEAR)
        q = np.array([c - side * e - f * e, c + side * e - f * e, c + side * e + f * s_near,
                      c - side * e + f * s_near])
        q[:, 1] = y
        verts.append(q)
    if noise.background:
        depth_half = float(np.abs((hi - lo) / 2 @ np.abs(f)))
        centre = c - f * (depth_half + noise.background_distance)
        y0, y1 = (lo[1] - 0.002 if noise.floor else lo[1] - 0.5), hi[1] + 2.0
        q = np.array([centre + side * -e, centre + side * e, centre + side * e,
                      centre + side * -e])
        q[:, 1] = [y0, y0, y1, y1]
        verts.append(q)
    for k in range(len(verts)):
        tris.append(np.array([[0, 1, 2], [0, 2, 3]]) + 4 * k)
    if not verts:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    return np.concatenate(verts), np.concatenate(tris)


def render_posed(posed: Posed, camera: Camera | None, noise: NoiseConfig, fps: float,
                 source: str, params: dict[str, Any],
                 distance: float | None = None) -> SynthSequence:
    """Place the camera (``distance`` metres from the centre of the motion's box, or
    auto-placed), render, corrupt and package a posed mesh."""
    cam = camera if camera is not None else Camera.kinect()
    F = posed.vertices.shape[0]
    lo = posed.vertices.reshape(-1, 3).min(axis=0)
    hi = posed.vertices.reshape(-1, 3).max(axis=0)
    if not cam.placed:
        cam = cam.placed_for(lo, hi, posed.facing, distance)
    Rc = np.asarray(cam.rotation, dtype=np.float64)
    tc = np.asarray(cam.translation, dtype=np.float64)
    eye = -Rc.T @ tc
    scene_v, scene_t = _scene_quads(lo, hi, posed.facing, noise, eye)
    scene_v_cam = cam.world_to_camera(scene_v)
    n_tri = len(posed.triangles)
    all_tris = np.concatenate([posed.triangles, scene_t + posed.vertices.shape[1]])
    tri_label = np.argmax(posed.weights[posed.triangles].sum(axis=1), axis=1)
    frames, labels = [], []
    rays = None
    if noise.grazing_cos > 0:
        vv, uu = np.mgrid[0:cam.height, 0:cam.width].astype(np.float64)
        rays = np.stack([(uu - cam.cx) / cam.fx, (vv - cam.cy) / cam.fy, np.ones_like(uu)],
                        axis=-1)
        rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    for t in range(F):
        v_cam = cam.world_to_camera(posed.vertices[t])
        verts = np.concatenate([v_cam, scene_v_cam])
        depth, tri_idx = rasterize(verts, all_tris, cam)
        cos_view = None
        if rays is not None:
            tv = verts[all_tris]
            n = np.cross(tv[:, 1] - tv[:, 0], tv[:, 2] - tv[:, 0])
            n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
            hit = tri_idx >= 0
            cos_view = np.ones(depth.shape)
            cos_view[hit] = np.abs(np.einsum("ni,ni->n", n[tri_idx[hit]], rays[hit]))
        noisy = apply_depth_noise(depth, cos_view, noise, t)
        n_valid = int((noisy > 0).sum())
        du, dv = lateral_offsets(n_valid, noise, t)
        pts, flat = depth_to_points(noisy, cam, du, dv)
        tri_hit = tri_idx.reshape(-1)[flat]
        lab = np.where((tri_hit >= 0) & (tri_hit < n_tri), tri_label[np.clip(tri_hit, 0,
                       n_tri - 1)], -1)
        subj = lab >= 0
        out = outliers_in_box(pts[subj] if subj.any() else pts, noise, t)
        frames.append(np.ascontiguousarray(np.concatenate([pts, out])))
        labels.append(np.concatenate([lab, np.full(len(out), -1)]).astype(np.int64))
    # ground truth in the camera frame
    joints = posed.joints @ Rc.T + tc
    R = np.einsum("ij,fbjk->fbik", Rc, posed.R)
    T = np.einsum("ij,fbj->fbi", Rc, posed.T) + tc
    tv = posed.vertices[:, posed.triangles[posed.surface_tri]]  # (F, S, 3, 3)
    surface = np.einsum("sk,fski->fsi", posed.surface_bary, tv) @ Rc.T + tc
    sw = np.einsum("sk,skj->sj", posed.surface_bary,
                   posed.weights[posed.triangles[posed.surface_tri]])
    rest_surface = np.einsum("sk,ski->si", posed.surface_bary,
                             posed.rest_vertices[posed.triangles[posed.surface_tri]])
    dominant = np.bincount(np.argmax(posed.weights, axis=1), minlength=len(posed.joint_names))
    return SynthSequence(
        frames=frames, point_labels=labels, gt_joints=joints,
        joint_names=list(posed.joint_names), joint_parents=posed.parents.astype(np.int64),
        surface=surface, surface_labels=np.argmax(sw, axis=1).astype(np.int64),
        surface_weights=sw, bone_rotations=R, bone_translations=T, rest_surface=rest_surface,
        skinned=dominant > 0, camera=cam, noise=noise, fps=float(fps), source=source,
        params={**params, **posed.info},
    )


def synthesize(
    source: str | Path,
    n_frames: int = 30,
    seed: int = 0,
    camera: Camera | None = None,
    noise: NoiseConfig | None = None,
    *,
    fps: float = 30.0,
    speed: float = 1.0,
    amplitude: float = 1.0,
    walk: float = 0.0,
    yaw: float = 0.0,
    clip: str | int | None = None,
    start: float = 0.0,
    surface_points: int = DEFAULT_SURFACE_POINTS,
    size: float | None = None,
    distance: float | None = None,
) -> SynthSequence:
    """Make a synthetic depth-camera sequence with ground truth.

    Parameters
    ----------
    source
        A figure name from :data:`FIGURES`, a path to a rigged, animated ``.glb``/``.gltf``,
        or a motion-capture ``.bvh`` clip (dressed in a capsule body,
        :mod:`pointrig.synth.bvh`).
    n_frames
        Number of frames ``F``.
    seed
        Seeds the motion and the body proportions of procedural figures (``0``: canonical
        proportions, see :func:`make_figure`) and the surface samples.
    camera
        Intrinsics and optionally the extrinsic; ``None`` is a Kinect v1 at 640x480
        (``Camera.kinect(320)`` for 320x240). Without an extrinsic the camera is placed in
        front of the subject so that the whole motion stays in view.
    noise
        Corruption settings; ``None`` is ``NoiseConfig()`` (Kinect-like), with its own seed.
    fps
        Frame rate, Hz (frame ``t`` is at ``t / fps`` seconds).
    speed
        Time scale of the motion. For procedural figures, joint-angle frequencies are
        multiplied by it (``speed=6`` moves the ``arm`` figure's hand by more than 25 cm per
        frame at 30 fps); for glTF, the clip is played ``speed`` times faster.
    amplitude
        Scale of the procedural joint-angle excursions (1 = the full joint range).
    walk
        Root translation in metres along world ``x`` (across the view) over the sequence,
        centred on the start position (e.g. ``walk=2.5``).
    yaw
        Rotation of the whole subject about the vertical, degrees.
    clip
        glTF animation name or index (default: the clip with the most joint motion).
    start
        glTF and BVH: time offset into the clip, seconds.
    surface_points
        Number of exact surface samples ``S`` (fewer for procedural figures after dropping
        buried samples).
    size
        Scale the subject so that its size, the median over the frames of the bounding-box
        diagonal of its mesh (in its own frame, before ``yaw``), is ``size`` metres (models
        come in any unit: glTF packs range from centimetres to tens of units for a human);
        ``None`` keeps the source's units. ``walk`` stays in metres.
    distance
        Camera distance from the centre of the motion's bounding box, metres (``None``:
        auto-placed to frame the whole motion, at least 0.6 m away). Ignored when ``camera``
        carries an extrinsic.

    Returns
    -------
    SynthSequence
    """
    noise = NoiseConfig() if noise is None else noise
    noise.validate()
    if n_frames < 1:
        raise ConfigError(f"n_frames must be >= 1, got {n_frames}")
    if fps <= 0 or speed < 0:
        raise ConfigError("fps must be > 0 and speed >= 0")
    if size is not None and not (np.isfinite(size) and size > 0):
        raise ConfigError(f"size must be a positive number of metres, got {size!r}")
    if distance is not None and not (np.isfinite(distance) and distance > 0):
        raise ConfigError(f"distance must be a positive number of metres, got {distance!r}")
    pose_walk = 0.0 if size is not None else walk
    params = {"n_frames": int(n_frames), "seed": int(seed), "fps": float(fps),
              "speed": float(speed), "amplitude": float(amplitude), "walk": float(walk),
              "yaw": float(yaw)}
    src = str(source)
    if src in FIGURES:
        posed = pose_figure(src, n_frames, fps, speed, amplitude, pose_walk, yaw, seed,
                            surface_points)
    elif src.lower().endswith((".glb", ".gltf")):
        from .gltf import pose_gltf

        params.update({"clip": clip, "start": float(start)})
        posed = pose_gltf(src, n_frames, fps=fps, speed=speed, walk=pose_walk, yaw=yaw,
                          clip=clip, start=start, seed=seed, surface_points=surface_points)
    elif src.lower().endswith(".bvh"):
        from .bvh import pose_bvh

        params.update({"start": float(start)})
        posed = pose_bvh(src, n_frames, fps=fps, speed=speed, walk=pose_walk, yaw=yaw,
                         start=start, seed=seed, surface_points=surface_points)
    else:
        raise ConfigError(f"unknown source {src!r}: expected one of {', '.join(FIGURES)}, a "
                          ".glb/.gltf file or a .bvh clip")
    if size is not None:
        scale = size / posed_size(posed, yaw)
        _scale_posed(posed, scale)
        _, tp = _placement(n_frames, walk, yaw)
        posed.vertices += tp[:, None]
        posed.joints += tp[:, None]
        posed.T += tp[:, None]
        params.update({"size": float(size), "scale": float(scale)})
    if distance is not None:
        params["distance"] = float(distance)
    return render_posed(posed, camera, noise, fps, src, params, distance)


def posed_size(posed: Posed, yaw: float = 0.0) -> float:
    """The size of a posed mesh: the median over the frames of the bounding-box diagonal of
    its vertices ``(F, V, 3)``, taken in the subject's own frame (``yaw`` degrees about ``y``
    undone), in the mesh's units."""
    Rp = rodrigues(np.array([0.0, 1.0, 0.0]), np.radians(yaw))
    v = posed.vertices @ Rp  # rows: Rp^T x
    diag = np.linalg.norm(v.max(axis=1) - v.min(axis=1), axis=1)
    size = float(np.median(diag))
    if not size > 0:
        raise ConfigError(f"{posed.name}: the posed mesh has no extent, it cannot be scaled")
    return size


def _scale_posed(posed: Posed, scale: float) -> None:
    """Scale a posed mesh about the world origin in place: vertices, joints, rest vertices and
    the bone translations (``T_frame_rest`` keeps its rotation: ``s x = R (s q) + s T``)."""
    posed.vertices *= scale
    posed.joints *= scale
    posed.T *= scale
    posed.rest_vertices = posed.rest_vertices * scale
