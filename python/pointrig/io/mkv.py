"""Azure Kinect and Orbbec Femto recordings (``.mkv``), read through PyAV.

The Azure Kinect recorder (``k4arecorder``, and Orbbec's K4A wrapper for the Femto cameras)
writes a Matroska file with a video track titled ``DEPTH`` (tag ``K4A_DEPTH_TRACK``): raw
16-bit depth, codec ``b16g`` (16-bit grey, big-endian), millimetres, 0 where there is no depth;
the depth mode in the track tag ``K4A_DEPTH_MODE``; and the factory calibration as an
attachment ``calibration.json`` (tag ``K4A_CALIBRATION_FILE``). Frame times are the block
timestamps (microseconds from the start of the recording; the device clock is ahead by the tag
``K4A_START_OFFSET_NS``).

The depth camera's calibration (``Purpose: CALIBRATION_CameraPurposeDepth``) gives
``cx, cy, fx, fy`` as fractions of the 1024 x 1024 sensor, ten distortion numbers and a valid
radius. For the image of a depth mode the SDK scales them to the mode's binned sensor size,
subtracts the mode's crop offset and moves the pixel centre to whole numbers (``- 0.5``); the
rays through each pixel then invert the Brown-Conrady distortion
(:func:`pointrig.io.depthcam.brown_conrady_rays`).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import FormatError, InputError
from .depthcam import (
    Isolation,
    Recording,
    brown_conrady_rays,
    check_crop,
    depth_image_points,
    may_select,
    need_extra,
    pinhole_rays,
    select_frames,
)

__all__ = ["MATROSKA_MAGIC", "K4A_DEPTH_MODES", "read_mkv", "k4a_depth_intrinsics",
           "matroska_truncation"]

#: the first bytes of every Matroska (EBML) file
MATROSKA_MAGIC = b"\x1a\x45\xdf\xa3"

#: Azure Kinect depth mode -> (binned sensor size, crop offset, image size), pixels (the SDK's
#: mode-specific calibration of the 1024 x 1024 depth sensor)
K4A_DEPTH_MODES: dict[str, tuple[tuple[int, int], tuple[int, int], tuple[int, int]]] = {
    "NFOV_2X2BINNED": ((512, 512), (96, 90), (320, 288)),
    "NFOV_UNBINNED": ((1024, 1024), (192, 180), (640, 576)),
    "WFOV_2X2BINNED": ((512, 512), (0, 0), (512, 512)),
    "WFOV_UNBINNED": ((1024, 1024), (0, 0), (1024, 1024)),
    "PASSIVE_IR": ((1024, 1024), (0, 0), (1024, 1024)),
}

_DEPTH_PURPOSE = "CALIBRATION_CameraPurposeDepth"


def _vint(buf: bytes, pos: int, keep_marker: bool) -> tuple[int, int]:
    """An EBML variable-length integer at ``pos``: (value, position after it). An all-ones
    size (unknown size) is returned as -1."""
    if pos >= len(buf):
        raise ValueError("the file ends inside an element header")
    first = buf[pos]
    length = 1
    while length <= 8 and not first & (0x80 >> (length - 1)):
        length += 1
    if length > 8 or pos + length > len(buf):
        raise ValueError("bad EBML number")
    value = first if keep_marker else first & (0xFF >> length)
    for b in buf[pos + 1:pos + length]:
        value = (value << 8) | b
    if not keep_marker and value == (1 << (7 * length)) - 1:
        return -1, pos + length
    return value, pos + length


def matroska_truncation(path: Path) -> str | None:
    """Why the Matroska file at ``path`` is cut short, or ``None``: its ``Segment`` declares a
    size (a recording that was closed properly) that runs past the end of the file."""
    size = path.stat().st_size
    with open(path, "rb") as fh:
        head = fh.read(4096)
    try:
        eid, pos = _vint(head, 0, True)
        if eid != 0x1A45DFA3:
            return None
        hsize, pos = _vint(head, pos, False)
        pos += hsize
        eid, pos = _vint(head, pos, True)
        if eid != 0x18538067:
            return "no Segment after the EBML header"
        ssize, pos = _vint(head, pos, False)
    except ValueError as exc:
        return str(exc)
    if ssize >= 0 and pos + ssize > size:
        return f"the Segment declares {pos + ssize} bytes, the file holds {size}"
    return None


def k4a_depth_intrinsics(calibration: dict[str, Any], mode: str) -> dict[str, Any]:
    """The depth camera's intrinsics for the image of ``mode`` from an Azure Kinect
    calibration JSON (``{"CalibrationInformation": {"Cameras": [...]}}``).

    Returns
    -------
    dict
        ``width, height`` (pixels), ``fx, fy, cx, cy`` (pixels, pixel centres at whole
        numbers), ``k`` (6 radial coefficients), ``p1, p2``, ``max_radius`` (normalised),
        ``model``.

    Raises
    ------
    ValueError
        No depth camera, an unknown mode or model, or malformed numbers.
    """
    if mode not in K4A_DEPTH_MODES:
        raise ValueError(f"unknown depth mode {mode!r} (known: {', '.join(K4A_DEPTH_MODES)})")
    cams = calibration["CalibrationInformation"]["Cameras"]
    depth = [c for c in cams if c.get("Purpose") == _DEPTH_PURPOSE]
    if not depth:
        raise ValueError("the calibration has no depth camera")
    cam = depth[0]
    intr = cam["Intrinsics"]
    if intr.get("ModelType") != "CALIBRATION_LensDistortionModelBrownConrady":
        raise ValueError(f"unsupported lens model {intr.get('ModelType')!r}")
    prm = [float(v) for v in intr["ModelParameters"]]
    if len(prm) < 14:
        raise ValueError(f"{len(prm)} model parameters, 14 expected")
    if (int(cam["SensorWidth"]), int(cam["SensorHeight"])) != (1024, 1024):
        raise ValueError(f"depth sensor {cam['SensorWidth']} x {cam['SensorHeight']}, "
                         "1024 x 1024 expected")
    (bw, bh), (ox, oy), (w, h) = K4A_DEPTH_MODES[mode]
    cx, cy, fx, fy = prm[0] * bw - ox - 0.5, prm[1] * bh - oy - 0.5, prm[2] * bw, prm[3] * bh
    return {"width": w, "height": h, "fx": fx, "fy": fy, "cx": cx, "cy": cy,
            "k": prm[4:10], "p2": prm[12], "p1": prm[13],
            "max_radius": float(cam.get("MetricRadius", 0.0)), "model": "brown_conrady"}


def _open(path: Path) -> Any:
    av = need_extra("av", "Azure Kinect / Orbbec .mkv recordings")
    why = matroska_truncation(path)
    if why is not None:
        raise FormatError(f"truncated Matroska recording: {why}", path)
    try:
        return av.open(str(path))
    except (av.error.FFmpegError, OSError) as exc:
        raise FormatError(f"not a readable Matroska recording: {exc}", path) from None


def read_mkv(path: str | Path, *, start: int = 0, stop: int | None = None, stride: int = 1,
             intrinsics: dict[str, float] | None = None, isolation: Isolation | None = None,
             keep_depth: bool = False) -> Recording:
    """Read the depth track of an Azure Kinect / Orbbec Femto recording to points.

    Parameters
    ----------
    path
        The ``.mkv`` file.
    start, stop, stride
        Depth frames used (slice of the track's frames).
    intrinsics
        A pinhole ``fx, fy, cx, cy`` (pixels) used instead of the calibration attachment
        (depth stays in millimetres unless it gives ``depth_scale``).
    isolation
        Depth range and pixel box kept.
    keep_depth
        Also return the depth images (metres) in :attr:`Recording.depth`.

    Returns
    -------
    Recording
        Points in metres in the depth camera's frame; ``meta`` with ``device``,
        ``resolution``, ``fps``, ``depth_mode``, ``intrinsics`` (``source``: the attachment or
        the file given), ``timestamps_s`` and ``duration_s``.

    Raises
    ------
    FormatError
        Not Matroska, truncated, no depth track, a depth frame of the wrong size.
    InputError
        No calibration and no ``intrinsics``.
    """
    p = Path(path)
    container = _open(p)
    with container:
        streams = list(container.streams)
        depth = [s for s in streams if s.type == "video"
                 and ("K4A_DEPTH_TRACK" in s.metadata or s.metadata.get("title") == "DEPTH")]
        if not depth:
            names = [s.metadata.get("title") or s.type for s in streams]
            raise FormatError("no depth track (a video track titled DEPTH, as the Azure Kinect "
                              f"and Orbbec recorders write); tracks: {', '.join(names) or 'none'}",
                              p)
        ds = depth[0]
        pix = ds.codec_context.pix_fmt
        if pix not in ("gray16be", "gray16le"):
            raise FormatError(f"the depth track is {ds.codec_context.name} / {pix}, not raw "
                              "16-bit depth", p)
        width, height = ds.codec_context.width, ds.codec_context.height
        mode = ds.metadata.get("K4A_DEPTH_MODE", "")
        calib_raw = None
        for s in streams:
            if s.type == "attachment" and ("K4A_CALIBRATION_FILE" in s.metadata
                                           or s.metadata.get("filename") == "calibration.json"):
                calib_raw = bytes(s.data)
        meta_tags = dict(container.metadata)
        container_duration = container.duration
        packets = []
        try:
            for pkt in container.demux(ds):
                if pkt.size == 0 or pkt.pts is None:
                    continue
                # the data of the frames that can be used only: a long recording's depth
                # does not all sit in memory
                keep = may_select(len(packets), start, stop, stride)
                packets.append((float(pkt.pts * pkt.time_base), bytes(pkt) if keep else b"",
                                None if not pkt.duration else float(pkt.duration * pkt.time_base)))
        except Exception as exc:  # PyAV's demuxer errors (av.error.*): a damaged file
            raise FormatError(f"damaged Matroska recording after {len(packets)} depth "
                              f"frame(s): {exc}", p) from None
    if not packets:
        raise FormatError("the depth track holds no frames", p)

    check_crop(isolation, width, height, p)
    scale = 0.001
    if intrinsics is not None:
        rays = pinhole_rays(width, height, intrinsics["fx"], intrinsics["fy"], intrinsics["cx"],
                            intrinsics["cy"])
        scale = float(intrinsics.get("depth_scale", scale))
        intr_meta: dict[str, Any] = {"source": "given", "model": "pinhole",
                                     **{k: float(intrinsics[k]) for k in ("fx", "fy", "cx", "cy")}}
    else:
        if calib_raw is None:
            raise InputError("no calibration attachment (calibration.json) in the recording; "
                             "pass --intrinsics FILE", p)
        try:
            intr = k4a_depth_intrinsics(json.loads(calib_raw), mode)
        except (ValueError, KeyError, TypeError) as exc:
            raise FormatError(f"unusable calibration attachment: {exc}", p) from None
        if (intr["width"], intr["height"]) != (width, height):
            raise FormatError(f"depth mode {mode} gives {intr['width']} x {intr['height']} "
                              f"images, the depth track is {width} x {height}", p)
        rays = brown_conrady_rays(width, height, intr["fx"], intr["fy"], intr["cx"], intr["cy"],
                                  np.asarray(intr["k"]), intr["p1"], intr["p2"],
                                  intr["max_radius"])
        intr_meta = {"source": "calibration.json attachment", **intr}

    times = [t for t, _, _ in packets]
    if len(times) > 1:
        fps = 1.0 / float(np.median(np.diff(times)))
    else:
        fps = 1.0 / packets[0][2] if packets[0][2] else None
    endian = ">u2" if pix == "gray16be" else "<u2"
    frames, names, images, used = [], [], [], []
    for i in select_frames(len(packets), start, stop, stride):
        t, raw, _ = packets[i]
        if len(raw) != width * height * 2:
            raise FormatError(f"depth frame of {len(raw)} bytes, {width} x {height} x 2 "
                              "expected", p, frame=i)
        img = np.frombuffer(raw, dtype=endian).reshape(height, width)
        frames.append(depth_image_points(img, rays, scale, isolation))
        names.append(f"depth {i} @ {t:.3f} s")
        used.append(t)
        if keep_depth:
            images.append((img * scale).astype(np.float32))
    device = meta_tags.get("title", "Matroska recording")
    serial = meta_tags.get("K4A_DEVICE_SERIAL_NUMBER")
    meta = {
        "device": device + (f" (serial {serial})" if serial else ""),
        "resolution": [width, height],
        "fps": None if fps is None else round(fps, 6),
        "depth_mode": mode or None,
        "depth_unit_m": scale,
        "intrinsics": intr_meta,
        "frames_in_file": len(packets),
        "timestamps_s": used,
        "duration_s": None if container_duration is None else container_duration / 1e6,
    }
    if isolation is not None and isolation.active:
        meta["isolation"] = isolation.to_dict()
    return Recording(frames, names, "mkv", meta, images)
