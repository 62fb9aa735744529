"""benchmarks/bench_capture.py: its conditions and the claim that a frame rate changes only the
sampling of the same motion."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import bench_capture  # noqa: E402

from pointrig.synth import synthesize  # noqa: E402
from pointrig.synth.camera import Camera  # noqa: E402
from pointrig.synth.noise import NoiseConfig  # noqa: E402


def test_conditions_parse_and_refuse() -> None:
    assert bench_capture.parse_conditions("640@30,1280@15,") == [(640, 30.0), (1280, 15.0)]
    for bad in ("640", "640@", "x@30", "640@30@2", "8@30", "640@0", "640@inf", ""):
        with pytest.raises(ValueError):
            bench_capture.parse_conditions(bad)
    assert [bench_capture.frames_at(f, 100) for f in (15, 30, 60)] == [50, 100, 200]


@pytest.mark.parametrize("variant, message", [
    ("[1]", "not a JSON object"),
    ("{bad", "--variant: Expecting"),
    ('{"x": {}}', "unknown section [x]"),
    ('{"registration": {"sigma2_start": "bogus"}}', "sigma2_start must be one of"),
])
def test_a_bad_variant_is_refused_before_any_work(variant: str, message: str,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        bench_capture.main(["--variant", variant])
    assert exc.value.code == 2
    assert message in capsys.readouterr().err


@pytest.mark.parametrize("source", ["human", "girl"])
def test_another_frame_rate_samples_the_same_motion(source: str) -> None:
    """At 15 fps frame k shows the pose of frame 2k at 30 fps, for a procedural figure and a glTF
    clip: the benchmark compares captures of one motion. Poses are compared by the distances
    between every two ground-truth joints (the auto-placed camera frames the sampled poses, so
    it may sit a few millimetres elsewhere)."""
    if source == "girl":  # the test copy of the shared model (tests/data/LICENSES.md)
        source = str(Path(__file__).resolve().parent / "data" / "girl.glb")
        kw = {"clip": "RunTrack"}
    else:
        kw = {}
    a = synthesize(source, n_frames=bench_capture.frames_at(30, 8), seed=3, fps=30,
                   camera=Camera.kinect(320), noise=NoiseConfig.clean(), **kw)
    b = synthesize(source, n_frames=bench_capture.frames_at(15, 8), seed=3, fps=15,
                   camera=Camera.kinect(320), noise=NoiseConfig.clean(), **kw)
    assert len(b.gt_joints) == 4

    def dists(j: np.ndarray) -> np.ndarray:
        return np.linalg.norm(j[:, :, None] - j[:, None], axis=3)

    np.testing.assert_allclose(dists(b.gt_joints), dists(a.gt_joints[::2]), atol=1e-9)
    assert not np.allclose(dists(b.gt_joints), dists(a.gt_joints[1::2]), atol=1e-3)
