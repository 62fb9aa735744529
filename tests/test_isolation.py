"""Subject isolation (``--near/--far``, ``--crop``), ``pointrig preview`` of what it keeps and
``pointrig info`` on recordings.

Oracles: the depth values of the PNGs and of the recording read here with numpy and Pillow
(which pixels a depth range and a box keep), and the recording's known description.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from pointrig.cli import main
from pointrig.errors import ConfigError
from pointrig.io import read_sequence, write_sequence
from pointrig.io.depthcam import Isolation

DATA = Path(__file__).parent / "data" / "capture"
HAND = DATA / "sr305_hand" / "right_wave"
MKV = DATA / "azure_kinect" / "recording.mkv"
PAD = 28  # the preview's margin, pixels


def _hand_depth(i: int) -> np.ndarray:
    """Frame i of the hand recording in metres, read with Pillow."""
    return np.asarray(Image.open(sorted(HAND.glob("*.png"))[i])).astype(np.float64) * 0.000125


def _coloured(png: Path, shape: tuple[int, int]) -> np.ndarray:
    """(H, W) bool: image pixels drawn in colour (kept), not grey (cut) or black."""
    img = np.asarray(Image.open(png).convert("RGB")).astype(int)
    img = img[PAD:PAD + shape[0], PAD:PAD + shape[1]]
    return (img.max(axis=2) - img.min(axis=2)) > 0


def test_preview_colours_exactly_the_pixels_the_depth_range_keeps(tmp_path, capsys) -> None:
    png = tmp_path / "p.png"
    assert main(["preview", str(HAND), "--frame", "3", "--near", "0.5", "--far", "0.65",
                 "-o", str(png)]) == 0
    assert str(png) in capsys.readouterr().out
    z = _hand_depth(3)
    want = (z >= 0.5) & (z <= 0.65)
    got = _coloured(png, z.shape)
    np.testing.assert_array_equal(got, want)


def test_preview_of_a_recording_draws_the_crop_box(tmp_path) -> None:
    png = tmp_path / "k.png"
    assert main(["preview", str(MKV), "--crop", "100,50,300,250", "-o", str(png)]) == 0
    img = np.asarray(Image.open(png).convert("RGB")).astype(int)
    assert img.shape[:2] == (576 + 2 * PAD, 640 + 2 * PAD)
    # the box outline is white; inside it the valid pixels are coloured, outside none are
    assert (img[PAD + 50, PAD + 100:PAD + 300] == 255).all()
    assert (img[PAD + 50:PAD + 250, PAD + 299] == 255).all()
    col = _coloured(png, (576, 640))
    assert not col[:50].any() and not col[250:].any() and not col[:, :100].any()
    assert col[60:240, 110:290].mean() > 0.5
    assert main(["preview", str(MKV), "--frame", "1", "-o", str(tmp_path / "x.png")]) == 1


def test_near_far_apply_to_point_inputs_and_crop_needs_depth_images(tmp_path, rng) -> None:
    frames = [rng.uniform([-1, -1, 0.2], [1, 1, 3.0], size=(500, 3)) for _ in range(2)]
    folder = tmp_path / "ply"
    write_sequence(folder, frames, fmt="ply")
    seq = read_sequence(folder, isolation=Isolation(near=1.0, far=2.0))
    for got, pts in zip(seq.frames, frames):
        want = pts[(pts[:, 2] >= 1.0) & (pts[:, 2] <= 2.0)]
        np.testing.assert_allclose(np.sort(got, axis=0), np.sort(want, axis=0), atol=1e-6)
    with pytest.raises(ConfigError, match="pixel box of depth images"):
        read_sequence(folder, isolation=Isolation(crop=(0, 0, 10, 10)))
    with pytest.raises(ConfigError, match="--topic is for ROS bags"):
        read_sequence(folder, topic="/camera/points")


@pytest.mark.parametrize("args, message", [
    (["--near", "2", "--far", "1"], "--near 2 must be less than --far 1"),
    (["--far", "-1"], "--far must be a distance"),
    (["--crop", "10,10,5,20"], "--crop U0,V0,U1,V1 needs"),
    (["--topic", "/camera/depth"], "--topic is for ROS bags"),
])
def test_bad_isolation_options_are_one_line_errors(args, message, capsys) -> None:
    assert main(["info", str(MKV), *args]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]


def test_info_describes_the_recordings(capsys) -> None:
    assert main(["info", str(MKV)]) == 0
    out = capsys.readouterr().out
    assert "device   Azure Kinect (serial 001514394512)" in out
    assert "depth    640 x 576 px, 5 fps, mode NFOV_UNBINNED" in out
    assert "file     1 frame, 0.464 s" in out
    assert "(calibration.json attachment)" in out and "frames   1\n" in out
    assert main(["info", str(HAND), "--far", "0.7"]) == 0
    out = capsys.readouterr().out
    assert "kept     far 0.7 m" in out and "frames   11" in out
    assert "depth    640 x 480 px\n" in out


def test_readers_keep_the_data_of_exactly_the_frames_a_slice_can_select() -> None:
    from pointrig.io.depthcam import may_select, select_frames

    for n in (0, 1, 7, 12):
        for start in (0, 1, 3, -4):
            for stop in (None, 5, 20, -2):
                for stride in (1, 2, 3):
                    chosen = select_frames(n, start, stop, stride)
                    kept = [i for i in range(n) if may_select(i, start, stop, stride)]
                    assert set(chosen) <= set(kept)
                    if start >= 0 and (stop is None or stop >= 0):
                        assert kept == chosen
