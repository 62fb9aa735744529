"""Frames kept on disk and read on demand: the same results as frames in memory, and a peak
memory that does not grow with the frames as read.

The synthetic capture is :mod:`benchmarks.bench_memory`'s: 640x480 depth PNGs of a wall 3 m
away (307,200 points a frame as read) with a two-link arm in front of it, which ``--far 2.5``
keeps.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
from benchmarks.bench_memory import FAR_M, HEIGHT, INTRINSICS, WIDTH, write_depth_sequence
from PIL import Image

from pointrig.background import remove_background
from pointrig.config import PipelineConfig
from pointrig.errors import InputError, OutputError
from pointrig.io import read_sequence
from pointrig.io.depthcam import Isolation
from pointrig.pipeline import extract
from pointrig.preprocess import remove_sparse_frames
from pointrig.sequence import PointSequence, SpilledFrames

#: bytes of one frame as read: every pixel of the 640x480 image a float64 3-vector
FULL_FRAME_BYTES = WIDTH * HEIGHT * 3 * 8


def _frames(seed: int, n: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [rng.normal(size=(int(k), 3)) * 10.0 ** rng.integers(-3, 3)
            for k in rng.integers(1, 500, size=n)]


def test_spilled_frames_give_back_every_frame_bit_for_bit(tmp_path):
    frames = _frames(1, 40)
    store = SpilledFrames(tmp_path / "spill")
    for f in frames:
        store.append(f)
    assert len(store) == 40
    assert list(store.counts) == [len(f) for f in frames]
    assert store.nbytes == sum(f.nbytes for f in frames)
    for got, want in zip(store, frames):
        assert got.dtype == np.float64 and got.flags.c_contiguous and got.flags.writeable
        assert got.tobytes() == want.tobytes()
    # slices and selections are views of the same file, in the order asked
    view = store[5:30:3]
    assert [g.tobytes() for g in view] == [f.tobytes() for f in frames[5:30:3]]
    sel = view.select([2, 0])
    assert [g.tobytes() for g in sel] == [frames[11].tobytes(), frames[5].tobytes()]
    assert store[-1].tobytes() == frames[-1].tobytes()
    with pytest.raises(IndexError):
        store[40]
    with pytest.raises(TypeError):
        view.append(frames[0])
    # read from several threads at once
    errors: list[int] = []

    def read_all(k: int) -> None:
        for t in range(k, 40, 4):
            if store[t].tobytes() != frames[t].tobytes():
                errors.append(t)

    threads = [threading.Thread(target=read_all, args=(k,)) for k in range(4)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    assert errors == []
    # the file leaves no trace in its folder, even while open
    assert list((tmp_path / "spill").iterdir()) == []


def test_spilled_sequence_behaves_as_the_one_in_memory(tmp_path):
    frames = _frames(2, 12)
    mem = PointSequence(frames, "x", fmt="npy")
    store = SpilledFrames(tmp_path)
    for f in frames:
        store.append(f)
    disk = PointSequence(store, "x", fmt="npy")
    assert isinstance(disk.frames, SpilledFrames)
    assert disk.summary() == mem.summary()
    sub_d, sub_m = disk.subset(1, 10, 2), mem.subset(1, 10, 2)
    assert isinstance(sub_d.frames, SpilledFrames)
    assert sub_d.names == sub_m.names
    assert [f.tobytes() for f in sub_d.frames] == [f.tobytes() for f in sub_m.frames]
    # the per-frame clean-up keeps its output on disk too, with the same points
    clean_d, removed_d = remove_sparse_frames(disk, min_points=1)
    clean_m, removed_m = remove_sparse_frames(mem, min_points=1)
    assert isinstance(clean_d.frames, SpilledFrames)
    np.testing.assert_array_equal(removed_d, removed_m)
    assert [f.tobytes() for f in clean_d.frames] == [f.tobytes() for f in clean_m.frames]


def test_a_spill_folder_that_cannot_be_made_is_an_output_error(tmp_path):
    (tmp_path / "file").write_text("")
    with pytest.raises(OutputError, match="cannot keep the frames on disk"):
        SpilledFrames(tmp_path / "file" / "spill")


def _eager_frames(folder: Path, far: float) -> list[np.ndarray]:
    """The capture's frames built in memory without pointrig's reader: each PNG back-projected
    through the pinhole intrinsics (``x = (u - cx) z / fx``, depth 0 invalid) and the points
    beyond ``far`` metres dropped."""
    k = INTRINSICS
    out = []
    for png in sorted(folder.glob("frame_*.png")):
        depth = np.asarray(Image.open(png))
        v, u = np.nonzero(depth > 0)
        z = depth[v, u].astype(np.float64) * k["depth_scale"]
        pts = np.stack([(u - k["cx"]) * z / k["fx"], (v - k["cy"]) * z / k["fy"], z], axis=1)
        out.append(pts[pts[:, 2] <= far])
    return out


def test_read_sequence_keeps_the_reduced_frames_on_disk(tmp_path):
    """Each depth PNG reduced as read (``far`` isolation, a crop box) and spilled: the frames
    equal numpy's back-projection of every PNG, reduced the same way, bit for bit."""
    folder = write_depth_sequence(tmp_path / "depth", 4)
    lo = np.array([-0.5, -1.0, 0.0])
    want = [f[(f >= lo).all(axis=1)] for f in _eager_frames(folder, FAR_M)]
    seq = read_sequence(folder, isolation=Isolation(far=FAR_M), crop_min=lo,
                        spill=tmp_path / "spill")
    assert isinstance(seq.frames, SpilledFrames)
    assert list(seq.counts) == [len(f) for f in want]
    assert [f.tobytes() for f in seq.frames] == [f.tobytes() for f in want]
    assert seq.names == [f"frame_{t:05d}.png" for t in range(4)]
    assert seq.meta["isolation"] == Isolation(far=FAR_M).to_dict()
    # a bad frame in the middle is still named, with its index
    (folder / "frame_00002.png").write_bytes(b"not a png")
    with pytest.raises(InputError) as exc:
        read_sequence(folder, isolation=Isolation(far=FAR_M), spill=tmp_path / "spill")
    assert exc.value.frame == 2 and exc.value.path == folder / "frame_00002.png"


def test_streamed_extract_equals_extract_on_frames_in_memory(tmp_path):
    """``pointrig extract`` (frames reduced as read and kept on disk) against
    :func:`pointrig.pipeline.extract` on every frame built in memory by numpy: the same
    skeleton.json (but for the timings and the input's description), weights.npz and
    registration bit for bit."""
    folder = write_depth_sequence(tmp_path / "depth", 8)
    env = dict(os.environ, RAYON_NUM_THREADS="1")
    subprocess.run([sys.executable, "-m", "pointrig", "extract", str(folder), "-o",
                    str(tmp_path / "streamed"), "-q", "--no-pictures", "--far", str(FAR_M)],
                   check=True, env=env, capture_output=True)
    cfg = PipelineConfig()
    seq = PointSequence(_eager_frames(folder, FAR_M), str(folder), fmt="depth-png")
    seq, _ = remove_background(seq, seed=cfg.registration.seed,
                               threshold=cfg.preprocess.background_threshold)
    extract(seq, cfg, tmp_path / "eager", pictures=False)
    a, b = (json.loads((tmp_path / d / "skeleton.json").read_text())
            for d in ("streamed", "eager"))
    for doc in (a, b):
        doc["params"].pop("timings_s")
    src_a, src_b = a.pop("source"), b.pop("source")
    assert a == b
    for key in ("frames", "points_per_frame", "points_used_per_frame", "rest_frame"):
        assert src_a[key] == src_b[key]
    for name in ("weights.npz", "registration.npz"):
        with np.load(tmp_path / "streamed" / name) as za, \
                np.load(tmp_path / "eager" / name) as zb:
            assert sorted(za.files) == sorted(zb.files)
            for k in za.files:  # the checkpoint's cache_key hashes every frame used
                np.testing.assert_array_equal(za[k], zb[k], err_msg=f"{name}:{k}")
    assert not (tmp_path / "streamed" / ".pointrig-partial").exists()


_CHEAP_STEP1 = """\
[preprocess]
voxel_size = 0.04
[registration]
rest_frame = 0
n_rest_points = 150
n_nodes = 20
max_iterations = 2
refine_rounds = 0
"""


def _peak_rss_bytes(cmd: list[str], env: dict[str, str]) -> int:
    """Peak resident set of the process running ``cmd`` (``ru_maxrss``, KiB on Linux)."""
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    assert os.waitstatus_to_exitcode(status) == 0, proc.stderr.read().decode()
    return usage.ru_maxrss * 1024


@pytest.mark.skipif(not hasattr(os, "wait4"), reason="needs os.wait4 (POSIX)")
def test_peak_memory_does_not_grow_with_the_frames_as_read(tmp_path):
    """Step 1 of ``pointrig extract`` on 10 and on 40 frames of a 640x480 depth capture: 30
    more frames would add 221 MB held as read; the peak resident set grows by less than a
    quarter of that (the reduced frames and the registration of 30 frames are a few MB)."""
    small, large = 10, 40
    write_depth_sequence(tmp_path / "large", large)
    (tmp_path / "small").mkdir()
    for name in ["intrinsics.json"] + [f"frame_{t:05d}.png" for t in range(small)]:
        os.link(tmp_path / "large" / name, tmp_path / "small" / name)
    (tmp_path / "cheap.toml").write_text(_CHEAP_STEP1)
    env = dict(os.environ, RAYON_NUM_THREADS="1")
    peak = {}
    for n, name in ((small, "small"), (large, "large")):
        peak[n] = _peak_rss_bytes(
            [sys.executable, "-m", "pointrig", "extract", str(tmp_path / name), "-o",
             str(tmp_path / f"out_{name}"), "-q", "--no-pictures", "--far", str(FAR_M),
             "--config", str(tmp_path / "cheap.toml"), "--stop-after", "registration"], env)
    as_read = (large - small) * FULL_FRAME_BYTES
    assert peak[large] - peak[small] < as_read / 4, (peak, as_read)
