"""``pointrig extract`` end to end on a real depth recording: a right hand and forearm in front
of a RealSense SR305 (tests/data/capture/sr305_hand, 16-bit PNGs, depth unit 0.125 mm), the
person behind it removed by ``--far`` and a ``--crop`` pixel box.

The recording has no ground-truth joints. Oracles: the points the pipeline received, counted
here from the PNGs with numpy (the pixels inside the box with depth up to ``--far``); and the
shape of the result, which must be one tree whose joints lie inside the hand and arm in every
frame and span them.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from scipy.spatial import cKDTree

from pointrig.cli import main
from pointrig.io import read_sequence
from pointrig.io.depthcam import Isolation

HAND = Path(__file__).parent / "data" / "capture" / "sr305_hand" / "right_wave"
FAR, CROP = 0.72, (160, 100, 400, 480)
FRAMES = slice(1, 10, 2)  # five of the eleven frames keep the test short


@pytest.mark.slow
def test_extract_on_the_real_hand_gives_one_tree_over_the_hand(tmp_path, capsys) -> None:
    out = tmp_path / "hand"
    argv = ["extract", str(HAND), "-o", str(out), "--far", str(FAR),
            "--crop", ",".join(str(c) for c in CROP), "--start", str(FRAMES.start),
            "--stop", str(FRAMES.stop), "--stride", str(FRAMES.step), "--no-pictures", "-q"]
    assert main(argv) == 0, capsys.readouterr().err
    doc = json.loads((out / "skeleton.json").read_text())
    src = doc["source"]
    assert src["isolation"] == {"near": None, "far": FAR, "crop": list(CROP)}

    # the points read are exactly the PNG pixels inside the box and nearer than --far
    files = sorted(HAND.glob("frame_*.png"))[FRAMES]
    u0, v0, u1, v1 = CROP
    expected = []
    for f in files:
        z = np.asarray(Image.open(f)).astype(np.float64)[v0:v1, u0:u1] * 0.000125
        expected.append(int(((z > 0) & (z <= FAR)).sum()))
    assert src["points_per_frame"] == expected
    assert min(expected) > 5000  # the hand and forearm, not a sliver

    # one tree: a single root, and every joint's parent chain reaches it
    parents = [j["parent"] for j in doc["joints"]]
    assert parents.count(-1) == 1 and len(parents) >= 4
    for j in range(len(parents)):
        seen, k = set(), j
        while parents[k] != -1:
            assert k not in seen
            seen.add(k)
            k = parents[k]

    # over the hand: every joint within 4 cm of the hand's points in every frame (inside a
    # forearm or a finger), and the joints spanning most of the hand and arm
    seq = read_sequence(HAND, start=FRAMES.start, stop=FRAMES.stop, stride=FRAMES.step,
                        isolation=Isolation(far=FAR, crop=CROP))
    joints = np.asarray(doc["joint_positions"])
    assert joints.shape[:2] == (len(files), len(parents))
    for t, pts in enumerate(seq.frames):
        dist, _ = cKDTree(pts).query(joints[t])
        assert dist.max() < 0.04, (t, dist.max())
        span_pts = np.ptp(pts, axis=0)
        span_joints = np.ptp(joints[t], axis=0)
        assert span_joints.max() > 0.6 * span_pts.max()
    weights = np.load(out / "weights.npz")
    assert np.allclose(weights["weights"].sum(axis=1), 1.0)
