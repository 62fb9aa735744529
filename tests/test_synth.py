"""Tests of pointrig.synth: rasteriser, camera, noise model, figures, glTF, sequences."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp
from synth_helpers import expected_two_bone, write_split_two_bone_glb, write_two_bone_glb

from pointrig.errors import ConfigError, InputError
from pointrig.io import read_sequence
from pointrig.synth import FIGURES, Camera, NoiseConfig, load_gt, make_figure, synthesize
from pointrig.synth.gltf import load_gltf, pose_gltf, quat_to_matrix, slerp
from pointrig.synth.noise import apply_depth_noise, axial_sigma, outliers_in_box
from pointrig.synth.render import depth_to_points, rasterize, rasterize_naive
from pointrig.synth.scene import Posed, posed_size

DATA = Path(__file__).parent / "data"


def _plane_quad(n: np.ndarray, d: float, half: float = 3.0) -> np.ndarray:
    """Corners of a big square on the plane n.x = d, around its foot point."""
    n = n / np.linalg.norm(n)
    c = n * d
    a = np.cross(n, [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(n, a)
    return np.array([c - half * a - half * b, c + half * a - half * b, c + half * a + half * b,
                     c - half * a + half * b])


def _analytic_plane_depth(cam: Camera, n: np.ndarray, d: float) -> np.ndarray:
    v, u = np.mgrid[0:cam.height, 0:cam.width].astype(np.float64)
    n = n / np.linalg.norm(n)
    ray = np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, np.ones_like(u)], axis=-1)
    return d / (ray @ n)


@pytest.mark.parametrize("width", [640, 320])
def test_rasteriser_exact_on_tilted_plane(width):
    cam = Camera.kinect(width)
    n = np.array([0.3, -0.4, 1.0])  # tilted plane facing the camera
    d = 2.2
    # quad on the plane through rays just outside the image corners (all in front of the camera)
    corners = np.array([[-2.0, -2.0], [cam.width + 1.0, -2.0], [cam.width + 1.0, cam.height + 1.0],
                        [-2.0, cam.height + 1.0]])
    rays = np.stack([(corners[:, 0] - cam.cx) / cam.fx, (corners[:, 1] - cam.cy) / cam.fy,
                     np.ones(4)], 1)
    verts = rays * (d / (rays @ (n / np.linalg.norm(n))))[:, None]
    depth, tri = rasterize(verts, np.array([[0, 1, 2], [0, 2, 3]]), cam)
    ref = _analytic_plane_depth(cam, n, d)
    assert (depth > 0).all(), "the quad covers the whole image"
    assert np.abs(depth - ref).max() < 1e-9
    assert set(np.unique(tri)) == {0, 1}
    # back-projected points lie on the plane
    pts, _ = depth_to_points(depth, cam)
    assert np.abs(pts @ (n / np.linalg.norm(n)) - d).max() < 1e-9


def test_rasteriser_partial_coverage_and_occlusion():
    cam = Camera.kinect(320)
    # small triangle: covered pixels are exactly those whose centres are inside it
    tri_v = np.array([[-0.2, -0.1, 1.5], [0.25, -0.05, 1.7], [0.0, 0.3, 1.6]])
    depth, _ = rasterize(tri_v, np.array([[0, 1, 2]]), cam)
    u, v, _ = cam.project(tri_v)
    P = np.stack([u, v], 1)
    vv, uu = np.mgrid[0:cam.height, 0:cam.width]
    q = np.stack([uu, vv], -1).astype(float)

    def edge(a, b):
        return (b[0] - a[0]) * (q[..., 1] - a[1]) - (b[1] - a[1]) * (q[..., 0] - a[0])

    e = np.stack([edge(P[0], P[1]), edge(P[1], P[2]), edge(P[2], P[0])])
    inside = (e >= 0).all(0) | (e <= 0).all(0)
    strict = (e > 1e-6).all(0) | (e < -1e-6).all(0)
    covered = depth > 0
    assert (covered[strict]).all() and not (covered & ~inside).any()
    # nearer plane occludes a farther one
    near = _plane_quad(np.array([0.0, 0.0, 1.0]), 1.0, 0.2)
    far = _plane_quad(np.array([0.0, 0.0, 1.0]), 2.0, 2.0)
    verts = np.concatenate([far, near])
    tris = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    depth, tri = rasterize(verts, tris, cam)
    centre = depth[cam.height // 2, cam.width // 2]
    assert abs(centre - 1.0) < 1e-12 and tri[cam.height // 2, cam.width // 2] >= 2
    assert abs(depth[2, 2] - 2.0) < 1e-12


def test_rasteriser_matches_naive_reference_on_a_figure():
    fig = make_figure("hand")
    cam = Camera.kinect(320).placed_for(fig.vertices.min(0), fig.vertices.max(0))
    v = cam.world_to_camera(fig.vertices)
    d1, t1 = rasterize(v, fig.triangles, cam)
    d2, t2 = rasterize_naive(v, fig.triangles, cam)
    assert (d1 > 0).sum() > 1000
    assert np.array_equal(d1 > 0, d2 > 0)
    assert np.abs(d1 - d2).max() < 1e-9


def _flat_depth(z: float, shape=(240, 320)) -> np.ndarray:
    return np.full(shape, z)


@pytest.mark.parametrize("z", [1.0, 2.0, 3.5])
def test_axial_noise_matches_nguyen_model(z):
    cfg = NoiseConfig.clean(axial=True, seed=3)
    noisy = apply_depth_noise(_flat_depth(z), None, cfg, frame=0)
    err = noisy - z
    sigma = 0.0012 + 0.0019 * (z - 0.4) ** 2
    assert axial_sigma(z, cfg) == pytest.approx(sigma)
    n = err.size
    assert abs(err.mean()) < 4 * sigma / np.sqrt(n)
    assert err.std() == pytest.approx(sigma, rel=0.02)


def test_quantisation_dropout_outliers_and_seeding():
    cfg = NoiseConfig.clean(quantize=True)
    z = np.linspace(0.8, 3.9, 240 * 320).reshape(240, 320)
    q = apply_depth_noise(z, None, cfg, frame=0)
    disp = cfg.quant_baseline * cfg.quant_focal / q / cfg.quant_subpixel
    assert np.abs(disp - np.round(disp)).max() < 1e-6  # on the 1/8-pixel disparity grid
    step = z ** 2 * cfg.quant_subpixel / (cfg.quant_baseline * cfg.quant_focal)
    assert (np.abs(q - z) <= 0.5 * step * 1.05 + 1e-12).all()
    cfg = NoiseConfig.clean(dropout=0.1, seed=5)
    d = apply_depth_noise(_flat_depth(2.0), None, cfg, frame=1)
    assert (d == 0).mean() == pytest.approx(0.1, abs=0.01)
    # same seed -> same result; other frame/seed -> different
    assert np.array_equal(d, apply_depth_noise(_flat_depth(2.0), None, cfg, frame=1))
    assert not np.array_equal(d, apply_depth_noise(_flat_depth(2.0), None, cfg, frame=2))
    # parts have independent streams: axial draws unchanged when dropout is switched on
    a = apply_depth_noise(_flat_depth(2.0), None, NoiseConfig.clean(axial=True, seed=5), 1)
    b = apply_depth_noise(_flat_depth(2.0), None,
                          NoiseConfig.clean(axial=True, dropout=0.1, seed=5), 1)
    keep = b > 0
    assert np.array_equal(a[keep], b[keep])
    pts = np.random.default_rng(0).random((1000, 3)) + [0, 0, 2]
    out = outliers_in_box(pts, NoiseConfig.clean(outliers=0.05, outlier_margin=0.3), 0)
    assert len(out) == 50
    assert (out >= pts.min(0) - 0.3 - 1e-12).all() and (out <= pts.max(0) + 0.3 + 1e-12).all()


def test_flying_pixels_lie_between_foreground_and_background():
    d = _flat_depth(3.0, (60, 80))
    d[20:40, 30:50] = 1.5
    cfg = NoiseConfig.clean(flying=1.0)
    out = apply_depth_noise(d, None, cfg, 0)
    changed = out != d
    assert changed.any()
    # only foreground edge pixels move, backwards, never beyond the background
    assert (d[changed] == 1.5).all()
    assert (out[changed] > 1.5).all() and (out[changed] <= 3.0).all()


def test_noise_config_validation():
    with pytest.raises(ConfigError):
        synthesize("arm", 2, noise=NoiseConfig(dropout=1.5))
    with pytest.raises(ConfigError):
        synthesize("no_such_figure", 2)
    with pytest.raises(ConfigError):
        make_figure("dragon")


@pytest.mark.parametrize("name", FIGURES)
@pytest.mark.parametrize("seed", [0, 3])
def test_figures_kinematics_consistent(name, seed):
    fig = make_figure(name, seed=seed)
    if seed:
        base = make_figure(name)
        ratio = np.linalg.norm(fig.tails - fig.heads, axis=1) / np.linalg.norm(
            base.tails - base.heads, axis=1)
        assert ratio.std() > 0.01 and 0.75 < ratio.min() and ratio.max() < 1.3
    assert fig.parents[0] == -1 and (fig.parents[1:] < np.arange(1, fig.n_bones)).all()
    np.testing.assert_allclose(fig.weights.sum(1), 1.0, atol=1e-12)
    assert (fig.weights >= 0).all()
    angles = fig.angles(6, seed=1)
    R, T = fig.forward(angles)
    # rotations are proper
    np.testing.assert_allclose(np.einsum("fbji,fbjk->fbik", R, R),
                               np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    J = fig.joints(R, T)
    for b in range(1, fig.n_bones):
        p = fig.parents[b]
        # each joint is where parent and child transforms agree (Eq. 20 holds exactly)
        via_parent = np.einsum("fij,j->fi", R[:, p], fig.heads[b]) + T[:, p]
        np.testing.assert_allclose(via_parent, J[:, b], atol=1e-12)
    # rest angles give the rest pose
    R0, T0 = fig.forward(fig.rest_angles(1))
    np.testing.assert_allclose(fig.skin(R0, T0)[0], fig.vertices, atol=1e-12)


def test_sequence_ground_truth_is_consistent_and_clean_points_on_surface():
    seq = synthesize("robot_arm", n_frames=4, seed=2, camera=Camera.kinect(320),
                     noise=NoiseConfig.clean())
    F, J = seq.gt_joints.shape[:2]
    # rigid figure: every surface sample moves with its bone's transform exactly
    lab = seq.surface_labels
    moved = np.einsum("fsij,sj->fsi", seq.bone_rotations[:, lab], seq.rest_surface) + \
        seq.bone_translations[:, lab]
    np.testing.assert_allclose(moved, seq.surface, atol=1e-10)
    # joints = bone heads moved by their bone (rest heads from the figure)
    fig = make_figure("robot_arm", seed=2)
    heads = np.einsum("fbij,bj->fbi", seq.bone_rotations, fig.heads) + seq.bone_translations
    np.testing.assert_allclose(heads, seq.gt_joints, atol=1e-10)
    # clean points back-project to pixel centres
    cam = seq.camera
    u, v, _ = cam.project(seq.frames[0])
    assert np.abs(u - np.round(u)).max() < 1e-6 and np.abs(v - np.round(v)).max() < 1e-6
    assert (seq.point_labels[0] >= 0).all()


def test_clean_points_lie_on_the_mesh():
    seq = synthesize("arm", n_frames=2, camera=Camera.kinect(320), noise=NoiseConfig.clean(),
                     surface_points=20000)
    from scipy.spatial import cKDTree

    d, _ = cKDTree(seq.surface[1]).query(seq.frames[1])
    # dense surface samples: every rendered point is within a sample spacing of the surface
    assert np.percentile(d, 99) < 0.01


def test_motion_options_fast_and_walking():
    fast = synthesize("arm", n_frames=30, speed=6.0, noise=NoiseConfig.clean(),
                      camera=Camera.kinect(320))
    step = np.linalg.norm(np.diff(fast.surface, axis=0), axis=2).max()
    assert step >= 0.25
    walk = synthesize("human", n_frames=20, walk=2.5, noise=NoiseConfig.clean(),
                      camera=Camera.kinect(320))
    root = walk.gt_joints[:, 0]
    assert np.linalg.norm(root[-1] - root[0]) == pytest.approx(2.5, abs=0.35)
    # the subject stays in view in every frame
    assert min(len(f) for f in walk.frames) > 500


def test_synthesize_deterministic_and_write_roundtrip(tmp_path):
    a = synthesize("hand", n_frames=3, seed=4, camera=Camera.kinect(320),
                   noise=NoiseConfig(seed=9, floor=True, background=True))
    b = synthesize("hand", n_frames=3, seed=4, camera=Camera.kinect(320),
                   noise=NoiseConfig(seed=9, floor=True, background=True))
    for fa, fb in zip(a.frames, b.frames):
        assert np.array_equal(fa, fb)
    assert (a.point_labels[0] == -1).sum() > 100  # floor / wall / outliers
    out = a.write(tmp_path / "seq")
    seq = read_sequence(out / "frames")
    assert len(seq.frames) == 3
    for fa, fr in zip(a.frames, seq.frames):
        np.testing.assert_array_equal(fa, fr)
    gt = load_gt(out)
    np.testing.assert_array_equal(gt["joints"], a.gt_joints)
    assert gt["names"] == a.joint_names
    np.testing.assert_array_equal(gt["surface"], a.surface)
    np.testing.assert_array_equal(gt["surface_labels"], a.surface_labels)
    with pytest.raises(InputError, match="gt.npz"):
        load_gt(tmp_path / "missing")


def test_quaternions_and_slerp_match_scipy():
    rng = np.random.default_rng(0)
    q0 = Rotation.random(50, random_state=1).as_quat()
    q1 = Rotation.random(50, random_state=2).as_quat()
    np.testing.assert_allclose(quat_to_matrix(q0), Rotation.from_quat(q0).as_matrix(),
                               atol=1e-12)
    u = rng.random(50)
    mine = Rotation.from_quat(slerp(q0, q1, u)).as_matrix()
    for i in range(50):
        ref = Slerp([0, 1], Rotation.from_quat([q0[i], q1[i]]))([u[i]]).as_matrix()[0]
        np.testing.assert_allclose(mine[i], ref, atol=1e-9)


@pytest.mark.parametrize("interp", ["LINEAR", "STEP"])
def test_gltf_two_bone_matches_analytic(tmp_path, interp):
    path = tmp_path / "strip.glb"
    geo = write_two_bone_glb(path, angle_deg=90.0, interpolation=interp, duration=1.0)
    model = load_gltf(path)
    assert model.joint_names == ["root", "tip"]
    assert model.joint_parents.tolist() == [-1, 0]
    posed = pose_gltf(path, n_frames=4, fps=4.0)  # t = 0, 0.25, 0.5, 0.75
    for k in range(4):
        u = k / 4 if interp == "LINEAR" else 0.0
        verts, joints = expected_two_bone(geo["verts"], geo["upper"], u, 90.0)
        np.testing.assert_allclose(posed.vertices[k], verts, atol=1e-6)
        np.testing.assert_allclose(posed.joints[k], joints, atol=1e-6)


@pytest.mark.parametrize("mode", ["skins", "rigid"])
def test_gltf_split_meshes_follow_their_joints(tmp_path, mode):
    # the strip as two meshes: a second skin listing only the tip, or a rigid part under the
    # tip's node; both halves must move as the one-mesh strip does
    path = tmp_path / "split.glb"
    geo = write_split_two_bone_glb(path, mode)
    model = load_gltf(path)
    assert model.joint_names == ["root", "tip"]
    posed = pose_gltf(path, n_frames=4, fps=4.0)
    assert posed.vertices.shape == (4, len(geo["verts"]), 3)
    for k in range(4):
        verts, joints = expected_two_bone(geo["verts"], geo["upper"], k / 4, 90.0)
        np.testing.assert_allclose(posed.vertices[k], verts, atol=1e-6)
        np.testing.assert_allclose(posed.joints[k], joints, atol=1e-6)
    assert np.allclose(model.weights[geo["upper"], 1], 1.0)


def test_posed_size_is_the_median_box_diagonal():
    # a box 1 x 2 x 2 (diagonal 3) in two frames, 2 x 4 x 4 (diagonal 6) in one: median 3
    box = np.array([[x, y, z] for x in (0, 1) for y in (0, 2) for z in (0, 2)], dtype=float)
    verts = np.stack([box, box + 5.0, 2 * box])
    posed = Posed("box", verts, np.zeros((0, 3), dtype=np.int64), np.ones((8, 1)),
                  np.zeros((3, 1, 3)), ["j"], np.array([-1]), np.zeros((3, 1, 3, 3)),
                  np.zeros((3, 1, 3)), box, np.zeros(0, dtype=np.int64), np.zeros((0, 3)))
    assert posed_size(posed) == pytest.approx(3.0)
    # the yaw is undone: a box turned by 30 degrees about y has the same size
    c, s = np.cos(np.radians(30)), np.sin(np.radians(30))
    Ry = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    posed.vertices = verts @ Ry.T
    assert posed_size(posed, yaw=30.0) == pytest.approx(3.0)


def _world(seq) -> np.ndarray:
    cam = seq.camera
    return (seq.gt_joints - np.asarray(cam.translation)) @ np.asarray(cam.rotation)


def test_synthesize_size_scales_the_subject_and_distance_places_the_camera():
    kw = {"n_frames": 3, "seed": 0, "noise": NoiseConfig.clean(), "camera": Camera.kinect(320)}
    a = synthesize("arm", size=1.0, **kw)
    b = synthesize("arm", size=2.5, **kw)
    np.testing.assert_allclose(_world(b), 2.5 * _world(a), atol=1e-9)
    assert b.params["scale"] == pytest.approx(2.5 * a.params["scale"])
    # the walk stays in metres whatever the scale
    w = synthesize("arm", size=2.5, walk=1.0, **kw)
    np.testing.assert_allclose(_world(w)[:, :, 0] - _world(b)[:, :, 0],
                               np.broadcast_to(np.array([-0.5, 0.0, 0.5])[:, None],
                                               b.gt_joints.shape[:2]),
                               atol=1e-9)
    # the camera distance: the eye sits `distance` metres from the subject box's centre, and
    # the subject is seen about that far
    far = synthesize("arm", size=1.0, distance=3.5, **kw)
    eye = -np.asarray(far.camera.rotation).T @ np.asarray(far.camera.translation)
    world = _world(far)
    lo, hi = world.reshape(-1, 3).min(0), world.reshape(-1, 3).max(0)
    assert abs(np.linalg.norm(eye - (lo + hi) / 2) - 3.5) < 0.3
    assert abs(np.median(far.frames[0][:, 2]) - 3.5) < 0.3
    with pytest.raises(ConfigError):
        synthesize("arm", size=0.0, **kw)
    with pytest.raises(ConfigError):
        synthesize("arm", distance=-1.0, **kw)


def test_camera_placed_at_a_distance():
    lo, hi = np.array([-0.5, 0.0, -0.2]), np.array([0.5, 1.8, 0.2])
    cam = Camera.kinect().placed_for(lo, hi, np.array([1.0, 0.0, 1.0]), distance=4.0)
    eye = -np.asarray(cam.rotation).T @ np.asarray(cam.translation)
    np.testing.assert_allclose(eye, (lo + hi) / 2 + 4.0 * np.array([1.0, 0.0, 1.0]) / np.sqrt(2),
                               atol=1e-12)
    with pytest.raises(ConfigError):
        Camera.kinect().placed_for(lo, hi, distance=0.0)


def test_gltf_real_model_and_errors(tmp_path):
    path = DATA / "girl.glb"
    model = load_gltf(path)
    assert len(model.joint_names) == 23 and model.clip_names() == ["IdleTrack", "RunTrack"]
    seq = synthesize(path, n_frames=3, clip="Run", camera=Camera.kinect(320),
                     noise=NoiseConfig.clean())
    assert seq.params["clip"] == "RunTrack"
    assert seq.gt_joints.shape == (3, 23, 3)
    # IK targets carry no skin
    names = seq.joint_names
    assert not seq.skinned[names.index("IKLegPole.L")] and seq.skinned[names.index("Head")]
    # joints sit inside the body: near the surface samples of their own part
    assert len(seq.frames[0]) > 1000
    # bone transforms take the bind-pose skin joint positions to the GT joints
    bind = np.linalg.inv(model.inverse_bind)[:, :3, 3]
    moved = np.einsum("fbij,bj->fbi", seq.bone_rotations, bind) + seq.bone_translations
    np.testing.assert_allclose(moved, seq.gt_joints, atol=1e-6)
    with pytest.raises(InputError, match="no animation named"):
        synthesize(path, n_frames=2, clip="Dance")
    bad = tmp_path / "bad.glb"
    bad.write_bytes(b"glTF\x02\x00\x00\x00\x10\x00\x00\x00")
    with pytest.raises(InputError, match="bad.glb"):
        load_gltf(bad)
    with pytest.raises(InputError, match="not found"):
        load_gltf(tmp_path / "none.glb")


def test_bundled_demo_is_reproducible(tmp_path):
    import importlib.util

    from pointrig.data import demo_path

    script = Path(__file__).resolve().parents[1] / "scripts" / "make_demo.py"
    spec = importlib.util.spec_from_file_location("make_demo", script)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    mod.make_demo(tmp_path / "demo")
    bundled = read_sequence(demo_path() / "frames")
    fresh = read_sequence(tmp_path / "demo" / "frames")
    assert len(bundled.frames) == len(fresh.frames) >= 20
    from scipy.spatial import cKDTree

    # tolerant comparison: libm/SIMD rounding may differ across machines
    for a, b in zip(bundled.frames, fresh.frames):
        assert 2000 <= len(a) <= 8000
        assert abs(len(a) - len(b)) <= 0.01 * len(a)
        d, _ = cKDTree(a).query(b)
        assert np.mean(d < 1e-4) > 0.99
    ga, gb = load_gt(demo_path()), load_gt(tmp_path / "demo")
    np.testing.assert_allclose(ga["joints"], gb["joints"], atol=1e-9)
    size = sum(f.stat().st_size for f in demo_path().rglob("*") if f.is_file())
    assert size < 3e6


def test_kinect_fov_scales_the_image_not_the_view():
    """``Camera.kinect_fov(w)`` is Kinect v1's view at another size: the 640 camera exactly,
    and at 1280 every point lands on the doubled pixel coordinate (pixel centres at
    ``2 (u + 1/2) - 1/2``), so the same scene gives 4x the pixels."""
    from pointrig.errors import ConfigError

    for w in (320, 640):
        assert Camera.kinect_fov(w) == Camera.kinect(w)
    big, ref = Camera.kinect_fov(1280), Camera.kinect(640)
    assert (big.width, big.height, big.fx) == (1280, 960, 1050.0)
    pts = np.random.default_rng(0).uniform([-1, -1, 1.5], [1, 1, 3.5], size=(50, 3))
    u1, v1, _ = ref.project(pts)
    u2, v2, _ = big.project(pts)
    np.testing.assert_allclose(u2, 2 * (u1 + 0.5) - 0.5, atol=1e-9)
    np.testing.assert_allclose(v2, 2 * (v1 + 0.5) - 0.5, atol=1e-9)
    for bad in (8, 640.0, True):
        with pytest.raises(ConfigError, match="camera width"):
            Camera.kinect_fov(bad)
