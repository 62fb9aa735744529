"""Sequence input: every format round-trips against an independent writer, every bad input
raises a typed error naming the file/frame."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from pointrig.errors import EmptyFrameError, FormatError, InputError
from pointrig.io import read_frame, read_sequence, write_frame, write_sequence
from pointrig.io.readers import depth_to_points, lzf_decompress, natural_key, voxel_downsample

DATA = Path(__file__).parent / "data"


def _frames(rng, n_frames=3, n=200):
    return [rng.normal(size=(n + 7 * t, 3)) for t in range(n_frames)]


def _plyfile_write(path: Path, pts: np.ndarray, text: bool, byte_order: str = "<") -> None:
    """Write ``pts`` with plyfile: float64 x, y, z plus a uchar colour, and a face element
    (a list property) after the vertices, as meshes exported by other tools have."""
    from plyfile import PlyData, PlyElement

    vert = np.empty(len(pts), dtype=[("x", "f8"), ("y", "f8"), ("z", "f8"), ("red", "u1")])
    vert["x"], vert["y"], vert["z"] = pts.T
    vert["red"] = np.arange(len(pts)) % 256
    face = np.empty(1, dtype=[("vertex_indices", "i4", (3,))])
    face["vertex_indices"] = [[0, 1, 2]]
    PlyData([PlyElement.describe(vert, "vertex"), PlyElement.describe(face, "face")],
            text=text, byte_order=byte_order).write(str(path))


@pytest.mark.parametrize("text,byte_order", [(False, "<"), (False, ">"), (True, "=")])
def test_plyfile_written_frames_round_trip(tmp_path, rng, text, byte_order):
    frames = _frames(rng)
    for t, pts in enumerate(frames):
        _plyfile_write(tmp_path / f"frame_{t}.ply", pts, text, byte_order)
    seq = read_sequence(tmp_path)
    assert seq.fmt == "ply"
    assert len(seq) == len(frames)
    for got, want in zip(seq.frames, frames):
        np.testing.assert_array_equal(got, want)  # plyfile's ascii keeps all 17 digits


#: the 48 points of tests/data/open3d_grid_*.pcd: a 4 x 4 x 3 grid, exact in float32, written
#: by Open3D with normals and colours (fields x y z normal_x normal_y normal_z rgb)
def _open3d_grid() -> np.ndarray:
    i, j, k = np.meshgrid(np.arange(4), np.arange(4), np.arange(3), indexing="ij")
    return np.stack([i / 8 - 0.25, j / 4 + 0.5, k / 16 + 2.0], -1).reshape(-1, 3)


@pytest.mark.parametrize("data", ["ascii", "binary", "binary_compressed"])
def test_open3d_written_pcd(tmp_path, data):
    """PCD files written by Open3D, one per DATA kind; the compressed one's LZF stream has
    literal runs, long (extended) and overlapping matches."""
    src = DATA / f"open3d_grid_{data}.pcd"
    assert f"DATA {data}\n".encode() in src.read_bytes()
    np.testing.assert_array_equal(read_frame(src), _open3d_grid())
    for t in range(2):
        shutil.copy(src, tmp_path / f"frame_{t}.pcd")
    seq = read_sequence(tmp_path)
    assert seq.fmt == "pcd" and len(seq) == 2
    np.testing.assert_array_equal(seq[1], _open3d_grid())


def _lzf_literals(data: bytes) -> bytes:
    """LZF with literal runs only (control byte = run length - 1, runs of at most 32): valid
    LZF by the format's definition, made without any match search."""
    return b"".join(bytes([len(data[i:i + 32]) - 1]) + data[i:i + 32]
                    for i in range(0, len(data), 32))


def _pcd_compressed(header: str, raw: bytes, stream: bytes | None = None) -> bytes:
    stream = _lzf_literals(raw) if stream is None else stream
    return (header.encode() + np.array([len(stream), len(raw)], "<u4").tobytes() + stream)


def test_compressed_pcd_fields_column_by_column(tmp_path, rng):
    """A field before x, a field with COUNT 3 and mixed sizes: each field's values of all
    points are stored contiguously, in the header's field order."""
    n = 37
    pts = rng.normal(size=(n, 3))
    columns = [rng.integers(0, 2**16, size=(n, 3)).astype("<u2"), pts[:, 0].astype("<f8"),
               pts[:, 1].astype("<f8"), pts[:, 2].astype("<f4"), np.zeros(n, "<u4")]
    header = ("VERSION 0.7\nFIELDS intensity x y z rgb\nSIZE 2 8 8 4 4\nTYPE U F F F U\n"
              f"COUNT 3 1 1 1 1\nWIDTH {n}\nHEIGHT 1\nPOINTS {n}\nDATA binary_compressed\n")
    (tmp_path / "a.pcd").write_bytes(
        _pcd_compressed(header, b"".join(c.tobytes() for c in columns)))
    got = read_frame(tmp_path / "a.pcd")
    np.testing.assert_array_equal(got[:, :2], pts[:, :2])
    np.testing.assert_array_equal(got[:, 2], pts[:, 2].astype(np.float32))


def test_lzf_decompress_by_the_format():
    """Streams made by hand from the format: a literal run, a match that overlaps what it
    writes, an extended length, a 13-bit offset."""
    assert lzf_decompress(b"\x02abc", 3) == b"abc"
    # ctrl 0x20: length 1 + 2, offset 0 + 1: repeats the one byte before it
    assert lzf_decompress(b"\x00a\x20\x00", 4) == b"aaaa"
    # ctrl 0xe0 + 10: length 7 + 10 + 2 = 19 copies of the two bytes "ab" back
    assert lzf_decompress(b"\x01ab\xe0\x0a\x01", 21) == b"ab" * 10 + b"a"
    text = bytes(range(256)) + bytes(range(100))
    # ctrl 0x21, 0x00: length 3 from 0x100 + 0 + 1 = 257 bytes back
    want = text + text[-257:-254]
    assert lzf_decompress(_lzf_literals(text) + b"\x21\x00", len(want)) == want
    assert lzf_decompress(b"", 0) == b""


@pytest.mark.parametrize("stream, size, match", [
    (b"\x05abc", 6, "past the end"),
    (b"\x00a\x20\x01", 4, "before the start"),
    (b"\x00a\xe0", 20, "ends inside"),
    (b"\x00a\x20", 4, "ends inside"),
    (b"\x02abc", 4, "3 bytes"),
    (b"\x02abc", 2, "more than"),
])
def test_lzf_decompress_refuses_corrupt_streams(stream, size, match):
    with pytest.raises(ValueError, match=match):
        lzf_decompress(stream, size)


def test_corrupt_compressed_pcd_names_the_file(tmp_path):
    good = (DATA / "open3d_grid_binary_compressed.pcd").read_bytes()
    head = good[:good.index(b"binary_compressed\n") + len(b"binary_compressed\n")]
    sizes = np.frombuffer(good, "<u4", 2, len(head))
    cases = {
        "cut.pcd": (good[:-10], "truncated"),
        "nosizes.pcd": (head + b"\x01", "no sizes"),
        "small.pcd": (head + np.array([sizes[0], 40], "<u4").tobytes() + good[len(head) + 8:],
                      "holds 40 bytes"),
        "bad.pcd": (head + sizes.tobytes() + b"\x20\x05" + good[len(head) + 10:], "corrupt"),
    }
    for name, (body, match) in cases.items():
        (tmp_path / name).write_bytes(body)
        with pytest.raises(FormatError, match=match) as err:
            read_frame(tmp_path / name)
        assert name in str(err.value)


@pytest.mark.parametrize("fmt", ["ply", "npy", "xyz", "pcd"])
def test_own_writers_round_trip_and_plyfile_reads_ply(tmp_path, rng, fmt):
    frames = _frames(rng)
    write_sequence(tmp_path, frames, fmt=fmt)
    seq = read_sequence(tmp_path)
    for got, want in zip(seq.frames, frames):
        np.testing.assert_allclose(got, want, rtol=1e-8)
    if fmt == "ply":  # an independent reader agrees on our binary float64 PLY
        from plyfile import PlyData

        vert = PlyData.read(str(tmp_path / "frame_0000.ply"))["vertex"]
        np.testing.assert_array_equal(np.stack([vert["x"], vert["y"], vert["z"]], 1), frames[0])


def test_xyz_and_txt_with_extra_columns_and_comments(tmp_path):
    (tmp_path / "a.txt").write_text("# header\n1 2 3 9 9\n4,5,6\n\n")
    (tmp_path / "b.txt").write_text("7 8 9\n")
    seq = read_sequence(tmp_path)
    np.testing.assert_array_equal(seq[0], [[1, 2, 3], [4, 5, 6]])
    assert seq.fmt == "xyz"


def test_npz_one_array_and_per_frame_arrays(tmp_path, rng):
    frames = _frames(rng, 4)
    np.savez(tmp_path / "seq.npz", **{f"frame_{t}": f for t, f in enumerate(frames)})
    seq = read_sequence(tmp_path / "seq.npz")
    for got, want in zip(seq.frames, frames):
        np.testing.assert_array_equal(got, want)
    stacked = rng.normal(size=(5, 50, 3))
    np.savez(tmp_path / "stack.npz", points=stacked)
    seq = read_sequence(tmp_path / "stack.npz")
    assert len(seq) == 5 and np.array_equal(seq[4], stacked[4])


def test_natural_order(tmp_path):
    for t in (10, 2, 1):
        np.save(tmp_path / f"frame_{t}.npy", np.full((3, 3), float(t)))
    seq = read_sequence(tmp_path)
    assert [f[0, 0] for f in seq.frames] == [1.0, 2.0, 10.0]
    assert sorted(["f10", "f2"], key=natural_key) == ["f2", "f10"]


def test_depth_png_back_projection(tmp_path):
    from PIL import Image

    intr = {"fx": 500.0, "fy": 400.0, "cx": 3.0, "cy": 2.0, "depth_scale": 0.001}
    (tmp_path / "intrinsics.json").write_text(json.dumps(intr))
    depth = np.zeros((5, 7), dtype=np.uint16)
    depth[1, 4] = 1500
    depth[3, 0] = 2000
    for t in range(2):
        Image.fromarray(depth).save(tmp_path / f"d_{t}.png")
    seq = read_sequence(tmp_path)
    assert seq.fmt == "depth-png"
    pts = seq[0]
    want = np.array([[(4 - 3) * 1.5 / 500, (1 - 2) * 1.5 / 400, 1.5],
                     [(0 - 3) * 2.0 / 500, (3 - 2) * 2.0 / 400, 2.0]])
    np.testing.assert_allclose(pts, want)
    np.testing.assert_allclose(depth_to_points(depth, intr), want)


#: what Open3D's ``write_pinhole_camera_intrinsic`` writes for a 32 x 24 camera with
#: fx 41, fy 37, cx 15.3, cy 11.8: ``K`` column-major, as its recorders' ``intrinsic.json``
_OPEN3D_INTRINSIC_JSON = """{
\t"height" : 24,
\t"intrinsic_matrix" : 
\t[
\t\t41.0,
\t\t0.0,
\t\t0.0,
\t\t0.0,
\t\t37.0,
\t\t0.0,
\t\t15.300000000000001,
\t\t11.800000000000001,
\t\t1.0
\t],
\t"width" : 32
}"""


def _recorder_layout(root: Path, rng: np.random.Generator, n_frames: int = 2) -> list:
    """An Open3D-recorder layout: ``root/depth/000000.png ...`` (16-bit, mm) and
    ``root/intrinsic.json`` as Open3D writes it. Returns the depth images ``(24, 32)``."""
    from PIL import Image

    (root / "depth").mkdir(parents=True)
    (root / "intrinsic.json").write_text(_OPEN3D_INTRINSIC_JSON)
    depths = []
    for t in range(n_frames):
        d = rng.integers(400, 4000, size=(24, 32)).astype(np.uint16)
        d[rng.random(d.shape) < 0.3] = 0  # invalid pixels
        Image.fromarray(d).save(root / "depth" / f"{t:06d}.png")
        depths.append(d)
    return depths


def _back_project(depth: np.ndarray, fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """Pinhole back-projection pixel by pixel (mm depth, 0 = no depth), as Open3D's
    ``create_from_depth_image``: ``x = (u - cx) z / fx``, ``y = (v - cy) z / fy``."""
    rows = []
    for v in range(depth.shape[0]):
        for u in range(depth.shape[1]):
            if depth[v, u]:
                z = float(depth[v, u]) / 1000.0
                rows.append(((u - cx) * z / fx, (v - cy) * z / fy, z))
    return np.array(rows)


def _sorted_rows(a: np.ndarray) -> np.ndarray:
    return a[np.lexsort(a.T[::-1])]


def test_depth_png_open3d_recorder_layout(tmp_path, rng):
    """A folder of depth PNGs with Open3D's ``intrinsic.json`` in the parent (its RealSense /
    Azure Kinect recorders' layout) reads without options and back-projects as a pinhole."""
    depths = _recorder_layout(tmp_path / "rec", rng)
    seq = read_sequence(tmp_path / "rec" / "depth")
    assert seq.fmt == "depth-png" and len(seq) == 2
    for got, d in zip(seq.frames, depths):
        want = _back_project(d, 41.0, 37.0, 15.3, 11.8)
        assert got.shape == want.shape == ((d > 0).sum(), 3)
        np.testing.assert_allclose(_sorted_rows(got), _sorted_rows(want), rtol=1e-12)
    # what was used is recorded (skeleton.json's "source", `pointrig info`)
    used = seq.meta["intrinsics"]
    assert used["path"] == str(tmp_path / "rec" / "intrinsic.json")
    assert (used["fx"], used["fy"], used["cx"], used["cy"]) == (41.0, 37.0, 15.3, 11.8)
    assert (used["width"], used["height"], used["depth_scale"]) == (32.0, 24.0, 0.001)
    assert seq.subset(0, 1).meta == seq.meta


def test_info_names_the_intrinsics_used(tmp_path, rng, capsys):
    from pointrig.cli import main

    _recorder_layout(tmp_path / "rec", rng)
    assert main(["info", str(tmp_path / "rec" / "depth")]) == 0
    out = capsys.readouterr().out
    assert "camera   fx 41 fy 37 cx 15.3 cy 11.8 px, depth unit 0.001 m" in out
    assert str(tmp_path / "rec" / "intrinsic.json") in out


def test_intrinsics_open3d_matrix_and_lookup_order(tmp_path):
    """Open3D's column-major ``intrinsic_matrix`` gives fx, fy, cx, cy and the image size; our
    own file in the folder wins over Open3D's in the parent."""
    from pointrig.io.readers import find_intrinsics, read_intrinsics

    doc = {"width": 640, "height": 480,
           "intrinsic_matrix": [525.0, 0.0, 0.0, 0.0, 520.0, 0.0, 319.5, 239.5, 1.0]}
    (tmp_path / "intrinsic.json").write_text(json.dumps(doc))
    got = read_intrinsics(tmp_path / "intrinsic.json")
    assert got == {"fx": 525.0, "fy": 520.0, "cx": 319.5, "cy": 239.5, "depth_scale": 0.001,
                   "width": 640.0, "height": 480.0}
    sub = tmp_path / "depth"
    sub.mkdir()
    assert find_intrinsics(sub) == tmp_path / "intrinsic.json"
    (sub / "intrinsics.json").write_text(json.dumps({"fx": 1, "fy": 1, "cx": 0, "cy": 0}))
    assert find_intrinsics(sub) == sub / "intrinsics.json"


@pytest.mark.parametrize("doc, match", [
    ({"intrinsic_matrix": [525.0, 0.0, 0.0, 0.0, 520.0, 0.0, 319.5, 239.5]}, "9 finite"),
    ({"intrinsic_matrix": [525.0, 3.0, 0.0, 0.0, 520.0, 0.0, 319.5, 239.5, 1.0]}, "pinhole"),
    ({"intrinsic_matrix": [[525.0, 0.0, 319.5], [0.0, 520.0, 239.5], [0, 0]]}, "9 finite"),
    ({"intrinsic_matrix": [[525.0, 0.0, 319.5], [0.0, 520.0, 239.5], [0, 0, 1]]}, "9 finite"),
    ({"fx": 500, "fy": 500, "cx": 1, "cy": 1, "width": 0, "height": 4}, "whole numbers"),
    ({"fx": 500, "fy": "x", "cx": 1, "cy": 1}, "numbers"),
    ({"fx": 500, "fy": 500, "cx": 1}, "'cy'"),
    ({"fx": 500, "fy": 500, "cx": 1, "cy": 1, "width": 6}, "both or neither"),
    ([1, 2, 3], "JSON object"),
])
def test_bad_intrinsics(tmp_path, doc, match):
    from PIL import Image

    (tmp_path / "intrinsics.json").write_text(json.dumps(doc))
    for t in range(2):
        Image.fromarray(np.ones((4, 6), dtype=np.uint16)).save(tmp_path / f"d{t}.png")
    with pytest.raises(InputError, match=match) as err:
        read_sequence(tmp_path)
    assert str(err.value).count("intrinsics.json") == 1  # named once, not nested


def test_depth_png_size_differs_from_intrinsics(tmp_path):
    """Intrinsics for another resolution are refused, naming the frame file."""
    from PIL import Image

    doc = {"fx": 500, "fy": 500, "cx": 3, "cy": 2, "width": 640, "height": 480}
    (tmp_path / "intrinsics.json").write_text(json.dumps(doc))
    for t in range(2):
        Image.fromarray(np.ones((4, 6), dtype=np.uint16)).save(tmp_path / f"d{t}.png")
    with pytest.raises(InputError, match="6 x 4 pixels .* 640 x 480") as err:
        read_sequence(tmp_path)
    assert "d0.png" in str(err.value)


def test_frame_range_crop_voxel_scale(tmp_path, rng):
    frames = [rng.uniform(-1000, 1000, size=(500, 3)) for _ in range(6)]
    write_sequence(tmp_path, frames, fmt="npy")
    seq = read_sequence(tmp_path, start=1, stop=5, stride=2, scale=0.001,
                        crop_min=(-0.5, -0.5, -0.5), crop_max=(0.5, 0.5, 0.5))
    assert len(seq) == 2
    for got, src in zip(seq.frames, (frames[1], frames[3])):
        m = src * 0.001
        keep = (np.abs(m) <= 0.5).all(axis=1)
        np.testing.assert_allclose(got, m[keep])
    pts = np.array([[0.01, 0.01, 0.01], [0.03, 0.03, 0.03], [0.51, 0.0, 0.0]])
    np.testing.assert_allclose(voxel_downsample(pts, 0.1), [[0.02, 0.02, 0.02], [0.51, 0, 0]])


# ---- bad input ---------------------------------------------------------------------------

def test_missing_path(tmp_path):
    with pytest.raises(InputError, match="not found") as e:
        read_sequence(tmp_path / "nope")
    assert "nope" in str(e.value)


def test_empty_folder(tmp_path):
    with pytest.raises(InputError, match="no frame files"):
        read_sequence(tmp_path)


def test_mixed_formats(tmp_path, rng):
    np.save(tmp_path / "a.npy", rng.normal(size=(5, 3)))
    write_frame(tmp_path / "b.ply", rng.normal(size=(5, 3)))
    with pytest.raises(FormatError, match="mixed frame formats"):
        read_sequence(tmp_path)


def test_truncated_binary_ply_names_file(tmp_path, rng):
    write_sequence(tmp_path, _frames(rng), fmt="ply")
    p = tmp_path / "frame_0001.ply"
    p.write_bytes(p.read_bytes()[:-100])
    with pytest.raises(FormatError, match="truncated") as e:
        read_sequence(tmp_path)
    assert "frame_0001.ply" in str(e.value)


def test_not_a_ply(tmp_path):
    (tmp_path / "a.ply").write_text("hello\n")
    (tmp_path / "b.ply").write_text("hello\n")
    with pytest.raises(FormatError, match="not a PLY"):
        read_sequence(tmp_path)


def test_truncated_ascii_ply_and_pcd(tmp_path):
    (tmp_path / "a.ply").write_text(
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
        "property float z\nend_header\n1 2 3\n")
    with pytest.raises(FormatError, match="truncated"):
        read_frame(tmp_path / "a.ply")
    (tmp_path / "b.pcd").write_text("VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\n"
                                     "COUNT 1 1 1\nWIDTH 3\nHEIGHT 1\nPOINTS 3\nDATA ascii\n1 2 3\n")
    with pytest.raises(FormatError, match="truncated"):
        read_frame(tmp_path / "b.pcd")


def test_empty_frame_names_frame(tmp_path, rng):
    np.save(tmp_path / "f0.npy", rng.normal(size=(5, 3)))
    np.save(tmp_path / "f1.npy", np.zeros((0, 3)))
    with pytest.raises(EmptyFrameError) as e:
        read_sequence(tmp_path)
    assert e.value.frame == 1 and "f1.npy" in str(e.value)


def test_nan_coordinates(tmp_path, rng):
    bad = rng.normal(size=(5, 3))
    bad[3, 1] = np.nan
    np.save(tmp_path / "f0.npy", rng.normal(size=(5, 3)))
    np.save(tmp_path / "f1.npy", bad)
    with pytest.raises(InputError, match="NaN/inf") as e:
        read_sequence(tmp_path)
    assert e.value.frame == 1 and "row 3" in str(e.value)


def test_inf_in_ply(tmp_path, rng):
    pts = rng.normal(size=(5, 3))
    pts[0, 0] = np.inf
    write_frame(tmp_path / "a.ply", rng.normal(size=(5, 3)))
    write_frame(tmp_path / "b.ply", pts)
    with pytest.raises(InputError, match="NaN/inf"):
        read_sequence(tmp_path)


def test_wrong_array_shape(tmp_path, rng):
    np.save(tmp_path / "f0.npy", rng.normal(size=(5, 4)))
    np.save(tmp_path / "f1.npy", rng.normal(size=(5, 4)))
    with pytest.raises(InputError, match=r"shape \(N, 3\)"):
        read_sequence(tmp_path)
    np.savez(tmp_path / "x.npz", a=rng.normal(size=(5, 2)), b=rng.normal(size=(5, 2)))
    with pytest.raises(InputError, match="expected shape"):
        read_sequence(tmp_path / "x.npz")


def test_single_frame(tmp_path, rng):
    np.save(tmp_path / "f0.npy", rng.normal(size=(5, 3)))
    with pytest.raises(InputError, match="at least 2"):
        read_sequence(tmp_path)


def test_too_few_points(tmp_path, rng):
    write_sequence(tmp_path, [rng.normal(size=(50, 3)), rng.normal(size=(3, 3))], fmt="npy")
    with pytest.raises(EmptyFrameError, match="at least 10") as e:
        read_sequence(tmp_path, min_points=10)
    assert e.value.frame == 1


def test_garbage_npy_and_npz(tmp_path):
    (tmp_path / "a.npy").write_bytes(b"garbage")
    (tmp_path / "b.npy").write_bytes(b"garbage")
    with pytest.raises(FormatError, match="a.npy"):
        read_sequence(tmp_path)
    (tmp_path / "c.npz").write_bytes(b"garbage")
    with pytest.raises(FormatError, match="npz"):
        read_sequence(tmp_path / "c.npz")


def test_depth_png_without_intrinsics(tmp_path):
    from PIL import Image

    for t in range(2):
        Image.fromarray(np.ones((3, 3), dtype=np.uint16)).save(tmp_path / f"d{t}.png")
    with pytest.raises(InputError, match="intrinsics"):
        read_sequence(tmp_path)


def test_writes_are_atomic(tmp_path, rng, monkeypatch):
    """A failure while writing leaves neither a partial file nor a temporary file."""
    from pointrig.io import write_npz

    target = tmp_path / "out.npz"
    target.write_bytes(b"old")

    class Boom(Exception):
        pass

    def explode(*a, **k):
        raise Boom()

    monkeypatch.setattr(np, "savez_compressed", explode)
    with pytest.raises(Boom):
        write_npz(target, a=np.zeros(3))
    assert target.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["out.npz"]


def test_outputs_get_the_umask_permissions_not_owner_only(tmp_path):
    import os
    import stat

    from pointrig.io.atomic import write_json

    old = os.umask(0o022)
    try:
        write_json(tmp_path / "a.json", {"x": 1})
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "a.json").stat().st_mode) == 0o644


def test_frame_extent_is_the_robust_box_diagonal(rng):
    """numpy oracle: the diagonal of the 0.5-99.5 % quantile box; stray points do not count."""
    from pointrig.sequence import frame_extent

    pts = rng.uniform(-1.0, 1.0, size=(20000, 3)) * np.array([0.3, 0.9, 0.2])
    lo, hi = np.quantile(pts, [0.005, 0.995], axis=0)
    assert frame_extent(pts) == pytest.approx(float(np.linalg.norm(hi - lo)))
    assert frame_extent(pts) == pytest.approx(2 * np.sqrt(0.3**2 + 0.9**2 + 0.2**2), rel=0.02)
    stray = np.vstack([pts, [[1e4, 1e4, 1e4]] * 10])  # 0.05 % of the points, far away
    assert frame_extent(stray) == pytest.approx(frame_extent(pts), rel=1e-3)
    assert frame_extent(np.zeros((0, 3))) == 0.0


def test_millimetre_input_is_refused_with_the_frame_and_the_scale(tmp_path, rng):
    """A body scan in millimetres (about 2 m -> 2000 units) is an InputError naming the file,
    the frame and the factor 0.001; the same frames scaled to metres pass, and 0 turns the
    check off."""
    from pointrig.sequence import check_units

    body = rng.normal(size=(500, 3)) * np.array([0.2, 0.5, 0.1]) + np.array([0, 0, 2.5])
    frames_mm = [1000.0 * body for _ in range(3)]
    frames_mm[2] = 1000.0 * (body * 1.3)  # the widest frame is named
    write_sequence(tmp_path / "mm", frames_mm, fmt="ply")
    seq = read_sequence(tmp_path / "mm")
    with pytest.raises(InputError) as exc:
        check_units(seq, 30.0)
    assert exc.value.frame == 2 and exc.value.path.name == seq.names[2]
    assert "millimetres" in str(exc.value) and "0.001" in str(exc.value)
    check_units(read_sequence(tmp_path / "mm", scale=0.001), 30.0)
    check_units(seq, 0.0)
    # a centimetre body (200 units) could be centimetres or millimetres: both are offered
    with pytest.raises(InputError, match="centimetres.*0.01.*millimetres.*0.001"):
        check_units(read_sequence(tmp_path / "mm", scale=0.1), 30.0)


def test_extract_refuses_millimetres_before_writing(tmp_path, rng, capsys):
    """The CLI exits 1 with one line and writes nothing; the Python API raises the same."""
    from pointrig.cli import main
    from pointrig.pipeline import extract

    body = rng.normal(size=(400, 3)) * np.array([0.2, 0.5, 0.1]) + np.array([0, 0, 2.5])
    write_sequence(tmp_path / "mm", [1000.0 * body] * 3, fmt="npy")
    out = tmp_path / "out"
    assert main(["extract", str(tmp_path / "mm"), "-o", str(out)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "frame 0" in err[0] and "--scale" in err[0]
    assert not out.exists()
    with pytest.raises(InputError, match="millimetres"):
        extract(read_sequence(tmp_path / "mm"), out_dir=out)
    assert not out.exists()


def test_extract_on_a_recorder_folder_records_the_intrinsics(tmp_path):
    """A synthetic sequence written as an Open3D recorder's depth/ folder (16-bit mm PNGs,
    intrinsic.json beside the folder) runs through `pointrig extract` without options, the
    back-projected frames match the rendered points, and skeleton.json names the intrinsics."""
    from PIL import Image

    from pointrig.cli import main
    from pointrig.synth import synthesize
    from pointrig.synth.camera import Camera

    cam = Camera.kinect(320)
    syn = synthesize("human", n_frames=4, seed=1, camera=cam)
    (tmp_path / "rec" / "depth").mkdir(parents=True)
    (tmp_path / "rec" / "intrinsic.json").write_text(json.dumps({  # Open3D's layout
        "width": cam.width, "height": cam.height,
        "intrinsic_matrix": [cam.fx, 0.0, 0.0, 0.0, cam.fy, 0.0, cam.cx, cam.cy, 1.0]}))
    for t, pts in enumerate(syn.frames):
        u, v, _ = cam.project(pts)
        u, v = np.rint(u).astype(int), np.rint(v).astype(int)
        inside = (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
        assert inside.mean() > 0.98  # the few others are the sensor model's stray outliers
        depth = np.zeros((cam.height, cam.width), np.uint16)
        depth[v[inside], u[inside]] = np.rint(pts[inside, 2] * 1000).astype(np.uint16)
        Image.fromarray(depth).save(tmp_path / "rec" / "depth" / f"{t:06d}.png")
    seq = read_sequence(tmp_path / "rec" / "depth")
    for got, pts in zip(seq.frames, syn.frames):  # the same surface, to the pixel and the mm
        d, _ = cKDTree(pts).query(got)
        assert np.percentile(d, 95) < 0.02
    out = tmp_path / "out"
    assert main(["extract", str(tmp_path / "rec" / "depth"), "-o", str(out), "--stop-after",
                 "structure", "--no-pictures", "-q"]) == 0
    source = json.loads((out / "skeleton.json").read_text())["source"]
    assert source["format"] == "depth-png"
    assert source["intrinsics"]["path"] == str(tmp_path / "rec" / "intrinsic.json")
    assert source["intrinsics"]["fx"] == cam.fx and source["intrinsics"]["width"] == cam.width
