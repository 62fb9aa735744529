"""rig.glb: the skinned rest surface, read back by pygltflib and imported into Blender.

The subject is a branching chain of capsules with known geometry whose bones disagree a
little on their joints (as step 3's do), so the exports must follow skeleton.json's joints,
not the bones. Oracles: the capsules' closed-form surface, a brute-force point-triangle
distance, pygltflib's reading of the file, and Blender's own import and skinning.
"""

from __future__ import annotations

import numpy as np
import pytest
from rig_helpers import CAMERA_TO_BLENDER, compare_with_blender, read_rig_glb
from scipy.spatial.transform import Rotation

from pointrig.config import RigConfig
from pointrig.export import joint_transforms, write_bvh, write_gltf
from pointrig.pipeline import build_skeleton
from pointrig.rig import build_surface, surface_distances

#: joints (camera frame, metres): a torso from the root up (y down), two arms, a head
PARENTS = np.array([-1, 0, 1, 1, 3, 1])
JOINTS = np.array([[0, 0.3, 2.0], [0, -0.1, 2.0], [0.35, -0.1, 2.0], [-0.05, -0.1, 2.0],
                   [-0.35, -0.1, 2.0], [0, -0.35, 2.0]], float)
#: capsule segments (joint a -> joint b) with radii; the label of each is its bone (b)
SEGMENTS = [(0, 1, 0.09), (1, 2, 0.04), (3, 4, 0.04), (1, 5, 0.06)]


def _capsule_distance(p: np.ndarray) -> np.ndarray:
    """Signed distance ``(N,)`` from points to the union of the capsules (metres)."""
    best = np.full(len(p), np.inf)
    for a, b, r in SEGMENTS:
        A, B = JOINTS[a], JOINTS[b]
        t = np.clip((p - A) @ (B - A) / ((B - A) @ (B - A)), 0, 1)
        best = np.minimum(best, np.linalg.norm(p - (A + t[:, None] * (B - A)), axis=1) - r)
    return best


def _subject(rng, F=12, gap=0.01):
    """A :class:`Skeleton` of the capsules: rest points on their surface (all sides),
    blended weights near the joints, a smooth motion with joints that are not rigid."""
    pts, lab = [], []
    for a, b, r in SEGMENTS:
        A, B = JOINTS[a], JOINTS[b]
        L = np.linalg.norm(B - A)
        axis = (B - A) / L
        # the side: directions across the axis; the caps: half spheres at both ends
        n = int(2 * np.pi * r * L / 0.01 ** 2)
        u = rng.normal(size=(n, 3))
        u -= (u @ axis)[:, None] * axis
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        side = A + rng.random(n)[:, None] * (B - A) + r * u
        m = int(2 * np.pi * r * r / 0.01 ** 2)
        caps = []
        for end, sign in ((A, -1.0), (B, 1.0)):
            u = rng.normal(size=(m, 3))
            u /= np.linalg.norm(u, axis=1, keepdims=True)
            u *= np.where(u @ axis * sign < 0, -1.0, 1.0)[:, None]
            caps.append(end + r * u)
        q = np.concatenate([side, *caps])
        pts.append(q)
        lab.append(np.full(len(q), b))
    q = np.concatenate(pts)
    keep = _capsule_distance(q) > -1e-9  # on the union's outer surface only
    q, lab = q[keep], np.concatenate(lab)[keep]
    W = np.eye(len(PARENTS))[lab]
    # blend each point with the parent bone near the joint it shares
    for k in range(1, len(PARENTS)):
        d = np.linalg.norm(q - JOINTS[k], axis=1)
        near = (lab == k) & (d < 0.08)
        W[near, PARENTS[k]] += 0.5 * (1 - d[near] / 0.08)
    W /= W.sum(axis=1, keepdims=True)
    R = np.zeros((F, 6, 3, 3))
    T = np.zeros((F, 6, 3))
    for t in range(F):
        ph = 2 * np.pi * t / F
        Wd, pos = [None] * 6, [None] * 6
        for j in range(6):
            local = Rotation.from_rotvec(0.5 * np.sin(ph + j) * np.array(
                [0.3, 0.5, 1.0])).as_matrix()
            if PARENTS[j] < 0:
                Wd[j], pos[j] = local, JOINTS[j] + np.array([0.05 * np.sin(ph), 0, 0])
            else:
                p = PARENTS[j]
                Wd[j], pos[j] = Wd[p] @ local, pos[p] + Wd[p] @ (JOINTS[j] - JOINTS[p])
            R[t, j] = Wd[j]
            T[t, j] = pos[j] - Wd[j] @ JOINTS[j] + gap * np.array([np.cos(ph + j), 0, 0])
    return build_skeleton(q, PARENTS, JOINTS, R, T, W, lab)


@pytest.fixture(scope="module")
def rig_out(tmp_path_factory):
    """An output folder as the pipeline writes it, from the capsule subject."""
    rng = np.random.default_rng(7)
    out = tmp_path_factory.mktemp("rig")
    sk = _subject(rng)
    sk.fps = 25.0
    mesh, stats = build_surface(sk, RigConfig(faces=6000, fill_frames=0))
    sk.save_json(out / "skeleton.json")
    sk.save_weights(out / "weights.npz")
    write_bvh(out / "skeleton.bvh", sk, fps=sk.fps)
    write_gltf(out / "rig.glb", sk, fps=sk.fps, mesh=mesh)
    return out, sk, mesh, stats


def test_surface_lies_on_the_capsules_and_is_closed(rig_out):
    _, sk, mesh, stats = rig_out
    assert stats.faces <= 6000 and len(mesh.faces) == stats.faces
    # the level set lies about `radius` outside the points: the capsules grown by it
    d = _capsule_distance(mesh.vertices) - stats.radius
    assert np.abs(np.median(d)) < 0.1 * stats.radius
    assert np.percentile(np.abs(d), 95) < 0.3 * stats.radius
    # closed: every edge shared by exactly two faces
    e = np.sort(np.concatenate([mesh.faces[:, [0, 1]], mesh.faces[:, [1, 2]],
                                mesh.faces[:, [2, 0]]]), axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    assert (counts == 2).mean() > 0.999
    # outward normals: along the capsule distance's gradient
    eps = 1e-4
    grad = np.stack([(_capsule_distance(mesh.vertices + eps * np.eye(3)[k])
                      - _capsule_distance(mesh.vertices - eps * np.eye(3)[k])) / (2 * eps)
                     for k in range(3)], axis=1)
    assert np.median(np.einsum("va,va->v", grad, mesh.normals)) > 0.9


def test_weights_are_normalised_smooth_and_on_their_part(rig_out):
    _, sk, mesh, _ = rig_out
    W = mesh.weights
    assert np.allclose(W.sum(1), 1.0) and (W >= 0).all() and ((W > 0).sum(1) <= 4).all()
    # a vertex by the middle of an arm is bound to that arm's bone
    for a, b, _ in SEGMENTS[1:3]:
        mid = 0.5 * (JOINTS[a] + JOINTS[b])
        near = np.linalg.norm(mesh.vertices - mid, axis=1) < 0.06
        bone = int(np.argmin(np.linalg.norm(sk.rest_positions - JOINTS[b], axis=1)))
        assert near.any() and (np.argmax(W[near], axis=1) == bone).all()
    # smooth: weights of neighbouring vertices differ little
    f = mesh.faces
    jump = np.abs(W[f[:, 0]] - W[f[:, 1]]).sum(1)
    assert np.percentile(jump, 99) < 0.5


def test_surface_distance_matches_brute_force(rng):
    v = rng.random((30, 3))
    f = rng.integers(0, 30, (40, 3))
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
    p = rng.random((50, 3)) * 1.4 - 0.2
    got = surface_distances(p, v, f, candidates=len(f))
    # brute force: dense barycentric samples of every triangle (a slight overestimate)
    s = np.linspace(0, 1, 161)
    a, b = np.meshgrid(s, s)
    ok = a + b <= 1
    bary = np.stack([1 - a[ok] - b[ok], a[ok], b[ok]], 1)
    samples = np.einsum("sk,fka->fsa", bary, v[f]).reshape(-1, 3)
    from scipy.spatial import cKDTree

    want = cKDTree(samples).query(p)[0]
    assert (got <= want + 1e-9).all() and np.allclose(got, want, atol=0.01)


def test_rig_glb_structure_read_by_pygltflib(rig_out):
    out, sk, mesh, _ = rig_out
    r = read_rig_glb(out / "rig.glb")
    g, acc = r["gltf"], r["acc"]
    # every accessor with bounds: the bounds are the data's
    for i, a in enumerate(g.accessors):
        if a.min:
            data = acc(i).astype(float)
            np.testing.assert_allclose(a.min, data.min(0), rtol=0, atol=1e-6)
            np.testing.assert_allclose(a.max, data.max(0), rtol=0, atol=1e-6)
    assert r["prim"].mode == 4 and r["faces"].max() < len(r["vertices"])
    np.testing.assert_allclose(r["weight_slots"].sum(1), 1.0, atol=1e-6)
    assert (r["joint_slots"] < sk.n_joints).all()
    np.testing.assert_allclose(np.linalg.norm(r["normals"], axis=1), 1.0, atol=1e-5)
    # inverse bind matrices invert each joint's rest transform relative to the mesh node
    nodes = g.nodes
    parent = {c: i for i, n in enumerate(nodes) for c in (n.children or [])}
    skin = g.skins[0]
    ibm = acc(skin.inverseBindMatrices).reshape(-1, 4, 4).transpose(0, 2, 1).astype(float)

    def local(n):
        m = np.eye(4)
        if nodes[n].rotation:
            m[:3, :3] = Rotation.from_quat(nodes[n].rotation).as_matrix()
        if nodes[n].translation:
            m[:3, 3] = nodes[n].translation
        return m

    def world(n):
        return world(parent[n]) @ local(n) if n in parent else local(n)

    mesh_node = next(i for i, n in enumerate(nodes) if n.mesh is not None)
    for k, n in enumerate(skin.joints):
        bind = np.linalg.inv(world(mesh_node)) @ world(n)
        np.testing.assert_allclose(ibm[k] @ bind, np.eye(4), atol=1e-5)
    # one animation, keyed at the recorded frame rate over the whole sequence
    anim = g.animations[0]
    times = acc(anim.samplers[0].input)[:, 0]
    np.testing.assert_allclose(times, np.arange(sk.n_frames) / 25.0, atol=1e-6)
    assert g.asset.extras["fps"] == 25.0


def test_blender_imports_the_rig_and_the_bvh_as_skeleton_json(rig_out):
    """Blender (bpy from PyPI in .venv-blender): one bone per joint, the whole sequence, joints
    within 1 mm of skeleton.json at three frames in both files, and the mesh Blender deforms
    within 1 mm of pointrig's skinning with the joint frames."""
    out, sk, mesh, _ = rig_out
    fig = compare_with_blender(out)
    assert fig["bones"] == sk.n_joints
    assert fig["gltf_frames"] == sk.n_frames and fig["bvh_frames"] == sk.n_frames
    assert fig["gltf_joint_mm"] < 1.0 and fig["bvh_joint_mm"] < 1.0
    assert fig["mesh_mm"] < 1.0
    # the check can fail: Blender's joints are not where step 3's bones carry them
    own = np.einsum("fjab,jb->fja", sk.bone_rotations, sk.rest_positions) \
        + sk.bone_translations
    assert np.abs(own - sk.joint_positions).max() > 0.002
    R, T = joint_transforms(sk)
    assert np.allclose(np.einsum("fjab,jb->fja", R, sk.rest_positions) + T, sk.joint_positions)
    assert CAMERA_TO_BLENDER[2, 1] == -1.0  # camera y down -> Blender z up


def _square(center, half, z, outward_to_camera=True):
    """Two triangles of a square at depth ``z`` (camera frame), facing the camera or away."""
    cx, cy = center
    v = np.array([[cx - half, cy - half, z], [cx + half, cy - half, z],
                  [cx + half, cy + half, z], [cx - half, cy + half, z]])
    f = np.array([[0, 2, 1], [0, 3, 2]])  # normal -z: towards the camera (y down, x right)
    return v, (f if outward_to_camera else f[:, ::-1])


def test_render_mesh_occludes_shades_and_culls():
    from pointrig.viz import _View, render_mesh

    near_v, near_f = _square((0.0, 0.0), 0.2, 1.0)
    far_v, far_f = _square((0.0, 0.0), 0.5, 2.0)
    back_v, back_f = _square((0.4, 0.4), 0.05, 0.5, outward_to_camera=False)
    v = np.concatenate([near_v, far_v, back_v])
    f = np.concatenate([near_f, far_f + 4, back_f + 8])
    cols = np.array([[250, 0, 0]] * 2 + [[0, 0, 250]] * 2 + [[0, 250, 0]] * 2, float)
    view = _View(v, 200)
    img = np.asarray(render_mesh(v, f, cols, None, None, view))

    def px(x, y):
        u, w = view.project(np.array([[x, y, 0.0]]))[0]
        return img[int(round(w)), int(round(u))]

    assert tuple(px(0.0, 0.0)) == (250, 0, 0)  # the near square, facing the light fully
    assert tuple(px(0.35, -0.35)) == (0, 0, 250)  # the far square around it
    assert tuple(px(0.4, 0.4)) == (0, 0, 250)  # the small square faces away: culled
    assert tuple(px(0.54, 0.54)) == (24, 24, 28)  # outside every face: background


def test_distinct_poses_picks_the_extremes():
    from pointrig.viz import _distinct_poses

    F = 9
    j = np.zeros((F, 2, 3))
    j[:, 1, 0] = np.sin(np.linspace(0, np.pi, F))  # out to 1 at frame 4 and back
    j[6, 1, 1] = 3.0  # one odd pose
    assert _distinct_poses(j) == [0, 4, 6]


def test_rig_png_three_panels(rig_out, tmp_path):
    from PIL import Image

    from pointrig.viz import save_rig_png

    _, sk, mesh, _ = rig_out
    R, T = joint_transforms(sk)
    save_rig_png(tmp_path / "rig.png", mesh.vertices, mesh.faces, mesh.weights, R, T,
                 sk.joint_positions, sk.parents, size=200)
    im = np.asarray(Image.open(tmp_path / "rig.png"))
    assert im.shape == (200, 600, 3)
    for k in range(3):  # every panel shows the surface (not only background)
        panel = im[:, 200 * k:200 * (k + 1)]
        assert (np.abs(panel.astype(int) - [24, 24, 28]).sum(2) > 30).mean() > 0.05


def test_usd_skinning_by_usd_core_matches_pointrig(rig_out, tmp_path):
    """rig.usda read by usd-core's UsdSkel: joints (skeleton space) at skeleton.json's joints
    turned y-up, and UsdSkel's own skinning of the mesh equal to pointrig's LBS, at every
    frame; the stage's time codes run at the frame rate."""
    from pxr import Usd, UsdSkel

    from pointrig.export import CAMERA_TO_YUP
    from pointrig.kinematics import skin
    from pointrig.usd import write_usd

    _, sk, mesh, _ = rig_out
    write_usd(tmp_path / "rig.usda", sk, mesh, fps=25.0)
    stage = Usd.Stage.Open(str(tmp_path / "rig.usda"))
    assert stage.GetTimeCodesPerSecond() == 25.0
    assert stage.GetEndTimeCode() == sk.n_frames - 1
    cache = UsdSkel.Cache()
    root = UsdSkel.Root(stage.GetPrimAtPath("/Rig"))
    cache.Populate(root, Usd.PrimDefaultPredicate)
    sq = cache.GetSkelQuery(UsdSkel.Skeleton(stage.GetPrimAtPath("/Rig/Skeleton")))
    mq = cache.GetSkinningQuery(stage.GetPrimAtPath("/Rig/Surface"))
    rest = np.array(stage.GetPrimAtPath("/Rig/Surface").GetAttribute("points").Get())
    R, T = joint_transforms(sk)
    ours = skin(mesh.vertices, mesh.weights, R, T) @ CAMERA_TO_YUP.T
    names = list(sq.GetJointOrder())
    assert len(names) == sk.n_joints
    for t in range(sk.n_frames):
        xf = sq.ComputeJointSkelTransforms(Usd.TimeCode(t))
        heads = np.array([list(m.ExtractTranslation()) for m in xf])
        np.testing.assert_allclose(heads, sk.joint_positions[t] @ CAMERA_TO_YUP.T, atol=1e-5)
        pts = rest.copy()
        from pxr import Vt

        pts_vt = Vt.Vec3fArray.FromNumpy(pts.astype(np.float32))
        ok = mq.ComputeSkinnedPoints(sq.ComputeSkinningTransforms(Usd.TimeCode(t)), pts_vt,
                                     Usd.TimeCode(t))
        assert ok
        np.testing.assert_allclose(np.array(pts_vt), ours[t], atol=1e-4)


def test_missing_extras_are_one_line_errors_only_when_asked(monkeypatch):
    import sys

    from pointrig.errors import PointrigError
    from pointrig.rig import rig_available
    from pointrig.usd import usd_available

    assert rig_available("auto") and usd_available("auto")
    assert not rig_available("off") and not usd_available("off")
    monkeypatch.setitem(sys.modules, "fast_simplification", None)  # import fails
    monkeypatch.setitem(sys.modules, "pxr.UsdSkel", None)
    assert not rig_available("auto") and not usd_available("auto")
    with pytest.raises(PointrigError, match=r"pip install 'pointrig\[rig\]'"):
        rig_available("on")
    with pytest.raises(PointrigError, match=r"pip install 'pointrig\[usd\]'"):
        usd_available("on")
