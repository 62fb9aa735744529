"""ROS bags (RealSense .bag, ROS 2 .db3 / .mcap) written here with rosbags' own writer from
synthetic sequences, read back by pointrig.

Oracles: the points the messages were made from (PointCloud2), and the closed-form
back-projection ``x = (u - cx) z / fx``, ``y = (v - cy) z / fy`` of the depth images written
(Image + CameraInfo), within 1e-6 m.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

from pointrig.cli import main
from pointrig.errors import ConfigError, FormatError, InputError
from pointrig.io import detect_format, read_sequence
from pointrig.io.depthcam import Isolation
from pointrig.synth import Camera, synthesize

W, H = 64, 48
K = {"fx": 58.0, "fy": 57.5, "cx": 31.2, "cy": 23.7}


def _depth_sequence(n: int = 3) -> list[np.ndarray]:
    """A ball moving across in front of a wall: (H, W) depth in metres, 0 at two holes."""
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    out = []
    for t in range(n):
        z = np.full((H, W), 1.6)
        cu, cv, r = 20.0 + 8 * t, 24.0, 10.0
        inside = (u - cu) ** 2 + (v - cv) ** 2 < r ** 2
        z[inside] = 1.0 - 0.2 * np.sqrt(1 - ((u - cu) ** 2 + (v - cv) ** 2)[inside] / r ** 2)
        z[5:9, 50:60] = 0.0
        out.append(z)
    return out


def _expected(z: np.ndarray) -> np.ndarray:
    v, u = np.nonzero(z > 0)
    zz = z[v, u]
    return np.stack([(u - K["cx"]) * zz / K["fx"], (v - K["cy"]) * zz / K["fy"], zz], axis=1)


def _header(ts, t: int):
    Header = ts.types["std_msgs/msg/Header"]
    Time = ts.types["builtin_interfaces/msg/Time"]
    kw = {"stamp": Time(sec=100 + t // 30, nanosec=(t % 30) * 33_333_333), "frame_id": "depth"}
    if "seq" in Header.__dataclass_fields__:
        kw["seq"] = t
    return Header(**kw)


def _camera_info(ts, ros1: bool):
    CameraInfo = ts.types["sensor_msgs/msg/CameraInfo"]
    Roi = ts.types["sensor_msgs/msg/RegionOfInterest"]
    Kmat = np.array([K["fx"], 0, K["cx"], 0, K["fy"], K["cy"], 0, 0, 1], dtype=np.float64)
    P = np.array([K["fx"], 0, K["cx"], 0, 0, K["fy"], K["cy"], 0, 0, 0, 1, 0], dtype=np.float64)
    arrays = {"D": np.zeros(5), "K": Kmat, "R": np.eye(3).reshape(-1), "P": P}
    if not ros1:
        arrays = {k.lower(): v for k, v in arrays.items()}
    return CameraInfo(header=_header(ts, 0), height=H, width=W, distortion_model="plumb_bob",
                      binning_x=0, binning_y=0,
                      roi=Roi(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False),
                      **arrays)


def _image(ts, z: np.ndarray, t: int, encoding: str, unit: float):
    Image = ts.types["sensor_msgs/msg/Image"]
    if encoding == "16UC1":
        arr = np.rint(z / unit).astype("<u2")
    else:
        arr = np.where(z > 0, z, np.nan).astype("<f4")
    return Image(header=_header(ts, t), height=H, width=W, encoding=encoding, is_bigendian=0,
                 step=W * arr.itemsize, data=np.frombuffer(arr.tobytes(), dtype=np.uint8))


def _cloud(ts, pts: np.ndarray, t: int):
    """A PointCloud2 with x, y, z float32 and an intensity field, 16 bytes a point."""
    PointCloud2 = ts.types["sensor_msgs/msg/PointCloud2"]
    PointField = ts.types["sensor_msgs/msg/PointField"]
    rec = np.zeros(len(pts), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("i", "<f4")])
    rec["x"], rec["y"], rec["z"], rec["i"] = pts[:, 0], pts[:, 1], pts[:, 2], 7.0
    fields = [PointField(name=n, offset=o, datatype=7, count=1)
              for n, o in (("x", 0), ("y", 4), ("z", 8), ("intensity", 12))]
    return PointCloud2(header=_header(ts, t), height=1, width=len(pts), fields=fields,
                       is_bigendian=False, point_step=16, row_step=16 * len(pts),
                       data=np.frombuffer(rec.tobytes(), dtype=np.uint8), is_dense=True)


def _write_realsense_bag(path: Path, depth: list[np.ndarray], unit: float) -> None:
    """A ROS 1 bag laid out as the RealSense recorder writes one."""
    ts = get_typestore(Stores.ROS1_NOETIC)
    base = "/device_0/sensor_0/Depth_0"
    with Writer1(path) as w:
        name = w.add_connection("/device_0/info", "diagnostic_msgs/msg/KeyValue", typestore=ts)
        KeyValue = ts.types["diagnostic_msgs/msg/KeyValue"]
        w.write(name, 1, ts.serialize_ros1(KeyValue(key="Name", value="Intel RealSense SR305"),
                                           "diagnostic_msgs/msg/KeyValue"))
        units = w.add_connection("/device_0/sensor_0/option/Depth Units/value",
                                 "std_msgs/msg/Float32", typestore=ts)
        w.write(units, 1, ts.serialize_ros1(ts.types["std_msgs/msg/Float32"](data=unit),
                                            "std_msgs/msg/Float32"))
        info = w.add_connection(f"{base}/info/camera_info", "sensor_msgs/msg/CameraInfo",
                                typestore=ts)
        w.write(info, 2, ts.serialize_ros1(_camera_info(ts, True), "sensor_msgs/msg/CameraInfo"))
        img = w.add_connection(f"{base}/image/data", "sensor_msgs/msg/Image", typestore=ts)
        for t, z in enumerate(depth):
            w.write(img, 10 + t * 33_333_333,
                    ts.serialize_ros1(_image(ts, z, t, "16UC1", unit), "sensor_msgs/msg/Image"))


def _write_ros2_bag(path: Path, plugin, depth: list[np.ndarray] | None = None,
                    clouds: list[np.ndarray] | None = None) -> None:
    ts = get_typestore(Stores.ROS2_HUMBLE)
    with Writer2(path, version=9, storage_plugin=plugin) as w:
        if depth is not None:
            info = w.add_connection("/camera/depth/camera_info", "sensor_msgs/msg/CameraInfo",
                                    typestore=ts)
            w.write(info, 1, ts.serialize_cdr(_camera_info(ts, False),
                                              "sensor_msgs/msg/CameraInfo"))
            img = w.add_connection("/camera/depth/image_rect_raw", "sensor_msgs/msg/Image",
                                   typestore=ts)
            for t, z in enumerate(depth):
                w.write(img, 10 + t * 33_333_333,
                        ts.serialize_cdr(_image(ts, z, t, "32FC1", 1.0), "sensor_msgs/msg/Image"))
        if clouds is not None:
            pc = w.add_connection("/camera/points", "sensor_msgs/msg/PointCloud2", typestore=ts)
            for t, pts in enumerate(clouds):
                w.write(pc, 20 + t * 33_333_333,
                        ts.serialize_cdr(_cloud(ts, pts, t), "sensor_msgs/msg/PointCloud2"))


def test_a_realsense_bag_round_trips_its_depth_images(tmp_path, capsys) -> None:
    unit = 0.000125
    depth = [np.rint(z / unit) * unit for z in _depth_sequence()]  # as stored
    bag = tmp_path / "capture.bag"
    _write_realsense_bag(bag, depth, unit)
    assert detect_format(bag) == "rosbag1"
    seq = read_sequence(bag)
    assert seq.fmt == "rosbag1" and len(seq) == 3
    for got, z in zip(seq.frames, depth):
        np.testing.assert_allclose(got, _expected(z), rtol=0, atol=1e-6)
    meta = seq.meta
    assert meta["device"] == "Intel RealSense SR305" and meta["depth_unit_m"] == unit
    assert meta["intrinsics"]["source"] == "CameraInfo /device_0/sensor_0/Depth_0/info/camera_info"
    assert meta["resolution"] == [W, H] and meta["fps"] == pytest.approx(30.0, rel=1e-6)
    assert meta["timestamps_s"][1] == pytest.approx(100 + 33_333_333e-9)
    assert main(["info", str(bag)]) == 0
    out = capsys.readouterr().out
    assert "device   Intel RealSense SR305" in out and "64 x 48 px, 30 fps" in out


@pytest.mark.parametrize("plugin", [StoragePlugin.SQLITE3, StoragePlugin.MCAP],
                         ids=["db3", "mcap"])
def test_ros2_bags_round_trip_depth_images_and_point_clouds(tmp_path, plugin) -> None:
    depth = [z.astype(np.float32).astype(np.float64) for z in _depth_sequence()]
    synth = synthesize("arm", n_frames=3, seed=0, camera=Camera.kinect(320))
    clouds = [f.astype(np.float32).astype(np.float64) for f in synth.frames]
    clouds[1][5] = np.nan  # a point with no return is dropped
    bag = tmp_path / "bag"
    _write_ros2_bag(bag, plugin, depth=depth, clouds=clouds)
    assert detect_format(bag) == "rosbag2"
    storage = next(bag.glob("*.db3" if plugin == StoragePlugin.SQLITE3 else "*.mcap"))
    assert detect_format(storage) == "rosbag2"  # its file, with metadata.yaml beside it

    with pytest.raises(ConfigError, match="several depth topics.*--topic"):
        read_sequence(bag)
    seq = read_sequence(storage, topic="/camera/depth/image_rect_raw")
    for got, z in zip(seq.frames, depth):
        np.testing.assert_allclose(got, _expected(z), rtol=0, atol=1e-6)
    part = read_sequence(storage, topic="/camera/depth/image_rect_raw", start=1, stride=2,
                         min_frames=1)
    assert len(part) == 1 and part.meta["frames_in_file"] == 3
    np.testing.assert_allclose(part.frames[0], _expected(depth[1]), rtol=0, atol=1e-6)
    assert seq.meta["depth_unit_m"] == 1.0

    seq = read_sequence(bag, topic="/camera/points")
    assert seq.meta["message_type"] == "sensor_msgs/msg/PointCloud2"
    for got, pts in zip(seq.frames, clouds):
        np.testing.assert_allclose(got, pts[np.isfinite(pts).all(axis=1)], rtol=0, atol=1e-6)
    near = read_sequence(bag, topic="/camera/points", isolation=Isolation(far=1.9))
    for got, pts in zip(near.frames, clouds):
        assert len(got) == int((pts[:, 2] <= 1.9).sum()) and got[:, 2].max() <= 1.9


def test_bag_errors_are_one_line_and_typed(tmp_path, capsys) -> None:
    bag = tmp_path / "bag"
    _write_ros2_bag(bag, StoragePlugin.SQLITE3, depth=_depth_sequence(2))
    with pytest.raises(InputError, match="no topic '/nope'.*/camera/depth/image_rect_raw"):
        read_sequence(bag, topic="/nope")
    assert main(["info", str(bag), "--topic", "/nope"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no topic '/nope'" in err[0] and str(bag) in err[0]
    with pytest.raises(InputError, match="is sensor_msgs/msg/CameraInfo, not a depth image"):
        read_sequence(bag, topic="/camera/depth/camera_info")
    with pytest.raises(InputError, match="goes past the 64 x 48"):
        read_sequence(bag, isolation=Isolation(crop=(0, 0, 65, 10)))

    cut = tmp_path / "cut.bag"
    _write_realsense_bag(cut, _depth_sequence(2), 0.001)
    cut.write_bytes(cut.read_bytes()[:3000])
    assert detect_format(cut) == "rosbag1"
    with pytest.raises(FormatError, match="ROS bag"):
        read_sequence(cut)
    assert main(["info", str(cut)]) == 1
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


@pytest.mark.slow
def test_extract_records_the_bag_in_skeleton_json(tmp_path) -> None:
    synth = synthesize("arm", n_frames=6, seed=1, camera=Camera.kinect(320))
    bag = tmp_path / "arm"
    _write_ros2_bag(bag, StoragePlugin.MCAP, clouds=list(synth.frames))
    out = tmp_path / "out"
    assert main(["extract", str(bag), "-o", str(out), "--no-pictures", "-q", "--far", "5"]) == 0
    src = json.loads((out / "skeleton.json").read_text())["source"]
    assert src["format"] == "rosbag2" and src["topic"] == "/camera/points"
    assert src["message_type"] == "sensor_msgs/msg/PointCloud2"
    assert src["fps"] == pytest.approx(30.0, rel=1e-6) and src["frames_in_file"] == 6
    assert src["timestamps_s"] == pytest.approx([100 + t * 33_333_333e-9 for t in range(6)])
    assert src["points_per_frame"] == [len(f) for f in synth.frames]
    assert src["isolation"] == {"near": None, "far": 5.0, "crop": None}


def test_preview_of_a_point_cloud_topic_draws_the_kept_points(tmp_path) -> None:
    synth = synthesize("arm", n_frames=2, seed=0, camera=Camera.kinect(320))
    bag = tmp_path / "bag"
    _write_ros2_bag(bag, StoragePlugin.SQLITE3, depth=_depth_sequence(2), clouds=synth.frames)
    png = tmp_path / "p.png"
    assert main(["preview", str(bag), "--topic", "/camera/points", "-o", str(png)]) == 0
    far = float(np.median(synth.frames[0][:, 2]))
    cut = tmp_path / "cut.png"
    assert main(["preview", str(bag), "--topic", "/camera/points", "--far", str(far),
                 "-o", str(cut)]) == 0

    def drawn(path: Path) -> int:  # pixels off the dark background
        img = np.asarray(Image.open(path).convert("RGB")).astype(int)
        return int((img.max(axis=2) > 40).sum())

    assert 0 < drawn(cut) < drawn(png)
