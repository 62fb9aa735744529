"""benchmarks/bench_misses.py: the causes of missed joints and the bones' visibility, on
constructed joints and surfaces whose answers are known by construction."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from bench_misses import CAUSES, bone_visibility, classify_misses, ray_offsets  # noqa: E402


def _scene() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Eight true joints 2 m in front of the camera, five output joints, threshold 10 cm."""
    g = np.array([[0.0, 0.0, 2.0],     # 0: an output joint 1 cm off -> matched
                  [0.3, 0.0, 2.0],     # 1 and 2: 2 cm apart, one output joint between them
                  [0.32, 0.0, 2.0],    #    -> one matched, the other shared
                  [-0.3, 0.0, 2.0],    # 3: output joint 20 cm further along the ray -> depth
                  [0.0, 0.3, 2.0],     # 4: output joint 15 cm across -> placement
                  [0.0, -0.3, 2.0],    # 5: as 4 but its bone barely seen -> hidden
                  [0.0, 0.6, 2.0],     # 6: not scorable, nothing near -> never reported
                  [0.0, 0.9, 2.0]])    # 7: scorable, nearest output joint 60 cm off -> absent
    u3 = g[3] / np.linalg.norm(g[3])
    p = np.array([g[0] + [0.01, 0.0, 0.0],
                  [0.31, 0.0, 2.0],
                  g[3] + 0.2 * u3,
                  g[4] + [0.15, 0.0, 0.0],
                  g[5] + [-0.15, 0.0, 0.0]])
    F = 3
    drift = np.linspace(0.0, 0.05, F)[:, None, None] * np.array([1.0, 0.0, 0.0])
    scorable = np.array([True] * 6 + [False, True])
    vis = np.array([0.8, 0.8, 0.8, 0.8, 0.8, 0.05, 0.8, 0.8])
    return p[None] + drift, g[None] + drift, scorable, vis


def test_each_cause_is_found_where_it_was_built() -> None:
    P, G, scorable, vis = _scene()
    misses = classify_misses(P, G, scorable, 0.10, vis)
    by_joint = {j: (cause, k, dist) for j, cause, k, dist in misses}
    assert set(by_joint) - {1, 2} == {3, 4, 5, 7}
    shared = [j for j in (1, 2) if j in by_joint]
    assert len(shared) == 1 and by_joint[shared[0]][:2] == ("shared", 1)
    assert abs(by_joint[shared[0]][2] - 0.01) < 1e-9
    assert by_joint[3][:2] == ("depth", 2) and abs(by_joint[3][2] - 0.2) < 1e-9
    assert by_joint[4][:2] == ("placement", 3) and abs(by_joint[4][2] - 0.15) < 1e-9
    assert by_joint[5][:2] == ("hidden", 4)
    assert by_joint[7][:2] == ("absent", 3) and abs(by_joint[7][2] - np.hypot(0.15, 0.6)) < 1e-9
    assert all(c in CAUSES for c, _, _ in by_joint.values())


def test_a_seen_joint_gets_its_cause_and_a_higher_bar_hides_more() -> None:
    """Joint 5 seen (0.8) is a placement miss like joint 4; with the bar above 0.8 every miss
    is hidden; a 25 cm threshold matches the depth, placement and hidden joints, one of the
    two joints 2 cm apart is still short of an output joint, and joint 7 (63 cm off) stays
    missed."""
    P, G, scorable, vis = _scene()
    vis_seen = vis.copy()
    vis_seen[5] = 0.8
    causes = {j: c for j, c, _, _ in classify_misses(P, G, scorable, 0.10, vis_seen)}
    assert causes[5] == "placement"
    causes = {j: c for j, c, _, _ in classify_misses(P, G, scorable, 0.10, vis, hidden=0.9)}
    assert set(causes.values()) == {"hidden"}
    wide = {j for j, _, _, _ in classify_misses(P, G, scorable, 0.25, vis)}
    assert wide - {7} == wide & {1, 2} and len(wide & {1, 2}) == 1 and 7 in wide


def test_no_output_joints_reads_every_scorable_joint_as_missed() -> None:
    _, G, scorable, vis = _scene()
    misses = classify_misses(np.zeros((G.shape[0], 0, 3)), G, scorable, 0.10, vis)
    assert [(j, c) for j, c, _, _ in misses] == [
        (0, "absent"), (1, "absent"), (2, "absent"), (3, "absent"), (4, "absent"),
        (5, "hidden"), (7, "absent")]


def test_bone_visibility_counts_own_points_within_the_tolerance() -> None:
    """Bone 0 fully observed; bone 1 observed on half of its samples in frame 0 and not at
    all in frame 1, with another bone's points on the rest of it (those do not count); bone 2
    has too few samples (nan)."""
    # samples 5 cm apart along lines, so a sample's tolerance ball holds only its own point
    line = np.arange(40)[:, None] * np.array([0.05, 0.0, 0.0])
    s0 = line + [-1.0, 0.0, 2.0]
    s1 = line + [1.5, 0.0, 2.0]
    s2 = line[:5] + [-1.0, 0.5, 2.0]
    surface1 = np.concatenate([s0, s1, s2])
    surface = np.stack([surface1, surface1])
    labels = np.repeat([0, 1, 2], [40, 40, 5])
    noise = np.array([0.0, 0.0, 0.005])  # within the 2 cm tolerance
    f0 = np.concatenate([s0 + noise, s1[:20] + noise, s1[20:] + noise, s2])
    l0 = np.concatenate([np.zeros(40), np.ones(20), np.full(20, 2), np.full(5, 2)])
    f1 = np.concatenate([s0 + noise, s1 + noise])
    l1 = np.concatenate([np.zeros(40), np.full(40, -1)])
    vis = bone_visibility([f0, f1], [l0.astype(int), l1.astype(int)], surface, labels, 3)
    assert vis.shape == (2, 3)
    np.testing.assert_allclose(vis[:, 0], [1.0, 1.0])
    np.testing.assert_allclose(vis[:, 1], [0.5, 0.0])
    assert np.isnan(vis[:, 2]).all()
    # a tolerance below the 5 mm offset sees nothing
    tight = bone_visibility([f0, f1], [l0.astype(int), l1.astype(int)], surface, labels, 3,
                            tol=0.004)
    np.testing.assert_allclose(tight[:, :2], 0.0)


def test_ray_offsets_split_a_known_offset() -> None:
    """A joint 3 cm nearer the camera along its ray and 4 cm across it, in every frame of a
    random set of true positions: the split returns -3 and 4 cm (closed form), and the two
    parts rebuild the 5 cm distance."""
    rng = np.random.default_rng(3)
    g = rng.normal(size=(30, 3)) + np.array([0.0, 0.0, 2.5])
    u = g / np.linalg.norm(g, axis=1, keepdims=True)
    side = np.cross(u, rng.normal(size=(30, 3)))
    side /= np.linalg.norm(side, axis=1, keepdims=True)
    p = g - 0.03 * u + 0.04 * side
    along, across = ray_offsets(p, g)
    assert abs(along + 0.03) < 1e-12 and abs(across - 0.04) < 1e-12
    assert abs(np.hypot(along, across) - np.linalg.norm(p - g, axis=1).mean()) < 1e-12
    far, _ = ray_offsets(g + 0.02 * u, g)
    assert abs(far - 0.02) < 1e-12
