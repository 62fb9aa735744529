"""Recordings as depth cameras and their apps write them, recognised by their content.

=============  ==========================================================  ==================
format         what                                                        recognised by
=============  ==========================================================  ==================
``mkv``        Azure Kinect / Orbbec Femto recording (:mod:`.mkv`)         EBML magic bytes
``rosbag1``    RealSense ``.bag`` and other ROS 1 bags (:mod:`.bags`)      ``#ROSBAG V2.0``
``rosbag2``    ROS 2 bag: folder, or its ``.db3`` / ``.mcap`` file         ``metadata.yaml``,
               (:mod:`.bags`)                                              SQLite/MCAP magic
``r3d``        Record3D ``.r3d`` export (:mod:`.phone`)                    zip: ``metadata``,
                                                                           ``rgbd/N.depth``
``stray``      Stray Scanner folder (:mod:`.phone`)                        ``camera_matrix.csv``
                                                                           and ``depth/``
=============  ==========================================================  ==================

Each reader returns a :class:`~pointrig.io.depthcam.Recording`: points in metres in the
camera frame, and a description (device, resolution, frame rate, intrinsics and where they came
from, frame times) that ``pointrig info`` prints and ``skeleton.json`` records as ``source``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ConfigError
from .bags import MCAP_MAGIC, ROSBAG1_MAGIC, SQLITE_MAGIC
from .depthcam import Isolation, Recording
from .mkv import MATROSKA_MAGIC
from .phone import is_r3d, is_stray

__all__ = ["RECORDING_FORMATS", "detect_recording", "read_recording", "isolate_points"]

#: the recording formats, by the name :func:`detect_recording` gives them
RECORDING_FORMATS = ("mkv", "rosbag1", "rosbag2", "r3d", "stray")


def detect_recording(path: str | Path) -> str | None:
    """The recording format of ``path`` from its content, or ``None`` when it is none of
    :data:`RECORDING_FORMATS` (a folder of frames, an ``.npz``, ...)."""
    p = Path(path)
    if p.is_file():
        with open(p, "rb") as fh:
            head = fh.read(16)
        if head.startswith(MATROSKA_MAGIC):
            return "mkv"
        if head.startswith(ROSBAG1_MAGIC[:8]):
            return "rosbag1"
        if head.startswith(MCAP_MAGIC) or head.startswith(SQLITE_MAGIC):
            return "rosbag2"
        if head.startswith(b"PK\x03\x04") and is_r3d(p):
            return "r3d"
    elif is_stray(p):
        return "stray"
    elif p.is_dir() and (p / "metadata.yaml").is_file():
        head = (p / "metadata.yaml").read_bytes()[:200]
        if b"rosbag2_bagfile_information" in head:
            return "rosbag2"
    return None


def read_recording(path: str | Path, fmt: str, *, start: int = 0, stop: int | None = None,
                   stride: int = 1, intrinsics: dict[str, float] | None = None,
                   topic: str | None = None, isolation: Isolation | None = None,
                   keep_depth: bool = False) -> Recording:
    """Read a recording of format ``fmt`` (:func:`detect_recording`).

    Parameters
    ----------
    path
        The recording.
    start, stop, stride
        Frames used (a slice of the recording's depth frames).
    intrinsics
        Pinhole ``fx, fy, cx, cy`` (pixels) to use instead of the recording's own.
    topic
        For bags: the topic read (default: the only depth image or point cloud topic).
    isolation
        Depth range and pixel box kept.
    keep_depth
        Also keep the depth images (for the preview).

    Returns
    -------
    Recording
        Points ``(N_t, 3)`` metres, camera frame, and the recording's description.
    """
    p = Path(path)
    if topic is not None and fmt not in ("rosbag1", "rosbag2"):
        raise ConfigError(f"--topic is for ROS bags; {p} is a {fmt} recording")
    if fmt == "mkv":
        from .mkv import read_mkv

        return read_mkv(p, start=start, stop=stop, stride=stride, intrinsics=intrinsics,
                        isolation=isolation, keep_depth=keep_depth)
    if fmt in ("rosbag1", "rosbag2"):
        from .bags import read_bag

        return read_bag(p, fmt, start=start, stop=stop, stride=stride, topic=topic,
                        intrinsics=intrinsics, isolation=isolation, keep_depth=keep_depth)
    if fmt in ("r3d", "stray"):
        from .phone import read_r3d, read_stray

        reader = read_r3d if fmt == "r3d" else read_stray
        return reader(p, start=start, stop=stop, stride=stride, intrinsics=intrinsics,
                      isolation=isolation, keep_depth=keep_depth)
    raise ConfigError(f"unknown recording format {fmt!r}")


def isolate_points(pts: np.ndarray, fmt: str, meta: dict[str, Any],
                   isolation: Isolation, path: Path) -> np.ndarray:
    """Subject isolation for inputs read as points (recordings isolate on the depth image
    instead): the depth range on ``z`` (camera frame, metres); the pixel box on depth PNGs, by
    projecting each point back through the pinhole intrinsics they were read with.

    Parameters
    ----------
    pts
        ``(N, 3)`` float64, metres, camera frame.
    fmt, meta
        The format and the reader's description (``meta["intrinsics"]`` for depth PNGs).
    isolation
        What is kept.
    path
        The input, for messages.

    Returns
    -------
    numpy.ndarray
        The kept points, ``(M, 3)``.
    """
    if isolation.crop is not None and fmt != "depth-png":
        raise ConfigError(f"--crop is a pixel box of depth images; {path} holds {fmt} points "
                          "(crop those with --crop-min/--crop-max, metres)")
    keep = isolation.depth_mask(pts[:, 2])
    if isolation.crop is not None:
        k = meta["intrinsics"]
        z = np.where(pts[:, 2] > 0, pts[:, 2], 1.0)
        u = np.rint(pts[:, 0] / z * k["fx"] + k["cx"])
        v = np.rint(pts[:, 1] / z * k["fy"] + k["cy"])
        u0, v0, u1, v1 = isolation.crop
        keep &= (u >= u0) & (u < u1) & (v >= v0) & (v < v1)
    return pts[keep]
