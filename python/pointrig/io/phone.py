"""iPhone / iPad LiDAR captures: Record3D ``.r3d`` files and Stray Scanner folders.

Record3D's ``.r3d`` export is a zip archive holding ``metadata`` (JSON: the colour image size
``w, h``, the depth size ``dw, dh``, ``K`` the colour camera's 3 x 3 intrinsics as 9 numbers in
column-major order, ``fps``, optional ``frameTimestamps`` in seconds) and per frame
``rgbd/N.depth``: ``dh x dw`` float32 depth in metres, LZFSE-compressed (NaN or 0: no depth).
The depth intrinsics are ``K`` scaled by ``dw / w`` (first row) and ``dh / h`` (second row).

A Stray Scanner folder holds ``depth/NNNNNN.png`` (16-bit millimetres), ``camera_matrix.csv``
(the colour camera's 3 x 3 ``K``, rows of comma-separated numbers), ``rgb.mp4`` and
``odometry.csv`` (``timestamp, frame, ...`` per frame). ``K`` is scaled from the colour size
(read from ``rgb.mp4`` with PyAV when it can be, else the app's 1920 x 1440) to the depth
size.
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import FormatError, InputError
from .depthcam import (
    Isolation,
    Recording,
    check_crop,
    depth_image_points,
    need_extra,
    pinhole_rays,
    select_frames,
)

__all__ = ["is_r3d", "is_stray", "read_r3d", "read_stray", "STRAY_COLOUR_SIZE"]

#: the colour image size Stray Scanner records (its camera_matrix.csv is for this size)
STRAY_COLOUR_SIZE = (1920, 1440)


def is_r3d(path: Path) -> bool:
    """Whether ``path`` is a zip archive with Record3D's ``metadata`` and ``rgbd/*.depth``."""
    if not zipfile.is_zipfile(path):
        return False
    try:
        with zipfile.ZipFile(path) as z:
            names = z.namelist()
    except (zipfile.BadZipFile, OSError):
        return False
    return "metadata" in names and any(n.startswith("rgbd/") and n.endswith(".depth")
                                       for n in names)


def stray_root(path: Path) -> Path | None:
    """The Stray Scanner folder of ``path`` (the folder, or its ``depth/`` subfolder)."""
    for d in (path, path.parent):
        if (d / "camera_matrix.csv").is_file() and (d / "depth").is_dir():
            if d == path or path.name == "depth":
                return d
    return None


def is_stray(path: Path) -> bool:
    """Whether ``path`` is a Stray Scanner folder (or its ``depth/`` subfolder)."""
    return path.is_dir() and stray_root(path) is not None


def _index(name: str) -> int:
    stem = name.rsplit("/", 1)[-1].split(".", 1)[0]
    return int(stem) if stem.isdigit() else -1


def _given(intrinsics: dict[str, float], w: int, h: int) -> tuple[np.ndarray, dict[str, Any]]:
    k = {key: float(intrinsics[key]) for key in ("fx", "fy", "cx", "cy")}
    return pinhole_rays(w, h, **k), {"source": "given", "model": "pinhole", **k}


def read_r3d(path: str | Path, *, start: int = 0, stop: int | None = None, stride: int = 1,
             intrinsics: dict[str, float] | None = None, isolation: Isolation | None = None,
             keep_depth: bool = False) -> Recording:
    """Read a Record3D ``.r3d`` capture's depth frames to points.

    Parameters
    ----------
    path
        The ``.r3d`` file.
    start, stop, stride
        Frames used.
    intrinsics
        Pinhole ``fx, fy, cx, cy`` of the depth image (pixels) instead of the metadata's.
    isolation
        Depth range and pixel box kept.
    keep_depth
        Also return the depth images (metres).

    Returns
    -------
    Recording
        Points in metres, camera frame (x right, y down, z forward); ``meta`` with
        ``device``, ``resolution``, ``fps``, ``intrinsics``, ``timestamps_s``, ``duration_s``.

    Raises
    ------
    FormatError
        A damaged archive, metadata or depth frame.
    """
    lzfse = need_extra("lzfse", "Record3D .r3d captures")
    p = Path(path)
    try:
        zf = zipfile.ZipFile(p)
    except (zipfile.BadZipFile, OSError) as exc:
        raise FormatError(f"not a readable .r3d archive: {exc}", p) from None
    with zf:
        try:
            md = json.loads(zf.read("metadata"))
            w, h, dw, dh = (int(md[k]) for k in ("w", "h", "dw", "dh"))
            K = np.asarray(md["K"], dtype=np.float64).reshape(3, 3).T  # column-major
        except (KeyError, ValueError, TypeError, json.JSONDecodeError, zipfile.BadZipFile) as exc:
            raise FormatError(f"unusable .r3d metadata: {type(exc).__name__}: {exc}",
                              p) from None
        names = sorted((n for n in zf.namelist() if n.startswith("rgbd/")
                        and n.endswith(".depth") and _index(n) >= 0), key=_index)
        if not names:
            raise FormatError("the .r3d archive holds no rgbd/N.depth frames", p)
        if intrinsics is not None:
            rays, intr_meta = _given(intrinsics, dw, dh)
        else:
            sx, sy = dw / w, dh / h
            k = {"fx": K[0, 0] * sx, "fy": K[1, 1] * sy, "cx": K[0, 2] * sx, "cy": K[1, 2] * sy}
            rays = pinhole_rays(dw, dh, **k)
            intr_meta = {"source": f"r3d metadata K, scaled from {w} x {h} to {dw} x {dh}",
                         "model": "pinhole", **k}
        check_crop(isolation, dw, dh, p)
        fps = float(md.get("fps") or 0) or None
        stamps = md.get("frameTimestamps")
        all_times = ([float(t) for t in stamps] if isinstance(stamps, list)
                     and len(stamps) == len(names) else
                     [i / fps for i in range(len(names))] if fps else [])
        frames, fnames, images, used = [], [], [], []
        for i in select_frames(len(names), start, stop, stride):
            try:
                raw = lzfse.decompress(zf.read(names[i]))
            except (lzfse.error, zipfile.BadZipFile, OSError, EOFError) as exc:
                raise FormatError(f"{names[i]}: damaged LZFSE depth ({exc or 'corrupt'})", p,
                                  frame=i) from None
            if len(raw) != dw * dh * 4:
                raise FormatError(f"{names[i]}: {len(raw)} bytes, {dw} x {dh} float32 expected",
                                  p, frame=i)
            depth = np.frombuffer(raw, dtype="<f4").reshape(dh, dw)
            frames.append(depth_image_points(depth, rays, 1.0, isolation))
            fnames.append(names[i])
            if all_times:
                used.append(all_times[i])
            if keep_depth:
                images.append(np.nan_to_num(depth, nan=0.0).astype(np.float32))
    cam = {0: "TrueDepth (front)", 1: "LiDAR (back)"}.get(md.get("cameraType"), None)
    meta: dict[str, Any] = {
        "device": "Record3D capture" + (f", {cam} camera" if cam else ""),
        "resolution": [dw, dh], "fps": fps, "depth_unit_m": 1.0, "intrinsics": intr_meta,
        "frames_in_file": len(names), "timestamps_s": used,
        "duration_s": (all_times[-1] - all_times[0]) if len(all_times) > 1 else None,
    }
    if isolation is not None and isolation.active:
        meta["isolation"] = isolation.to_dict()
    return Recording(frames, fnames, "r3d", meta, images)


def _stray_colour_size(root: Path) -> tuple[tuple[int, int], str]:
    """The colour image size ``camera_matrix.csv`` is for, and where it came from."""
    video = root / "rgb.mp4"
    if video.is_file():
        try:
            import av

            with av.open(str(video)) as c:
                s = c.streams.video[0]
                return (int(s.codec_context.width), int(s.codec_context.height)), "rgb.mp4"
        except Exception:  # no PyAV, or an unreadable video: the app's recording size
            pass
    return STRAY_COLOUR_SIZE, "Stray Scanner's colour size"


def read_stray(path: str | Path, *, start: int = 0, stop: int | None = None, stride: int = 1,
               intrinsics: dict[str, float] | None = None, isolation: Isolation | None = None,
               keep_depth: bool = False) -> Recording:
    """Read a Stray Scanner folder's depth frames to points.

    Parameters
    ----------
    path
        The folder (or its ``depth/`` subfolder).
    start, stop, stride, intrinsics, isolation, keep_depth
        As for :func:`read_r3d`.

    Returns
    -------
    Recording
        Points in metres, camera frame; ``meta`` as for :func:`read_r3d`.

    Raises
    ------
    InputError
        An unreadable ``camera_matrix.csv``.
    FormatError
        A depth PNG that is not 16-bit or changes size.
    """
    from PIL import Image, UnidentifiedImageError

    p = Path(path)
    root = stray_root(p)
    assert root is not None  # detect_recording found it
    files = sorted((f for f in (root / "depth").iterdir() if f.suffix.lower() == ".png"
                    and f.stem.isdigit()), key=lambda f: int(f.stem))
    if not files:
        raise InputError("no depth/NNNNNN.png frames", root)
    K = None
    if intrinsics is None:
        try:
            K = np.loadtxt(root / "camera_matrix.csv", delimiter=",", dtype=np.float64)
        except (ValueError, OSError) as exc:
            raise InputError(f"camera_matrix.csv is not a 3 x 3 matrix: {exc}", root) from None
        if K.shape != (3, 3) or not np.isfinite(K).all() or K[0, 0] <= 0 or K[1, 1] <= 0:
            raise InputError("camera_matrix.csv is not a 3 x 3 camera matrix", root)
    times: dict[int, float] = {}
    odo = root / "odometry.csv"
    if odo.is_file():
        try:
            rows = np.atleast_2d(np.loadtxt(odo, delimiter=",", skiprows=1, dtype=np.float64))
            times = {int(r[1]): float(r[0]) for r in rows if len(r) > 1}
        except (ValueError, OSError):
            times = {}  # frame times are a description only
    frames, names, images, used = [], [], [], []
    rays, intr_meta, shape = None, {}, None
    for i in select_frames(len(files), start, stop, stride):
        try:
            with Image.open(files[i]) as im:
                depth = np.asarray(im)
        except (UnidentifiedImageError, OSError) as exc:
            raise FormatError(f"not a readable PNG: {exc}", files[i], frame=i) from None
        if depth.ndim != 2 or depth.dtype not in (np.uint16, np.int32, np.uint32):
            raise FormatError(f"depth PNG must be 16-bit single-channel, got {depth.dtype} "
                              f"{depth.shape}", files[i], frame=i)
        if rays is None:
            dh, dw = depth.shape
            shape = depth.shape
            check_crop(isolation, dw, dh, root)
            if intrinsics is not None:
                rays, intr_meta = _given(intrinsics, dw, dh)
            else:
                (cw, ch), size_from = _stray_colour_size(root)
                sx, sy = dw / cw, dh / ch
                k = {"fx": K[0, 0] * sx, "fy": K[1, 1] * sy, "cx": K[0, 2] * sx,
                     "cy": K[1, 2] * sy}
                rays = pinhole_rays(dw, dh, **k)
                intr_meta = {"source": f"camera_matrix.csv, scaled from {cw} x {ch} "
                             f"({size_from}) to {dw} x {dh}", "model": "pinhole", **k}
        elif depth.shape != shape:
            raise FormatError(f"depth PNG of {depth.shape[1]} x {depth.shape[0]} pixels, the "
                              f"first was {shape[1]} x {shape[0]}", files[i], frame=i)
        frames.append(depth_image_points(depth, rays, 0.001, isolation))
        names.append(f"depth/{files[i].name}")
        if int(files[i].stem) in times:
            used.append(times[int(files[i].stem)])
        if keep_depth:
            images.append((depth * 0.001).astype(np.float32))
    all_t = sorted(times.values())
    fps = (round(1.0 / float(np.median(np.diff(all_t))), 6)
           if len(all_t) > 1 and np.median(np.diff(all_t)) > 0 else None)
    meta: dict[str, Any] = {
        "device": "Stray Scanner capture",
        "resolution": None if shape is None else [int(shape[1]), int(shape[0])],
        "fps": fps, "depth_unit_m": 0.001, "intrinsics": intr_meta,
        "frames_in_file": len(files), "timestamps_s": used,
        "duration_s": (all_t[-1] - all_t[0]) if len(all_t) > 1 else None,
    }
    if isolation is not None and isolation.active:
        meta["isolation"] = isolation.to_dict()
    return Recording(frames, names, "stray", meta, images)
