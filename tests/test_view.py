"""Single-view depth correction (pointrig.view) against closed-form geometry."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.spatial import cKDTree

from pointrig.config import StructureConfig
from pointrig.structure import StructureResult, extract_structure
from pointrig.view import (
    SINGLE_VIEW_MAX_TWO_LAYER,
    chord_depth_offset,
    chord_half_width,
    chord_roundness,
    image_coordinates,
    in_view,
    is_single_view,
    two_layer_fraction,
    view_depth_correct,
    view_depth_joints,
)


def _cylinder(depth: float, radius: float, length: float, n: int, rng, visible_only: bool
              ) -> np.ndarray:
    """Surface samples of a cylinder along x whose axis crosses (0, 0, depth); with
    ``visible_only`` only the half facing a camera at the origin (normals with z < 0)."""
    theta = rng.uniform(-np.pi, np.pi, n)
    if visible_only:
        theta = rng.uniform(-np.pi / 2, np.pi / 2, n)  # angle from the -z direction
    x = rng.uniform(-length / 2, length / 2, n)
    return np.stack([x, radius * np.sin(theta), depth - radius * np.cos(theta)], 1)


def _sphere_view(depth: float, radius: float, n: int, rng, visible_only: bool) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    if visible_only:
        v[:, 2] = -np.abs(v[:, 2])  # the half facing the camera at the origin
    return v * radius + np.array([0.0, 0.0, depth])


def test_depth_correct_moves_visible_centroid_to_axis_depth():
    rng = np.random.default_rng(0)
    depth, r = 2.0, 0.06
    pts = _cylinder(depth, r, 0.05, 4000, rng, visible_only=True)
    c = pts.mean(0)
    # the visible half-ring's centroid is 2r/pi in front of the axis (closed form)
    assert c[2] == pytest.approx(depth - 2 * r / np.pi, abs=0.1 * r)
    out = view_depth_correct(pts, None, c, np.zeros(3), 0.97)
    u = c / np.linalg.norm(c)
    # moved along the ray only, back to within 0.1 r of the axis depth
    assert np.linalg.norm(np.cross(out - c, u)) < 1e-12
    assert abs(out @ u - depth) < 0.1 * r
    assert abs(pts.mean(0)[2] - depth) > 0.5 * r  # the uncorrected error was much larger


def test_depth_correct_never_moves_towards_camera_and_quantile_zero_is_identity():
    rng = np.random.default_rng(1)
    pts = _cylinder(1.5, 0.05, 0.05, 500, rng, visible_only=True)
    behind = pts.mean(0) + np.array([0.0, 0.0, 0.5])  # already behind every point
    np.testing.assert_array_equal(view_depth_correct(pts, None, behind, np.zeros(3), 0.97),
                                  behind)
    c = pts.mean(0)
    np.testing.assert_array_equal(view_depth_correct(pts, None, c, np.zeros(3), 0.0), c)


def test_depth_correct_weighted_quantile_matches_repeated_points():
    rng = np.random.default_rng(2)
    pts = rng.normal(size=(40, 3)) * 0.05 + np.array([0.1, -0.2, 2.0])
    reps = rng.integers(1, 5, size=40)
    c = pts.mean(0)
    cam = np.array([0.3, 0.1, -0.5])
    a = view_depth_correct(pts, reps.astype(float), c, cam, 0.8)
    b = view_depth_correct(np.repeat(pts, reps, axis=0), None, c, cam, 0.8)
    np.testing.assert_allclose(a, b, atol=1e-12)
    # oracle: the front depth (numpy's inverted-cdf 0.2 quantile of the depths along the ray)
    # plus the radius from the spread across the view along its major axis
    P = np.repeat(pts, reps, axis=0)
    u = (c - cam) / np.linalg.norm(c - cam)
    d = (P - cam) @ u
    lateral = (P - c) - np.outer((P - c) @ u, u)
    axis = np.linalg.eigh(np.cov(lateral.T, bias=True))[1][:, -1]
    s = lateral @ axis
    spread = np.quantile(s, 0.8, method="inverted_cdf") - np.quantile(s, 0.2,
                                                                        method="inverted_cdf")
    expect = max(np.quantile(d, 0.2, method="inverted_cdf") + spread / (2 * 0.6),
                 (c - cam) @ u)
    assert (a - cam) @ u == pytest.approx(expect, abs=1e-9)


def _grazing_cut_ring(depth: float, radius: float, length: float, n: int, theta_max: float,
                      rng) -> np.ndarray:
    """A short cylinder along x, axis through (0, 0, depth), as a depth camera at the origin
    samples it: uniformly in the image, i.e. uniformly in the lateral coordinate
    ``y = r sin(theta)``, up to the viewing angle ``theta_max`` (radians; the sensor loses the
    grazing points near the silhouette first)."""
    a = radius * np.sin(theta_max)
    y = rng.uniform(-a, a, n)
    x = rng.uniform(-length / 2, length / 2, n)
    return np.stack([x, y, depth - np.sqrt(radius ** 2 - y ** 2)], 1)


@pytest.mark.parametrize("theta_deg", [90.0, 70.0])
def test_depth_correct_finds_the_axis_of_an_image_sampled_ring(theta_deg):
    rng = np.random.default_rng(7)
    depth, r, q = 2.0, 0.06, 0.95
    a = r * np.sin(np.radians(theta_deg))  # half-width of what the sensor keeps
    pts = _grazing_cut_ring(depth, r, 0.3 * r, 40000, np.radians(theta_deg), rng)
    c = pts.mean(0)
    u = c / np.linalg.norm(c)
    width = view_depth_correct(pts, None, c, np.zeros(3), q)
    # the alternative estimate, a high quantile of the depths along the ray
    quant = np.quantile(pts @ u, q, method="inverted_cdf") * u
    assert np.linalg.norm(np.cross(width - c, u)) < 1e-12  # along the ray only
    # closed forms with y uniform on [-a, a]: the (1 - q) depth quantile is at |y| = (1 - q) a,
    # the spread between the y quantiles is 2 (2q - 1) a, and the q depth quantile is at
    # |y| = q a
    expect_width = depth - np.sqrt(r ** 2 - ((1 - q) * a) ** 2) + a
    expect_quant = depth - np.sqrt(r ** 2 - (q * a) ** 2)
    assert width @ u == pytest.approx(expect_width, abs=0.02 * r)
    assert quant @ u == pytest.approx(expect_quant, abs=0.02 * r)
    if theta_deg == 90.0:
        # the whole visible half: unbiased, where the depth quantile stays 0.3 r in front
        assert abs(width @ u - depth) < 0.03 * r
        assert depth - quant @ u > 0.25 * r
    else:
        # losing the silhouette costs the width estimate far less than the depth quantile
        assert abs(width @ u - depth) < 0.1 * r
        assert depth - quant @ u > 0.4 * r


def test_depth_correct_never_moves_a_ring_towards_camera_and_rejects_bad_quantiles():
    rng = np.random.default_rng(8)
    pts = _grazing_cut_ring(1.5, 0.05, 0.02, 500, np.radians(80), rng)
    behind = pts.mean(0) + np.array([0.0, 0.0, 0.5])
    np.testing.assert_array_equal(view_depth_correct(pts, None, behind, np.zeros(3), 0.95),
                                  behind)
    c = pts.mean(0)
    with pytest.raises(ValueError, match="above 1/2"):
        view_depth_correct(pts, None, c, np.zeros(3), 0.5)


def test_two_layer_fraction_tells_one_view_from_a_closed_surface():
    rng = np.random.default_rng(3)
    for make in (lambda vis: _sphere_view(2.5, 0.3, 3000, rng, vis),
                 lambda vis: _cylinder(2.0, 0.1, 0.8, 3000, rng, vis)):
        front, both = make(True), make(False)
        assert two_layer_fraction(front, np.zeros(3)) < SINGLE_VIEW_MAX_TWO_LAYER
        assert two_layer_fraction(both, np.zeros(3)) > SINGLE_VIEW_MAX_TWO_LAYER
        assert is_single_view(front, np.zeros(3)) and not is_single_view(both, np.zeros(3))
    # points behind the camera cannot come from one view through it
    pts = _sphere_view(0.0, 1.0, 500, rng, False)
    assert two_layer_fraction(pts, np.zeros(3)) == 1.0


def _two_bone_sequence(visible_only: bool, rng) -> tuple[np.ndarray, np.ndarray]:
    """A cylinder of two 0.4 m bones along x (radius 6 cm, axis depth 2 m) bending at x = 0
    about the view axis, 12 frames; returns rest points and their motion."""
    q = _cylinder(2.0, 0.06, 0.8, 3000, rng, visible_only)
    Y = []
    for ang in np.linspace(0.0, 0.8, 12):
        c, s = np.cos(ang), np.sin(ang)
        R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        y = q.copy()
        right = q[:, 0] > 0
        pivot = np.array([0.0, 0.0, 2.0])
        y[right] = (q[right] - pivot) @ R.T + pivot
        Y.append(y)
    return q, np.stack(Y)


@pytest.mark.parametrize("visible_only", [True, False])
def test_structure_auto_applies_the_correction_only_to_single_view_input(visible_only, tmp_path):
    rng = np.random.default_rng(4)
    q, Y = _two_bone_sequence(visible_only, rng)
    cfg = StructureConfig(n_clusters=8, single_view="auto")
    st = extract_structure(q, Y, cfg)
    assert (st.view_camera is not None) == visible_only
    forced = extract_structure(q, Y, dataclasses.replace(cfg, single_view="yes"))
    np.testing.assert_array_equal(forced.view_camera, np.zeros(3))
    assert forced.view_quantile == cfg.view_depth_quantile
    off = extract_structure(q, Y, dataclasses.replace(cfg, view_depth_quantile=0.0))
    assert off.view_camera is None and off.view_quantile == 0.0
    assert st.n_bones == off.n_bones  # the correction never changes the bone count
    if visible_only:
        # the elbow (axis depth 2 m) is found behind the visible surface's centroid
        k = int(np.flatnonzero(st.bone_parent >= 0)[0])
        assert abs(st.c_tilde[k, 2] - 2.0) < abs(off.c_tilde[k, 2] - 2.0)
        assert abs(st.c_tilde[k, 2] - 2.0) < 0.015
    path = tmp_path / "st.npz"
    st.save(path)
    back = StructureResult.load(path)
    assert back.view_quantile == st.view_quantile
    if st.view_camera is None:
        assert back.view_camera is None
    else:
        np.testing.assert_array_equal(back.view_camera, st.view_camera)


def test_in_view_and_structure_skip_when_the_camera_is_inside_the_subject():
    rng = np.random.default_rng(6)
    front = _sphere_view(2.0, 0.3, 500, rng, True)
    assert in_view(front, np.zeros(3))
    assert not in_view(front - front.mean(0), np.zeros(3))  # world frame centred on it
    assert not in_view(front, np.array([0.0, 0.0, 2.0]))  # camera at the sphere's centre
    q, Y = _two_bone_sequence(True, rng)
    st = extract_structure(q - [0.0, 0.0, 2.0], Y - [0.0, 0.0, 2.0],
                           StructureConfig(n_clusters=8, single_view="yes"))
    assert st.view_camera is None and "skipped" in st.diagnostics["view_depth"]


def test_structure_rejects_bad_view_parameters():
    from pointrig.errors import ConfigError

    rng = np.random.default_rng(5)
    q, Y = _two_bone_sequence(True, rng)
    for bad in ({"view_depth_quantile": 1.5}, {"single_view": "maybe"},
                {"camera_position": (0.0, float("nan"), 0.0)}, {"camera_position": (0.0, 1.0)},
                {"view_depth_quantile": 0.4}):
        (name,) = bad
        with pytest.raises(ConfigError, match=rf"\[structure\] {name} must be"):
            extract_structure(q, Y, StructureConfig(**bad))


# ---------------------------------------------------------------------------- the chord rule


def _ray_cast_cylinder(depth: float, radius: float, x_range: tuple[float, float],
                       pixel: float = 1.0 / 525) -> np.ndarray:
    """What a pinhole depth camera at the origin looking along +z sees of a cylinder along x
    whose axis crosses (0, 0, depth): one point per pixel (``pixel`` in tangent units) on the
    near surface, the exact ray-cylinder intersection."""
    u = np.arange(-0.5, 0.5, pixel)
    U, V = np.meshgrid(u, u)
    U, V = U.ravel(), V.ravel()
    # ray t (U, V, 1): (V t)^2 + (t - depth)^2 = radius^2, nearest root
    a, b, c = V ** 2 + 1.0, -2.0 * depth, depth ** 2 - radius ** 2
    disc = b ** 2 - 4 * a * c
    hit = disc >= 0
    t = (-b - np.sqrt(np.where(hit, disc, 0.0))) / (2 * a)
    P = np.stack([U * t, V * t, t], 1)[hit]
    return P[(P[:, 0] >= x_range[0]) & (P[:, 0] <= x_range[1])]


def _shortest_chord_numpy(uv: np.ndarray, centre: np.ndarray, band: float, gap: float,
                          n_directions: int = 12) -> tuple[float, float, int] | None:
    """The shortest chord as a numpy loop over the directions (the oracle of the Rust
    kernel): ``(a, b, direction index)`` or ``None``."""
    rel = uv - centre
    best = None
    for k, th in enumerate(np.linspace(0.0, np.pi, n_directions, endpoint=False)):
        d = np.array([np.cos(th), np.sin(th)])
        s = np.sort(rel[np.abs(rel @ np.array([-d[1], d[0]])) < band] @ d)
        hi = int(np.searchsorted(s, 0.0))
        if len(s) < 3 or hi == 0 or hi >= len(s) or s[hi] - s[hi - 1] > gap:
            continue
        breaks = np.flatnonzero(np.diff(s) > gap)
        left, right = breaks[breaks < hi - 1], breaks[breaks >= hi]
        a = float(s[left[-1] + 1] if len(left) else s[0])
        b = float(s[right[0]] if len(right) else s[-1])
        if best is None or b - a < best[1] - best[0]:
            best = (a, b, k)
    return best


def test_shortest_chord_equals_the_numpy_loop() -> None:
    """The Rust chord kernel against the numpy loop on random blobs with holes and stray
    points: the same direction and ends (to rounding), ``None`` at the same centres, and rows
    with a NaN left out."""
    from pointrig.view import _shortest_chord

    rng = np.random.default_rng(7)
    found = 0
    for trial in range(40):
        n = int(rng.integers(200, 3000))
        ax = rng.uniform(0.05, 0.5, 2)
        p = rng.uniform(-1, 1, (n, 2)) * ax
        p = p[(p[:, 0] / ax[0]) ** 2 + (p[:, 1] / ax[1]) ** 2 <= 1.0]
        p = p[np.linalg.norm(p - rng.uniform(-0.2, 0.2, 2), axis=1) > rng.uniform(0, 0.1)]
        p = np.vstack([p, rng.uniform(-1, 1, (10, 2))])
        spacing = float(np.median(cKDTree(p).query(p, k=2)[0][:, 1]))
        band, gap = 4.5 * spacing, 6.0 * spacing
        centre = rng.uniform(-0.3, 0.3, 2) * ax
        want = _shortest_chord_numpy(p, centre, band, gap)
        got = _shortest_chord(np.vstack([p, [[np.nan, 0.0]]]), centre, band, gap, 12)
        assert (got is None) == (want is None), trial
        if want is not None:
            found += 1
            np.testing.assert_allclose(got[:2], want[:2], rtol=0, atol=1e-12)
            th = np.pi * want[2] / 12
            np.testing.assert_allclose(got[2], [np.cos(th), np.sin(th)], rtol=0, atol=1e-15)
    assert found >= 20


def test_chord_half_width_of_a_sampled_rectangle_is_half_its_short_side():
    g = np.arange(0.0, 1.0, 0.005)
    X, Y = np.meshgrid(g * 2.0, g * 0.4)
    uv = np.stack([X.ravel(), Y.ravel()], 1)
    half = chord_half_width(uv, np.array([1.0, 0.2]), band=0.01, gap=0.02)
    assert half == pytest.approx(0.2, abs=0.01)
    # off the rectangle (in a gap wider than ``gap``) there is no chord
    assert chord_half_width(uv, np.array([1.0, 0.6]), band=0.01, gap=0.02) == np.inf
    # a second rectangle beyond a gap does not join the chord
    uv2 = np.concatenate([uv, uv + [0.0, 0.5]])
    assert chord_half_width(uv2, np.array([1.0, 0.2]), band=0.01, gap=0.02) == pytest.approx(
        0.2, abs=0.01)


@pytest.mark.parametrize("start", ["front", "axis", "behind"])
def test_chord_depth_offset_finds_a_ray_cast_cylinders_axis(start):
    depth, r = 2.0, 0.08
    P = _ray_cast_cylinder(depth, r, (-0.3, 0.3))
    joint = {"front": np.array([0.05, 0.0, depth - r]), "axis": np.array([0.05, 0.0, depth]),
             "behind": np.array([0.05, 0.0, depth + 0.1])}[start]
    off = chord_depth_offset(P, joint, np.zeros(3), np.array([0.0, 0.0, 1.0]), radius=0.02,
                             band=4.5 / 525, gap=6.0 / 525)
    u = joint / np.linalg.norm(joint)
    moved = joint + off * u
    # the axis point on the joint's ray: closest approach of the ray to the axis
    assert moved[2] == pytest.approx(depth, abs=0.1 * r)
    # nothing near the joint's pixel: undefined
    assert np.isnan(chord_depth_offset(P, np.array([0.0, 0.5, 2.0]), np.zeros(3),
                                       np.array([0.0, 0.0, 1.0]), 0.02, 4.5 / 525, 6.0 / 525))


def test_view_depth_joints_moves_surface_joints_of_a_two_bone_limb_to_its_axis():
    depth, r = 2.0, 0.06
    rest = _ray_cast_cylinder(depth, r, (-0.4, 0.4))
    labels = (rest[:, 0] > 0).astype(np.int64)  # bone 0 (root) x < 0, bone 1 x > 0
    parent = np.array([-1, 0])
    # on the near surface; joint 1 a little inside its bone, as "child" reads only that bone
    # (at the bone's very end the chord can cut the corner)
    joints = np.array([[-0.2, 0.0, depth - r], [0.05, 0.0, depth - r]])
    F = 4
    R = np.tile(np.eye(3), (F, 2, 1, 1))
    T = np.zeros((F, 2, 3))
    frames = [rest.copy() for _ in range(F)]
    registered = np.repeat(rest[None], F, axis=0)
    out, shift = view_depth_joints(frames, registered, labels, parent, joints, R, T,
                                   np.zeros(3), n_frames=3)
    assert out[:, 2] == pytest.approx([depth, depth], abs=0.1 * r)
    np.testing.assert_allclose(shift, np.linalg.norm(out - joints, axis=1), atol=1e-12)
    # joints behind the axis move forwards to it
    deep = joints + [0.0, 0.0, 2 * r]
    out_b, shift_b = view_depth_joints(frames, registered, labels, parent, deep, R, T,
                                       np.zeros(3), n_frames=3)
    assert np.all(shift_b < 0)
    assert out_b[:, 2] == pytest.approx([depth, depth], abs=0.1 * r)


def test_view_depth_joints_ignores_an_occluder_that_misleads_the_whole_view():
    depth, r = 2.0, 0.06
    pixel = 1.0 / 525
    limb = _ray_cast_cylinder(depth, r, (-0.4, 0.4), pixel)
    # a bar across the view at 1.6 m, in front of joint 1: the camera sees the bar there
    u = np.arange(-0.5, 0.5, pixel)
    U, V = np.meshgrid(u, u)
    bar = np.stack([U.ravel() * 1.6, V.ravel() * 1.6, np.full(U.size, 1.6)], 1)
    bar = bar[(bar[:, 0] > 0.03) & (bar[:, 0] < 0.07) & (np.abs(bar[:, 1]) < 0.3)]
    hidden = (limb[:, 0] / limb[:, 2] > 0.03 / 1.6) & (limb[:, 0] / limb[:, 2] < 0.07 / 1.6)
    frame = np.concatenate([limb[~hidden], bar])
    rest = np.concatenate([limb, bar])
    labels = np.concatenate([(limb[:, 0] > 0).astype(np.int64), np.full(len(bar), 2)])
    parent = np.array([-1, 0, 0])
    joints = np.array([[-0.2, 0.0, depth - r], [0.05, 0.0, depth - r], [0.05, 0.0, 1.6]])
    F = 3
    R = np.tile(np.eye(3), (F, 3, 1, 1))
    T = np.zeros((F, 3, 3))
    args = ([frame] * F, np.repeat(rest[None], F, axis=0), labels, parent, joints, R, T,
            np.zeros(3))
    # the whole view's reading puts joint 1 at the bar's depth
    assert _whole_view_offset(frame, joints[1]) < -0.2
    out, shift = view_depth_joints(*args)
    assert shift[1] == 0.0  # joint 1's bone is not what is seen, its own bones disagree: stays
    assert out[0, 2] == pytest.approx(depth, abs=0.1 * r)  # the visible joint still moves


def _whole_view_offset(points: np.ndarray, joint: np.ndarray) -> float:
    """:func:`chord_depth_offset` of ``joint`` read from all of ``points`` (one frame seen from
    the origin, the parameters of :func:`view_depth_joints`' defaults): the chord rule on the
    whole view, metres along the ray."""
    axis = points.mean(0) / np.linalg.norm(points.mean(0))
    uv = image_coordinates(points, np.zeros(3), axis)[0]
    spacing = float(np.median(cKDTree(uv).query(uv, k=2)[0][:, 1]))
    size = float(np.linalg.norm(np.ptp(points, axis=0)))
    return chord_depth_offset(points, joint, np.zeros(3), axis, 0.02 * size, 4.5 * spacing,
                              6.0 * spacing)


def _plate(depth: float, half: float, pixel: float = 1.0 / 525) -> np.ndarray:
    """``(n, 3)`` a flat square plate facing the camera at the origin (depth ``depth`` m, side
    ``2 half`` m), one point per pixel."""
    u = np.arange(-0.5, 0.5, pixel)
    U, V = np.meshgrid(u, u)
    P = np.stack([U.ravel() * depth, V.ravel() * depth, np.full(U.size, depth)], 1)
    return P[(np.abs(P[:, 0]) <= half) & (np.abs(P[:, 1]) <= half)]


def test_chord_roundness_tells_a_round_part_from_a_flat_one():
    axis, band, gap = np.array([0.0, 0.0, 1.0]), 4.5 / 525, 6.0 / 525
    cyl = _ray_cast_cylinder(2.0, 0.08, (-0.3, 0.3))
    uv, z = image_coordinates(cyl, np.zeros(3), axis)
    # the exact circular profile: depth over half-width 1 (the fit leaves the grazing ends out)
    assert chord_roundness(uv, z, np.array([0.02, 0.0]), band, gap) == pytest.approx(1.0,
                                                                                    abs=0.15)
    plate = _plate(2.0, 0.1)
    uvp, zp = image_coordinates(plate, np.zeros(3), axis)
    assert abs(chord_roundness(uvp, zp, np.array([0.0, 0.0]), band, gap)) < 0.05
    # off the silhouette: undefined
    assert np.isnan(chord_roundness(uv, z, np.array([0.0, 0.3]), band, gap))
    # a thin rod seen in front of a wider plate: no image gap between them, so the chord runs
    # on over the plate, and its profile is a step, far deeper for its width than a circle
    rod = _ray_cast_cylinder(1.8, 0.03, (-0.3, 0.3))
    back = _plate(2.1, 0.25)
    behind = np.abs(back[:, 1] / 2.1) < np.abs(rod[:, 1] / 1.8).max()
    uvs, zs = image_coordinates(np.concatenate([rod, back[~behind]]), np.zeros(3), axis)
    assert chord_roundness(uvs, zs, np.array([0.0, 0.0]), band, gap) > 1.0 / 0.7


def _strip_labelled(points: np.ndarray, strip: float) -> np.ndarray:
    """Bone 1 = a strip ``|y| < strip`` m right of x = 0 (a fragment of the part, as a bone that
    cuts across a rig's part labels it), bone 0 = the rest."""
    return ((points[:, 0] > 0) & (np.abs(points[:, 1]) < strip)).astype(np.int64)


def _depth_args(points: np.ndarray, labels: np.ndarray, joints: np.ndarray, F: int = 3):
    B = len(joints)
    return ([points] * F, np.repeat(points[None], F, axis=0), labels, np.array([-1, 0]),
            joints, np.tile(np.eye(3), (F, B, 1, 1)), np.zeros((F, B, 3)), np.zeros(3))


def test_view_depth_joints_trusts_the_whole_view_of_a_seen_round_part():
    # a thick round limb whose joint-1 bone labels only a strip along it: the bone's own
    # silhouette is narrow and reads the joint forwards, so the three readings disagree in
    # sign; the bone is what the camera sees at the joint's pixel and the part is round, so
    # the whole view's reading is taken: the axis
    depth, r = 2.0, 0.15
    limb = _ray_cast_cylinder(depth, r, (-0.5, 0.5))
    joints = np.array([[-0.2, 0.0, depth - r], [0.1, 0.0, depth - r + 0.03]])
    labels = _strip_labelled(limb, 0.01)
    args = _depth_args(limb, labels, joints)
    assert _whole_view_offset(limb[labels == 1], joints[1]) < 0  # its own bone: forwards
    out, shift = view_depth_joints(*args)
    assert shift[1] > 0
    assert out[1, 2] == pytest.approx(depth, abs=0.1 * r)


def test_view_depth_joints_keeps_a_joint_on_a_flat_part():
    # the same labels on a flat plate: wide in the image but thin along the ray, so the whole
    # view's chord would push the joint far back; the flat depth profile vetoes it, and any
    # other chord reading with it (the joint stays); without the veto the readings' sign
    # consensus moves it by less than 2 cm
    depth = 2.0
    plate = _plate(depth, 0.15)
    joints = np.array([[-0.1, 0.0, depth], [0.05, 0.0, depth + 0.01]])
    args = _depth_args(plate, _strip_labelled(plate, 0.01), joints)
    assert _whole_view_offset(plate, joints[1]) > 0.1
    _, shift = view_depth_joints(*args)
    assert shift[1] == 0.0
    assert abs(view_depth_joints(*args, flat_roundness=-1.0)[1][1]) < 0.02
