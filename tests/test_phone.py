"""iPhone LiDAR captures: Record3D .r3d archives and Stray Scanner folders, written here in the
apps' layouts from a synthetic depth sequence.

Oracle: the closed-form back-projection of the depth written, with the colour camera's K
scaled to the depth image (``fx dw / w``, ...), within 1e-6 m.
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import av  # the capture extra (make setup installs it)
import lzfse
import numpy as np
import pytest
from PIL import Image

from pointrig.cli import main
from pointrig.errors import FormatError
from pointrig.io import detect_format, read_sequence
from pointrig.io.depthcam import Isolation

DW, DH = 64, 48
COLOUR = (960, 720)  # the colour image the app's K is for
K_COLOUR = {"fx": 700.0, "fy": 705.0, "cx": 481.0, "cy": 362.5}


def _depth(n: int) -> list[np.ndarray]:
    """A hand-sized blob sliding across a wall: (DH, DW) metres; NaN where there is none."""
    v, u = np.mgrid[0:DH, 0:DW].astype(np.float64)
    out = []
    for t in range(n):
        z = 1.2 + 0.001 * u
        blob = (u - 15 - 3 * t) ** 2 + (v - 20) ** 2 < 64
        z[blob] = 0.55 + 0.0005 * v[blob]
        z[:3, :5] = np.nan
        out.append(z)
    return out


def _expected(z: np.ndarray, colour: tuple[int, int]) -> np.ndarray:
    sx, sy = DW / colour[0], DH / colour[1]
    fx, fy = K_COLOUR["fx"] * sx, K_COLOUR["fy"] * sy
    cx, cy = K_COLOUR["cx"] * sx, K_COLOUR["cy"] * sy
    v, u = np.nonzero(np.nan_to_num(z) > 0)
    zz = z[v, u]
    return np.stack([(u - cx) * zz / fx, (v - cy) * zz / fy, zz], axis=1)


def _k_matrix() -> np.ndarray:
    return np.array([[K_COLOUR["fx"], 0, K_COLOUR["cx"]], [0, K_COLOUR["fy"], K_COLOUR["cy"]],
                     [0, 0, 1]])


def _write_r3d(path: Path, depth: list[np.ndarray]) -> None:
    meta = {"w": COLOUR[0], "h": COLOUR[1], "dw": DW, "dh": DH, "fps": 60, "cameraType": 1,
            "K": _k_matrix().T.reshape(-1).tolist(),  # column-major, as Record3D writes it
            "frameTimestamps": [10.0 + i / 60 for i in range(len(depth))],
            "poses": [[0, 0, 0, 1, 0, 0, 0]] * len(depth)}
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("metadata", json.dumps(meta))
        for i, d in enumerate(depth):
            z.writestr(f"rgbd/{i}.depth", lzfse.compress(d.astype("<f4").tobytes()))
            z.writestr(f"rgbd/{i}.jpg", b"")


def test_an_r3d_capture_round_trips_its_depth(tmp_path, capsys) -> None:
    depth = [d.astype(np.float32).astype(np.float64) for d in _depth(11)]
    r3d = tmp_path / "capture.zip"  # recognised by content, whatever its name
    _write_r3d(r3d, depth)
    assert detect_format(r3d) == "r3d"
    seq = read_sequence(r3d)
    assert len(seq) == 11 and seq.names[10] == "rgbd/10.depth"  # 10 after 9
    for got, z in zip(seq.frames, depth):
        np.testing.assert_allclose(got, _expected(z, COLOUR), rtol=0, atol=1e-6)
    assert seq.meta["fps"] == 60 and seq.meta["timestamps_s"][10] == pytest.approx(10 + 10 / 60)
    assert seq.meta["resolution"] == [DW, DH] and "LiDAR" in seq.meta["device"]
    near = read_sequence(r3d, isolation=Isolation(far=0.9), stop=3)
    for got, z in zip(near.frames, depth):
        assert len(got) == int((np.nan_to_num(z) > 0).sum() - (z > 0.9).sum())
    assert main(["info", str(r3d)]) == 0
    out = capsys.readouterr().out
    assert "64 x 48 px, 60 fps" in out and "r3d metadata K" in out


def test_a_damaged_r3d_frame_is_a_format_error(tmp_path, capsys) -> None:
    r3d = tmp_path / "bad.r3d"
    _write_r3d(r3d, _depth(3))
    with zipfile.ZipFile(r3d, "a") as z:
        z.writestr("rgbd/3.depth", b"bvx2 not lzfse at all")
    with pytest.raises(FormatError, match="rgbd/3.depth: damaged LZFSE depth"):
        read_sequence(r3d)
    assert main(["info", str(r3d), "--start", "3"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "frame 3" in err[0]


def _write_stray(root: Path, depth: list[np.ndarray], video: tuple[int, int] | None) -> None:
    (root / "depth").mkdir(parents=True)
    for i, z in enumerate(depth):
        Image.fromarray(np.rint(np.nan_to_num(z) * 1000).astype(np.uint16)).save(
            root / "depth" / f"{i:06d}.png")
    np.savetxt(root / "camera_matrix.csv", _k_matrix(), delimiter=",")
    rows = [[5.0 + i / 30, i, 0, 0, 0, 0, 0, 0, 1] for i in range(len(depth))]
    np.savetxt(root / "odometry.csv", rows, delimiter=",", comments="",
               header="timestamp, frame, x, y, z, qx, qy, qz, qw")
    if video is not None:
        with av.open(str(root / "rgb.mp4"), "w") as c:
            s = c.add_stream("mpeg4", rate=30)
            s.width, s.height, s.pix_fmt = video[0], video[1], "yuv420p"
            frame = av.VideoFrame.from_ndarray(np.zeros((video[1], video[0], 3), np.uint8),
                                               format="rgb24")
            for pkt in s.encode(frame):
                c.mux(pkt)
            for pkt in s.encode():
                c.mux(pkt)


@pytest.mark.parametrize("video", [None, (480, 360)], ids=["app-size", "rgb.mp4"])
def test_a_stray_scanner_folder_round_trips_its_depth(tmp_path, video) -> None:
    depth = [np.rint(np.nan_to_num(z) * 1000) / 1000 for z in _depth(3)]
    root = tmp_path / "stray"
    _write_stray(root, depth, video)
    colour = video or (1920, 1440)
    for path in (root, root / "depth"):
        assert detect_format(path) == "stray"
        seq = read_sequence(path)
        for got, z in zip(seq.frames, depth):
            np.testing.assert_allclose(got, _expected(z, colour), rtol=0, atol=1e-6)
    assert seq.meta["fps"] == pytest.approx(30.0)
    assert f"scaled from {colour[0]} x {colour[1]}" in seq.meta["intrinsics"]["source"]
    boxed = read_sequence(root, isolation=Isolation(crop=(10, 10, 40, 30)))
    for got, z in zip(boxed.frames, depth):
        assert len(got) == int((z[10:30, 10:40] > 0).sum())
