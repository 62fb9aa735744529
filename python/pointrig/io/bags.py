"""ROS bags: RealSense ``.bag`` files (ROS 1) and ROS 2 bags (``.db3`` / ``.mcap``), read
through ``rosbags`` (pure Python).

Two kinds of topic hold a sequence:

- ``sensor_msgs/Image`` depth images (encoding ``16UC1`` / ``mono16``: millimetres, unless the
  RealSense option topic ``.../option/Depth Units/value`` gives the unit; ``32FC1``: metres;
  0 or NaN: no depth), back-projected with the ``sensor_msgs/CameraInfo`` of the same camera
  (the info topic that shares the longest prefix with the image topic; its ``K`` matrix,
  the image treated as rectified);
- ``sensor_msgs/PointCloud2``: the ``x, y, z`` fields as stored (non-finite points dropped).

Without ``--topic`` the bag must hold one such topic (image topics count when their name says
``depth``); with it, the topic named.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ConfigError, FormatError, InputError
from .depthcam import (
    Isolation,
    Recording,
    check_crop,
    depth_image_points,
    may_select,
    need_extra,
    pinhole_rays,
    select_frames,
)

__all__ = ["ROSBAG1_MAGIC", "MCAP_MAGIC", "SQLITE_MAGIC", "read_bag", "pointcloud2_xyz",
           "image_depth"]

ROSBAG1_MAGIC = b"#ROSBAG V2.0\n"
MCAP_MAGIC = b"\x89MCAP0\r\n"
SQLITE_MAGIC = b"SQLite format 3\x00"

_IMAGE = "sensor_msgs/msg/Image"
_INFO = "sensor_msgs/msg/CameraInfo"
_CLOUD = "sensor_msgs/msg/PointCloud2"
#: PointField datatype -> numpy kind and size
_FIELD_TYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}


def bag_folder(path: Path) -> Path:
    """The path ``rosbags`` opens: a ROS 1 ``.bag`` file as is; for a ROS 2 bag its folder
    (the one holding ``metadata.yaml``), given the folder or one of its storage files."""
    if path.is_dir() or path.suffix.lower() == ".bag":
        return path
    if (path.parent / "metadata.yaml").is_file():
        return path.parent
    raise FormatError("a ROS 2 bag file is read with its folder's metadata.yaml, and there is "
                      "none beside it", path)


def pointcloud2_xyz(msg: Any) -> np.ndarray:
    """``(N, 3)`` float64 of a ``sensor_msgs/PointCloud2`` message's ``x, y, z`` fields, rows
    with a non-finite coordinate dropped.

    Raises
    ------
    ValueError
        No ``x``, ``y`` or ``z`` field, an unknown datatype, or less data than the message's
        size needs.
    """
    fields = {f.name: f for f in msg.fields}
    missing = [c for c in "xyz" if c not in fields]
    if missing:
        raise ValueError(f"the point cloud has no {'/'.join(missing)} field (fields: "
                         f"{', '.join(fields) or 'none'})")
    n = int(msg.width) * int(msg.height)
    step = int(msg.point_step)
    data = np.asarray(msg.data, dtype=np.uint8)
    rows = np.arange(int(msg.height))
    need = (int(msg.height) - 1) * int(msg.row_step) + int(msg.width) * step if n else 0
    if len(data) < need:
        raise ValueError(f"{len(data)} bytes of point data, {need} expected")
    order = ">" if msg.is_bigendian else "<"
    cols = []
    for c in "xyz":
        f = fields[c]
        if f.datatype not in _FIELD_TYPES:
            raise ValueError(f"field {c} has unknown datatype {f.datatype}")
        dt = np.dtype(order + _FIELD_TYPES[f.datatype])
        # byte offsets of the field in every point: row r, column k
        starts = (rows[:, None] * int(msg.row_step) + np.arange(int(msg.width))[None, :] * step
                  + int(f.offset)).reshape(-1)
        raw = data[starts[:, None] + np.arange(dt.itemsize)[None, :]]
        cols.append(raw.copy().view(dt).reshape(-1).astype(np.float64))
    pts = np.stack(cols, axis=1) if n else np.zeros((0, 3))
    return pts[np.isfinite(pts).all(axis=1)]


def image_depth(msg: Any) -> tuple[np.ndarray, float | None]:
    """The depth of a ``sensor_msgs/Image``: ``(H, W)`` array and its unit in metres (``None``:
    integer depth, the unit comes from elsewhere; 1.0 for ``32FC1``).

    Raises
    ------
    ValueError
        An encoding that is not depth, or a data size that does not match.
    """
    enc = str(msg.encoding).upper()
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    order = ">" if msg.is_bigendian else "<"
    if enc in ("16UC1", "MONO16"):
        dt, unit = np.dtype(order + "u2"), None
    elif enc == "32FC1":
        dt, unit = np.dtype(order + "f4"), 1.0
    else:
        raise ValueError(f"image encoding {msg.encoding!r} is not depth (16UC1, mono16, 32FC1)")
    data = np.asarray(msg.data, dtype=np.uint8)
    if step < w * dt.itemsize or len(data) < h * step:
        raise ValueError(f"{len(data)} bytes for a {w} x {h} {msg.encoding} image with rows "
                         f"of {step} bytes")
    rows = data[:h * step].reshape(h, step)[:, :w * dt.itemsize]
    return rows.copy().view(dt).reshape(h, w), unit


def _stamp(msg: Any, fallback_ns: int) -> float:
    """The message's header time, seconds (the bag's record time when the header has none)."""
    st = getattr(getattr(msg, "header", None), "stamp", None)
    if st is not None:
        sec = getattr(st, "sec", getattr(st, "secs", 0))
        nsec = getattr(st, "nanosec", getattr(st, "nsecs", 0))
        if sec or nsec:
            return float(sec) + float(nsec) * 1e-9
    return fallback_ns * 1e-9


def _choose_topic(conns: list[Any], topic: str | None, path: Path) -> Any:
    usable = [c for c in conns if c.msgtype == _CLOUD
              or (c.msgtype == _IMAGE and "depth" in c.topic.lower())]
    if topic is not None:
        named = [c for c in conns if c.topic == topic]
        if not named:
            listed = ", ".join(sorted({c.topic for c in usable})) or "none"
            raise InputError(f"no topic {topic!r} in the bag (its depth image and point cloud "
                             f"topics: {listed})", path)
        if named[0].msgtype not in (_IMAGE, _CLOUD):
            raise InputError(f"topic {topic!r} is {named[0].msgtype}, not a depth image or "
                             "point cloud", path)
        return named[0]
    topics = sorted({c.topic for c in usable})
    if not topics:
        listed = ", ".join(sorted({f"{c.topic} ({c.msgtype})" for c in conns})) or "none"
        raise InputError(f"no depth image or point cloud topic in the bag (topics: {listed})",
                         path)
    if len(topics) > 1:
        raise ConfigError(f"{path}: several depth topics, choose one with --topic: "
                          f"{', '.join(topics)}")
    return next(c for c in usable if c.topic == topics[0])


def _camera_info(reader: Any, conns: list[Any], image_topic: str) -> tuple[Any, str] | None:
    """The first CameraInfo message of the info topic sharing the longest prefix with the
    image topic, and that topic."""
    infos = [c for c in conns if c.msgtype == _INFO]
    if not infos:
        return None

    def shared(c: Any) -> int:
        a, b = c.topic.split("/"), image_topic.split("/")
        n = 0
        while n < min(len(a), len(b)) and a[n] == b[n]:
            n += 1
        return n

    best = max(infos, key=shared)
    for conn, _, raw in reader.messages(connections=[best]):
        return reader.deserialize(raw, conn.msgtype), best.topic
    return None


def _depth_units(reader: Any, conns: list[Any]) -> float | None:
    """RealSense's ``.../option/Depth Units/value`` (metres per unit), if recorded."""
    for c in conns:
        if c.topic.endswith("/option/Depth Units/value"):
            for conn, _, raw in reader.messages(connections=[c]):
                # a float32: its shortest decimal (0.000125, not 0.0001250000059)
                return float(str(np.float32(reader.deserialize(raw, conn.msgtype).data)))
    return None


def _device(reader: Any, conns: list[Any]) -> str | None:
    """The device name a RealSense bag records (``diagnostic_msgs/KeyValue`` ``Name``)."""
    for c in conns:
        if c.msgtype == "diagnostic_msgs/msg/KeyValue" and c.topic.count("/") <= 2:
            for conn, _, raw in reader.messages(connections=[c]):
                kv = reader.deserialize(raw, conn.msgtype)
                if kv.key == "Name":
                    return str(kv.value)
    return None


def read_bag(path: str | Path, fmt: str, *, start: int = 0, stop: int | None = None,
             stride: int = 1, topic: str | None = None,
             intrinsics: dict[str, float] | None = None, isolation: Isolation | None = None,
             keep_depth: bool = False) -> Recording:
    """Read a depth image or point cloud topic of a ROS bag to points.

    Parameters
    ----------
    path
        A ROS 1 ``.bag`` file, or a ROS 2 bag folder (or its ``.db3`` / ``.mcap`` file).
    fmt
        ``"rosbag1"`` or ``"rosbag2"``.
    start, stop, stride
        Messages used (a slice of the topic's messages).
    topic
        The topic (default: the bag's only depth image or point cloud topic).
    intrinsics
        Pinhole ``fx, fy, cx, cy`` (pixels, optional ``depth_scale``) instead of CameraInfo.
    isolation
        Depth range (and, for images, pixel box) kept.
    keep_depth
        Also return the depth images (metres) in :attr:`Recording.depth`.

    Returns
    -------
    Recording
        Points in metres in the message's frame; ``meta`` with ``topic``, ``message_type``,
        ``device`` (when the bag records it), ``resolution``, ``fps``, ``intrinsics``,
        ``timestamps_s`` and ``duration_s``.

    Raises
    ------
    InputError
        Unknown topic, no usable topic, no CameraInfo for a depth image topic.
    ConfigError
        Several usable topics and no ``topic``.
    FormatError
        An unreadable bag or message.
    """
    need_extra("rosbags", "ROS bags")
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    p = Path(path)
    try:
        reader = AnyReader([bag_folder(p)], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except (InputError, ConfigError):
        raise
    except Exception as exc:  # rosbags' reader errors: not a bag, or a damaged one
        raise FormatError(f"not a readable ROS bag: {exc}", p) from None
    try:
        return _read(reader, p, fmt, start, stop, stride, topic, intrinsics, isolation,
                     keep_depth)
    except (InputError, ConfigError):
        raise
    except Exception as exc:  # a damaged message, a chunk cut short
        raise FormatError(f"damaged ROS bag: {type(exc).__name__}: {exc}", p) from None
    finally:
        reader.close()


def _read(reader: Any, p: Path, fmt: str, start: int, stop: int | None, stride: int,
          topic: str | None, intrinsics: dict[str, float] | None,
          isolation: Isolation | None, keep_depth: bool) -> Recording:
    conns = list(reader.connections)
    conn = _choose_topic(conns, topic, p)
    # the data of the messages that can be used only (a long bag does not all sit in memory)
    stamps = [(c, t, raw if may_select(i, start, stop, stride) else b"")
              for i, (c, t, raw) in enumerate(reader.messages(connections=[conn]))]
    if not stamps:
        raise InputError(f"topic {conn.topic!r} holds no messages", p)
    idx = select_frames(len(stamps), start, stop, stride)
    meta: dict[str, Any] = {"topic": conn.topic, "message_type": conn.msgtype,
                            "frames_in_file": len(stamps)}
    device = _device(reader, conns)
    if device:
        meta["device"] = device
    frames, names, images, times = [], [], [], []
    if conn.msgtype == _CLOUD:
        if isolation is not None and isolation.crop is not None:
            raise ConfigError(f"--crop is a pixel box of depth images; {conn.topic} holds "
                              "point clouds (crop those with --crop-min/--crop-max, metres)")
        for i in idx:
            c, t, raw = stamps[i]
            msg = reader.deserialize(raw, c.msgtype)
            try:
                pts = pointcloud2_xyz(msg)
            except ValueError as exc:
                raise FormatError(str(exc), p, frame=i) from None
            if isolation is not None:
                pts = pts[isolation.depth_mask(pts[:, 2])]
            frames.append(pts)
            times.append(_stamp(msg, t))
            names.append(f"{conn.topic} #{i}")
    else:
        unit = _depth_units(reader, conns)
        rays = None
        for i in idx:
            c, t, raw = stamps[i]
            msg = reader.deserialize(raw, c.msgtype)
            try:
                depth, img_unit = image_depth(msg)
            except ValueError as exc:
                raise FormatError(str(exc), p, frame=i) from None
            h, w = depth.shape
            if rays is None:
                rays, meta["intrinsics"] = _rays(reader, conns, conn.topic, intrinsics, w, h, p)
                meta["resolution"] = [w, h]
                check_crop(isolation, w, h, p)
            elif rays.shape[:2] != (h, w):
                raise FormatError(f"image of {w} x {h} pixels, the first was "
                                  f"{rays.shape[1]} x {rays.shape[0]}", p, frame=i)
            scale = img_unit if img_unit is not None else (
                intrinsics.get("depth_scale", unit or 0.001) if intrinsics else (unit or 0.001))
            meta["depth_unit_m"] = scale
            frames.append(depth_image_points(depth, rays, scale, isolation))
            times.append(_stamp(msg, t))
            names.append(f"{conn.topic} #{i}")
            if keep_depth:
                images.append((np.nan_to_num(depth.astype(np.float64)) * scale)
                              .astype(np.float32))
    all_times = [t * 1e-9 for _, t, _ in stamps]
    meta["fps"] = (round(1.0 / float(np.median(np.diff(all_times))), 6)
                   if len(all_times) > 1 and np.median(np.diff(all_times)) > 0 else None)
    meta["timestamps_s"] = times
    meta["duration_s"] = all_times[-1] - all_times[0] if len(all_times) > 1 else 0.0
    if isolation is not None and isolation.active:
        meta["isolation"] = isolation.to_dict()
    return Recording(frames, names, fmt, meta, images)


def _rays(reader: Any, conns: list[Any], image_topic: str,
          intrinsics: dict[str, float] | None, w: int, h: int,
          p: Path) -> tuple[np.ndarray, dict[str, Any]]:
    """The ray table of a depth image topic and the intrinsics' description."""
    if intrinsics is not None:
        k = {key: float(intrinsics[key]) for key in ("fx", "fy", "cx", "cy")}
        return pinhole_rays(w, h, **k), {"source": "given", "model": "pinhole", **k}
    found = _camera_info(reader, conns, image_topic)
    if found is None:
        raise InputError(f"no sensor_msgs/CameraInfo topic for {image_topic}; pass "
                         "--intrinsics FILE", p)
    info, info_topic = found
    K = np.asarray(getattr(info, "k", getattr(info, "K", None)), dtype=np.float64).reshape(-1)
    if K.shape != (9,) or not K[0] > 0 or not K[4] > 0:
        raise FormatError(f"CameraInfo on {info_topic} has no usable K matrix", p)
    if (int(info.width), int(info.height)) not in ((w, h), (0, 0)):
        raise FormatError(f"CameraInfo on {info_topic} is for {info.width} x {info.height}, "
                          f"the images are {w} x {h}", p)
    k = {"fx": float(K[0]), "fy": float(K[4]), "cx": float(K[2]), "cy": float(K[5])}
    return pinhole_rays(w, h, **k), {"source": f"CameraInfo {info_topic}", "model": "pinhole",
                                     **k}
