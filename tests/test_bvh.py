"""Tests of pointrig.synth.bvh: parsing, forward kinematics, the capsule body and synthesis."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pointrig.errors import FormatError, InputError
from pointrig.synth import Camera, NoiseConfig, synthesize
from pointrig.synth.bvh import capsule_body, load_bvh, parse_bvh

HIERARCHY = """HIERARCHY
ROOT hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT upper
  {
    OFFSET 0 1 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 0.5 0
    }
  }
  JOINT side
  {
    OFFSET 0.5 0 0
    CHANNELS 3 Xrotation Yrotation Zrotation
    JOINT tip
    {
      OFFSET 1 0 0
      CHANNELS 3 Zrotation Yrotation Xrotation
      End Site
      {
        OFFSET 0.3 0 0
      }
    }
  }
}
"""
#: frame 0: rest; frame 1: root at (1, 2, 3) turned 90 deg about z, the side joint another 90
#: about z; frame 2: arbitrary angles on every channel (checked against scipy)
FRAME2 = [0.2, -0.1, 0.4, 30, -20, 50, 10, 70, -35, 25, -60, 15, -45, 80, 5]
MOTION = ("MOTION\nFrames: 3\nFrame Time: 0.05\n" + " ".join(["0"] * 15) + "\n"
          + "1 2 3 90 0 0  0 90 0  0 0 90  0 0 0\n" + " ".join(map(str, FRAME2)) + "\n")


def test_parse_hierarchy_and_motion():
    b = parse_bvh(HIERARCHY + MOTION)
    assert b.names == ["hips", "upper", "side", "tip"]
    assert b.parents.tolist() == [-1, 0, 0, 2]
    assert [len(c) for c in b.channels] == [6, 3, 3, 3]
    assert b.motion.shape == (3, 15) and b.n_frames == 3 and b.fps == pytest.approx(20.0)
    rest, ends = b.rest_positions()
    np.testing.assert_allclose(rest, [[0, 0, 0], [0, 1, 0], [0.5, 0, 0], [1.5, 0, 0]])
    np.testing.assert_allclose(ends, [[0, 1.5, 0], [1.8, 0, 0]])


def test_forward_kinematics_closed_form():
    b = parse_bvh(HIERARCHY + MOTION)
    R, P = b.forward()
    rest, _ = b.rest_positions()
    np.testing.assert_allclose(P[0], rest, atol=1e-12)
    np.testing.assert_allclose(R[0], np.broadcast_to(np.eye(3), (4, 3, 3)), atol=1e-12)
    # frame 1: Rz(90) takes x to y and y to -x
    np.testing.assert_allclose(P[1], [[1, 2, 3], [0, 2, 3], [1, 2.5, 3], [0, 2.5, 3]],
                               atol=1e-12)
    np.testing.assert_allclose(R[1, 2], [[-1, 0, 0], [0, -1, 0], [0, 0, 1]], atol=1e-12)
    # frame 2: each joint's channels compose in file order (intrinsic rotations)
    f = FRAME2

    def rot(order: str, angles) -> np.ndarray:
        return Rotation.from_euler(order, angles, degrees=True).as_matrix()

    R0 = rot("ZXY", f[3:6])
    R1 = R0 @ rot("ZXY", f[6:9])
    R2 = R0 @ rot("XYZ", f[9:12])
    R3 = R2 @ rot("ZYX", f[12:15])
    p0 = np.array(f[:3])
    p1 = p0 + R0 @ [0, 1, 0]
    p2 = p0 + R0 @ [0.5, 0, 0]
    p3 = p2 + R2 @ [1, 0, 0]
    np.testing.assert_allclose(P[2], [p0, p1, p2, p3], atol=1e-12)
    np.testing.assert_allclose(R[2], [R0, R1, R2, R3], atol=1e-12)


@pytest.mark.parametrize("text, what", [
    ("ROOT x", "HIERARCHY"),
    (HIERARCHY.replace("Zrotation Xrotation Yrotation\n    End", "Zrotation Xrotation Wrot\n"
                       "    End"), "unknown channel"),
    (HIERARCHY, "end of BVH"),
    (HIERARCHY + MOTION.replace("Frames: 3", "Frames: 4"), "expected 4 frames"),
    (HIERARCHY + MOTION.replace("0.05", "0"), "positive frame time"),
    (HIERARCHY + MOTION.replace("1 2 3", "1 a 3"), "non-numeric"),
])
def test_malformed_bvh_is_a_format_error(text, what):
    with pytest.raises(FormatError, match=what):
        parse_bvh(text)


def test_missing_file(tmp_path):
    with pytest.raises(InputError, match="not found"):
        load_bvh(tmp_path / "none.bvh")


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    s = np.clip((p - a) @ ab / (ab @ ab), 0, 1)
    return np.linalg.norm(p - a - s[:, None] * ab, axis=1)


def test_capsule_body_geometry_and_weights():
    b = parse_bvh(HIERARCHY + MOTION)
    body = capsule_body(b)
    np.testing.assert_allclose(body.weights.sum(axis=1), 1.0, atol=1e-12)
    # every capsule's vertices lie on its surface: at its radius from its segment
    for k, (seg, r) in enumerate(zip(body.segments, body.radii)):
        v = body.vertices[body.vertex_segment == k]
        np.testing.assert_allclose(_segment_distance(v, seg[0], seg[1]), r, atol=1e-9)
    # every joint owns a capsule; limb capsules are thinner than the trunk's
    assert sorted(set(body.owner.tolist())) == [0, 1, 2, 3]
    trunk_r = body.radii[body.owner == 0].max()
    assert body.radii[body.owner == 3].max() < trunk_r


def test_synthesize_bvh_resamples_and_places_joints(tmp_path):
    # 12 frames at 120 Hz, the root moving 1 cm a frame along x: at 30 fps frame k is motion
    # frame 4k, so the root is at x = 0, 4, 8 cm
    rows = [" ".join([f"{0.01 * i:.2f}"] + ["0"] * 14) for i in range(12)]
    path = tmp_path / "clip.bvh"
    path.write_text(HIERARCHY + "MOTION\nFrames: 12\nFrame Time: 0.0083333333\n"
                    + "\n".join(rows) + "\n")
    seq = synthesize(path, n_frames=3, fps=30.0, camera=Camera.kinect(320),
                     noise=NoiseConfig.clean())
    cam = seq.camera
    world = (seq.gt_joints - np.asarray(cam.translation)) @ np.asarray(cam.rotation)
    np.testing.assert_allclose(world[:, 0, 0], [0.0, 0.04, 0.08], atol=1e-9)
    assert seq.joint_names == ["hips", "upper", "side", "tip"]
    assert seq.skinned.all() and len(seq.frames[0]) > 100
    # the bone transforms carry the rest samples to the posed samples (rigid parts)
    lab = seq.surface_labels
    moved = np.einsum("fsij,sj->fsi", seq.bone_rotations[:, lab], seq.rest_surface) \
        + seq.bone_translations[:, lab]
    pure = seq.surface_weights.max(axis=1) > 1 - 1e-12
    np.testing.assert_allclose(moved[:, pure], seq.surface[:, pure], atol=1e-9)


def test_synthesize_malformed_bvh(tmp_path):
    path = tmp_path / "bad.bvh"
    path.write_text(HIERARCHY + MOTION.replace("Frames: 3", "Frames: 2"))
    with pytest.raises(FormatError):
        synthesize(path, n_frames=2)

