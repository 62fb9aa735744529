"""Background removal before step 1: static floor / wall planes go, subjects stay untouched."""

from __future__ import annotations

import numpy as np
import pytest

from pointrig.background import find_background_planes, remove_background
from pointrig.cli import main
from pointrig.geometry import connected_pieces_exact
from pointrig.io import write_sequence
from pointrig.sequence import PointSequence
from pointrig.synth import Camera, NoiseConfig, synthesize


def _scene(figure: str, floor: bool, wall: bool, frames: int = 6, **kw):
    noise = NoiseConfig(seed=1, floor=floor, background=wall, outliers=0.0)
    return synthesize(figure, n_frames=frames, seed=3, camera=Camera.kinect(320), noise=noise, **kw)


def _kept(frame: np.ndarray, new: np.ndarray) -> np.ndarray:
    """Mask of the rows of ``frame`` that survive in ``new`` (points are copied, not moved)."""
    rows = {r.tobytes() for r in np.ascontiguousarray(new)}
    return np.array([r.tobytes() in rows for r in np.ascontiguousarray(frame)])


@pytest.mark.parametrize("walk", [0.0, 2.5])
def test_floor_and_wall_are_removed_and_the_subject_kept(walk):
    syn = _scene("human", True, True, walk=walk)
    new, report = remove_background(PointSequence(syn.frames))
    normals = np.abs(np.array([p.normal for p in report.planes]))
    assert len(report.planes) == 2
    # the renderer's floor is y = const, its wall z = const (camera frame): up to 2 degrees
    assert sorted(np.argmax(normals, axis=1).tolist()) == [1, 2]
    assert normals.max(axis=1).min() > np.cos(np.radians(2.0))
    for x, lab, y in zip(syn.frames, syn.point_labels, new.frames):
        kept = _kept(x, y)
        assert kept[lab < 0].mean() < 0.005  # background (floor, wall) points left
        assert kept[lab >= 0].mean() > 0.93  # subject points kept (soles within the band go)


@pytest.mark.parametrize("figure", ["human", "arm", "snake", "hand"])
def test_sequences_without_background_are_returned_unchanged(figure):
    syn = _scene(figure, False, False)
    seq = PointSequence(syn.frames)
    new, report = remove_background(seq)
    assert report.planes == [] and new is seq
    assert report.removed_fraction.shape == (len(syn.frames),) and not report.removed_fraction.any()


def _plane_scene(rng, side: float):
    """A static 6 x 4 m plane z = 3 + 0.1 x (noise 5 mm) and a moving blob at z = 3 - side m."""
    frames = []
    for t in range(5):
        uv = rng.uniform([-3, -2], [3, 2], size=(20000, 2))
        wall = np.c_[uv[:, 0], uv[:, 1], 3.0 + 0.1 * uv[:, 0] + rng.normal(0, 0.005, len(uv))]
        blob = rng.normal(0, 0.15, size=(3000, 3)) + [0.1 * t, 0.0, 3.0 - side]
        frames.append(np.r_[wall, blob])
    return frames


def test_plane_equation_against_the_generating_plane(rng):
    planes, _ = find_background_planes(_plane_scene(rng, 0.8))
    assert len(planes) == 1
    n, d = planes[0].normal, planes[0].offset
    truth = np.array([-0.1, 0.0, 1.0]) / np.linalg.norm([-0.1, 0.0, 1.0])
    s = np.sign(n @ truth)
    assert np.degrees(np.arccos(min(1.0, s * n @ truth))) < 0.5
    assert abs(s * d - (-3.0 / np.linalg.norm([-0.1, 0.0, 1.0]))) < 0.005  # metres
    assert planes[0].band >= 0.005 * 1.9 and planes[0].static > 0.9


def test_a_plane_with_the_scene_behind_it_is_kept(rng):
    """The same static plane with the moving blob behind it (seen through, as a flat part of
    a subject would have its other parts behind it) is not background."""
    planes, found = find_background_planes(_plane_scene(rng, -0.8))
    assert found >= 1 and planes == []


def test_same_seed_same_planes():
    syn = _scene("human", True, False, frames=4)
    a, _ = remove_background(PointSequence(syn.frames), seed=5)
    b, _ = remove_background(PointSequence(syn.frames), seed=5)
    for x, y in zip(a.frames, b.frames):
        np.testing.assert_array_equal(x, y)


def test_cli_removes_a_floor_and_rejects_a_bad_option(tmp_path, capsys):
    syn = _scene("human", True, False, frames=4)
    write_sequence(tmp_path / "seq", syn.frames, fmt="npy")
    code = main(["extract", str(tmp_path / "seq"), "-o", str(tmp_path / "out"),
                 "--stop-after", "registration"])
    assert code == 0
    assert "[background] removed 1 static background plane" in capsys.readouterr().err
    from pointrig.registration import RegistrationResult

    rest = RegistrationResult.load(tmp_path / "out" / "registration.npz").rest_points
    floor_y = max(x[lab < 0, 1].max() for x, lab in zip(syn.frames, syn.point_labels))
    # no rest point on the floor (the floor is y = floor_y in the camera frame, y down)
    assert (rest[:, 1] < floor_y - 0.02).all()
    (tmp_path / "bad.toml").write_text('[preprocess]\nbackground = "maybe"\n')
    code = main(["extract", str(tmp_path / "seq"), "-o", str(tmp_path / "out2"),
                 "--config", str(tmp_path / "bad.toml")])
    err = capsys.readouterr().err
    assert code != 0 and "background" in err and not (tmp_path / "out2" / "skeleton.json").exists()


def _same_partition(a: np.ndarray, b: np.ndarray) -> bool:
    """Two labelings describe the same partition (labels may be permuted)."""
    pairs = np.unique(np.stack([a, b], 1), axis=0)
    return len(pairs) == len(np.unique(a)) == len(np.unique(b))


def test_connected_pieces_match_the_exact_point_graph():
    """The cell-representative graph gives the exact graph's pieces: sheets sampled like a depth
    frame (5 mm spacing), a gap of 0.85 radius that connects, gaps of 1.15 and 3 radii that do
    not, and isolated speckle, rotated off the grid axes. (Cells of a whole radius, four times
    the default, join the 1.15-radius gap or split the 0.85-radius one.)"""
    from pointrig.geometry import _connected_pieces

    rng = np.random.default_rng(4)
    r = 0.05
    g = np.arange(0.0, 0.4, 0.005)
    sheet = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    parts = []
    x0 = np.cumsum([0.0, 0.395 + 0.85 * r, 0.395 + 1.15 * r, 0.395 + 3.0 * r])
    for dx in x0:
        xy = sheet + [dx, 0.0] + rng.normal(0, 0.001, sheet.shape)
        parts.append(np.column_stack([xy, rng.normal(0, 0.002, len(xy))]))
    speckle = rng.uniform([0, 0.6, -0.5], [2, 1.5, 0.5], (40, 3))
    pts = np.concatenate(parts + [speckle])
    from scipy.spatial.transform import Rotation
    pts = pts @ Rotation.from_euler("xyz", [20, 35, 50], degrees=True).as_matrix().T
    got = _connected_pieces(pts, r)
    want = connected_pieces_exact(pts, r)
    assert _same_partition(got, want)
    # the first two sheets are one piece, the other two are apart
    first = [got[i * len(sheet)] for i in range(4)]
    assert first[0] == first[1] and len(set(first)) == 3


def test_connected_pieces_degenerate_radius_and_huge_extent():
    """Radius 0 (a frame of duplicated points has a median spacing of 0): only coincident
    points are one piece. A radius tiny against the extent (more cells than an int64 key can
    number) still gives the exact graph's pieces."""
    from pointrig.geometry import _connected_pieces

    pts = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.001, 0.0, 1.0], [5.0, 5.0, 5.0]])
    lab = _connected_pieces(pts, 0.0)
    assert lab[0] == lab[1] and len({lab[0], lab[2], lab[3]}) == 3
    far = np.array([[0.0, 0.0, 0.0], [1e-7, 0.0, 0.0], [3e-7, 0.0, 0.0], [25.0, 25.0, 25.0]])
    assert _same_partition(_connected_pieces(far, 1.5e-7), connected_pieces_exact(far, 1.5e-7))
