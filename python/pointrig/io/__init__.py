"""Reading and writing point-cloud sequences.

Supported inputs (see :func:`read_sequence`):

- a directory of per-frame files in natural order (``frame_2`` before ``frame_10``):
  PLY (ascii and binary), PCD (ascii, binary and binary_compressed), XYZ/TXT, NPY;
- one ``.npz`` holding all frames;
- a directory of 16-bit depth PNGs in millimetres plus an intrinsics JSON;
- a recording as a camera or app writes it, recognised by content (:mod:`.recordings`):
  Azure Kinect / Orbbec ``.mkv``, RealSense ``.bag`` and ROS 2 bags, Record3D ``.r3d``,
  Stray Scanner folders.

All points are returned as ``(N, 3)`` float64 in metres.
"""

from __future__ import annotations

from .atomic import atomic_path, write_json, write_npz
from .readers import (
    FRAME_FORMATS,
    detect_format,
    read_frame,
    read_sequence,
)
from .writers import write_frame, write_ply, write_sequence

__all__ = [
    "FRAME_FORMATS",
    "atomic_path",
    "detect_format",
    "read_frame",
    "read_sequence",
    "write_frame",
    "write_json",
    "write_npz",
    "write_ply",
    "write_sequence",
]
