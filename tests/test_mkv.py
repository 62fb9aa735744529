"""The Azure Kinect / Orbbec .mkv reader on a real Azure Kinect recording (tests/data/capture).

Oracles: the Matroska file walked here byte by byte (EBML elements, the depth track's
BITMAPINFOHEADER and its block) independently of PyAV; the vendor's layout (NFOV_UNBINNED is
640 x 576 16-bit big-endian millimetres, 5 fps, 0.463945 s long with one capture, as pyk4a's
own tests of this file state); the calibration file shipped beside the recording, with the
SDK's mode-specific scaling; and the forward Brown-Conrady projection, which must put every
point back on its pixel.
"""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import av  # the capture extra (make setup installs it)
import numpy as np
import pytest

from pointrig.cli import main
from pointrig.errors import FormatError, InputError
from pointrig.io import detect_format, read_sequence
from pointrig.io.depthcam import Isolation
from pointrig.io.mkv import read_mkv

KINECT = Path(__file__).parent / "data" / "capture" / "azure_kinect"
MKV = KINECT / "recording.mkv"


def _vint(buf: bytes, pos: int, marker: bool) -> tuple[int, int]:
    n = 1
    while not buf[pos] & (0x80 >> (n - 1)):
        n += 1
    val = buf[pos] if marker else buf[pos] & (0xFF >> n)
    for b in buf[pos + 1:pos + n]:
        val = (val << 8) | b
    return val, pos + n


def _elements(buf: bytes, pos: int, end: int):
    """(id, data start, data end) of the EBML elements between pos and end."""
    while pos < end:
        eid, pos = _vint(buf, pos, True)
        size, pos = _vint(buf, pos, False)
        yield eid, pos, pos + size
        pos += size


def _walk_depth_track(path: Path) -> dict:
    """The DEPTH track's codec, BITMAPINFOHEADER fields, block times and payloads, found by
    walking the Matroska elements (no PyAV)."""
    buf = path.read_bytes()
    (_, _, hend), = [e for e in _elements(buf, 0, 40) if e[0] == 0x1A45DFA3][:1]
    seg = next(e for e in _elements(buf, hend, len(buf)) if e[0] == 0x18538067)
    scale = 1_000_000
    tracks: dict[int, dict] = {}
    blocks: list[tuple[int, int, bytes]] = []
    for eid, a, b in _elements(buf, seg[1], seg[2]):
        if eid == 0x1549A966:  # Info
            for cid, ca, cb in _elements(buf, a, b):
                if cid == 0x2AD7B1:  # TimecodeScale, ns
                    scale = int.from_bytes(buf[ca:cb], "big")
        elif eid == 0x1654AE6B:  # Tracks
            for _, ta, tb in _elements(buf, a, b):  # TrackEntry
                entry = {cid: buf[ca:cb] for cid, ca, cb in _elements(buf, ta, tb)}
                tracks[int.from_bytes(entry[0xD7], "big")] = entry
        elif eid == 0x1F43B675:  # Cluster
            ctime = 0
            for cid, ca, cb in _elements(buf, a, b):
                if cid == 0xE7:  # cluster Timecode
                    ctime = int.from_bytes(buf[ca:cb], "big")
                bodies = [(ca, cb)] if cid == 0xA3 else (
                    [(ba, bb) for bid, ba, bb in _elements(buf, ca, cb) if bid == 0xA1]
                    if cid == 0xA0 else [])
                for ba, bb in bodies:
                    track, q = _vint(buf, ba, False)
                    rel = int.from_bytes(buf[q:q + 2], "big", signed=True)
                    blocks.append((track, ctime + rel, buf[q + 3:bb]))
    (num, entry), = [(n, e) for n, e in tracks.items() if e.get(0x536E) == b"DEPTH"]
    bih = entry[0x63A2]  # CodecPrivate: BITMAPINFOHEADER
    return {
        "codec": entry[0x86].decode(),
        "width": int.from_bytes(bih[4:8], "little"),
        "height": int.from_bytes(bih[8:12], "little", signed=True),
        "bits": int.from_bytes(bih[14:16], "little"),
        "fourcc": bih[16:20],
        "times_s": [t * scale / 1e9 for n, t, _ in blocks if n == num],
        "payloads": [d for n, _, d in blocks if n == num],
    }


def _forward(points: np.ndarray, intr: dict) -> np.ndarray:
    """Pixel (u, v) of camera points through the SDK's Brown-Conrady model."""
    x, y = points[:, 0] / points[:, 2], points[:, 1] / points[:, 2]
    k1, k2, k3, k4, k5, k6 = intr["k"]
    r2 = x * x + y * y
    d = (1 + k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3) / (1 + k4 * r2 + k5 * r2 ** 2 + k6 * r2 ** 3)
    xd = x * d + (r2 + 2 * x * x) * intr["p2"] + 2 * x * y * intr["p1"]
    yd = y * d + (r2 + 2 * y * y) * intr["p1"] + 2 * x * y * intr["p2"]
    return np.stack([xd * intr["fx"] + intr["cx"], yd * intr["fy"] + intr["cy"]], axis=1)


def test_the_depth_track_matches_the_bytes_of_the_file_and_the_vendor_layout() -> None:
    walk = _walk_depth_track(MKV)
    assert walk["codec"] == "V_MS/VFW/FOURCC" and walk["fourcc"] == b"b16g"
    assert (walk["width"], walk["height"], walk["bits"]) == (640, 576, 16)  # NFOV_UNBINNED
    assert len(walk["payloads"]) == 1 and len(walk["payloads"][0]) == 640 * 576 * 2
    raw = np.frombuffer(walk["payloads"][0], dtype=">u2").reshape(576, 640)
    valid = raw[raw > 0]
    # millimetres within NFOV_UNBINNED's operating range (0.5-3.86 m) for the bulk of the
    # scene; read little-endian the same bytes would be tens of metres
    assert 500 < np.median(valid) < 3860 and valid.max() < 3860

    rec = read_mkv(MKV, keep_depth=True)
    assert rec.meta["timestamps_s"] == pytest.approx(walk["times_s"], abs=1e-9)
    assert rec.meta["resolution"] == [640, 576] and rec.meta["depth_mode"] == "NFOV_UNBINNED"
    assert rec.meta["fps"] == pytest.approx(5.0)
    assert rec.meta["duration_s"] == pytest.approx(0.463945)
    assert rec.meta["frames_in_file"] == 1
    assert "001514394512" in rec.meta["device"]
    np.testing.assert_array_equal(rec.depth[0], (raw * 0.001).astype(np.float32))

    # the intrinsics from the shipped calibration file, scaled as the SDK does for this mode
    cal = json.loads((KINECT / "calibration.json").read_text())
    cam, = [c for c in cal["CalibrationInformation"]["Cameras"]
            if c["Purpose"] == "CALIBRATION_CameraPurposeDepth"]
    prm = cam["Intrinsics"]["ModelParameters"]
    intr = rec.meta["intrinsics"]
    assert intr["source"] == "calibration.json attachment"
    assert intr["cx"] == pytest.approx(prm[0] * 1024 - 192 - 0.5)
    assert intr["cy"] == pytest.approx(prm[1] * 1024 - 180 - 0.5)
    assert intr["fx"] == pytest.approx(prm[2] * 1024) and intr["fy"] == pytest.approx(prm[3] * 1024)
    assert intr["k"] == pytest.approx(prm[4:10]) and (intr["p2"], intr["p1"]) == (prm[12], prm[13])

    # every point: z is its pixel's depth, and the lens model projects it onto that pixel
    pts = rec.frames[0]
    uv = _forward(pts, intr)
    pix = np.rint(uv).astype(int)
    assert np.abs(uv - pix).max() < 1e-4
    np.testing.assert_allclose(pts[:, 2], raw[pix[:, 1], pix[:, 0]] * 0.001, rtol=0, atol=1e-12)
    # all valid pixels but those outside the calibrated radius
    assert len(np.unique(pix[:, 1] * 640 + pix[:, 0])) == len(pts)
    assert 0.99 * len(valid) < len(pts) <= len(valid)


def test_the_recording_is_recognised_by_content_and_read_as_a_sequence(tmp_path) -> None:
    renamed = tmp_path / "capture.dat"
    shutil.copy(MKV, renamed)
    assert detect_format(renamed) == "mkv"
    seq = read_sequence(renamed, min_frames=1, isolation=Isolation(near=1.0, far=2.0))
    assert seq.fmt == "mkv" and len(seq) == 1
    z = seq.frames[0][:, 2]
    assert z.min() >= 1.0 and z.max() <= 2.0
    full = read_mkv(MKV).frames[0]
    assert len(z) == int(((full[:, 2] >= 1.0) & (full[:, 2] <= 2.0)).sum())
    assert seq.meta["isolation"] == {"near": 1.0, "far": 2.0, "crop": None}
    # a pixel box: the points of exactly those pixels
    boxed = read_mkv(MKV, isolation=Isolation(crop=(100, 50, 300, 250)), keep_depth=True)
    n_box = int((boxed.depth[0][50:250, 100:300] > 0).sum())
    assert n_box * 0.99 < len(boxed.frames[0]) <= n_box


def test_a_truncated_recording_is_a_format_error(tmp_path, capsys) -> None:
    cut = tmp_path / "cut.mkv"
    cut.write_bytes(MKV.read_bytes()[:1_000_000])
    with pytest.raises(FormatError, match="truncated Matroska recording"):
        read_mkv(cut)
    assert main(["info", str(cut)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(cut) in err[0] and "truncated" in err[0]


def test_a_recording_without_a_depth_track_is_a_format_error(tmp_path, capsys) -> None:
    out = tmp_path / "colour_only.mkv"
    with av.open(str(MKV)) as src, av.open(str(out), "w", format="matroska") as dst:
        colour, = [s for s in src.streams.video if s.metadata.get("title") == "COLOR"]
        copy = dst.add_stream_from_template(colour)
        copy.metadata["title"] = "COLOR"
        for pkt in src.demux(colour):
            if pkt.dts is not None:
                pkt.stream = copy
                dst.mux(pkt)
    with pytest.raises(FormatError, match="no depth track.*tracks: COLOR"):
        read_mkv(out)
    assert main(["extract", str(out), "-o", str(tmp_path / "o")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no depth track" in err[0]
    assert not (tmp_path / "o" / "skeleton.json").exists()


def test_given_intrinsics_replace_the_calibration_and_a_crop_must_fit(tmp_path) -> None:
    k = {"fx": 500.0, "fy": 500.0, "cx": 320.0, "cy": 288.0}
    rec = read_mkv(MKV, intrinsics=k, keep_depth=True)
    assert rec.meta["intrinsics"]["source"] == "given"
    pts, depth = rec.frames[0], rec.depth[0]
    u = np.rint(pts[:, 0] / pts[:, 2] * 500 + 320).astype(int)
    v = np.rint(pts[:, 1] / pts[:, 2] * 500 + 288).astype(int)
    np.testing.assert_allclose(pts[:, 2], depth[v, u], rtol=1e-6)
    with pytest.raises(InputError, match="goes past the 640 x 576"):
        read_mkv(MKV, isolation=Isolation(crop=(0, 0, 700, 100)))


def test_without_the_capture_extra_the_error_says_how_to_install_it(monkeypatch, capsys) -> None:
    monkeypatch.setitem(sys.modules, "av", None)  # as if PyAV were not installed
    assert main(["info", str(MKV)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "needs the Python package 'av'" in err[0]
    assert "pip install 'pointrig[capture]'" in err[0]
