"""Tests of pointrig.evaluate (matching, scores, scorable-joint rules, loaders, CLI)."""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest

from pointrig.cli import main
from pointrig.errors import ConfigError, InputError
from pointrig.evaluate import (
    evaluate,
    evaluate_files,
    far_joints,
    load_prediction,
    match_pairs,
    pivot_errors,
    scorable_joints,
    subject_size,
)
from pointrig.skeleton import Skeleton
from pointrig.synth import Camera, NoiseConfig, synthesize
from pointrig.synth.figures import rodrigues


@pytest.fixture(scope="module")
def human():
    return synthesize("human", n_frames=20, seed=1, camera=Camera.kinect(320),
                      noise=NoiseConfig.clean(), surface_points=2000)


def _kw(seq):
    return dict(surface=seq.surface, surface_labels=seq.surface_labels, skinned=seq.skinned,
                gt_names=seq.joint_names)


def test_ground_truth_plus_1cm_noise(human):
    rng = np.random.default_rng(0)
    g = human.gt_joints
    dirs = rng.normal(size=g.shape)
    dirs /= np.linalg.norm(dirs, axis=2, keepdims=True)
    rep = evaluate(g + 0.01 * dirs, g, human.joint_parents, **_kw(human))
    assert rep.n_scorable >= 10
    assert rep.recall == 1.0
    assert rep.raw_error == pytest.approx(0.01, abs=1e-9)  # every offset is exactly 1 cm
    assert 0.008 < rep.normalized_error <= 0.01 + 1e-9
    # predicting exactly the scorable joints gives precision 1
    rep2 = evaluate(g[:, rep.scorable], g, human.joint_parents, **_kw(human))
    assert rep2.precision == 1.0 and rep2.raw_error < 1e-12


def test_single_centroid_joint(human):
    cen = human.surface.mean(axis=1, keepdims=True)
    rep = evaluate(cen, human.gt_joints, human.joint_parents, **_kw(human))
    assert rep.recall <= 1.0 / rep.n_scorable + 1e-12
    assert rep.n_matched <= 1 and rep.n_pred == 1


def test_constant_offset(human):
    g = human.gt_joints
    rep = evaluate(g + np.array([0.0, 0.05, 0.0]), g, human.joint_parents, **_kw(human))
    assert rep.recall == 1.0
    assert rep.raw_error == pytest.approx(0.05, abs=1e-12)
    assert rep.normalized_error < 1e-12
    for row in rep.rows:
        if row.scorable:
            assert row.raw_error == pytest.approx(0.05, abs=1e-12)


def test_threshold_rule_and_gate(human):
    s = subject_size(human.gt_joints, human.surface)
    rep = evaluate(human.gt_joints, human.gt_joints, human.joint_parents, **_kw(human))
    assert rep.threshold == pytest.approx(0.08 * s)
    far = human.gt_joints + np.array([0.0, 0.0, 0.08 * s * 1.01])
    rep_far = evaluate(far, human.gt_joints, human.joint_parents, **_kw(human))
    # no joint may match its own (shifted) copy; any other match is genuinely within tau
    for j, row in enumerate(rep_far.rows):
        assert row.matched != j
        if row.matched >= 0:
            assert row.raw_error < rep_far.threshold
    near = human.gt_joints + np.array([0.0, 0.0, 0.08 * s * 0.99])
    assert evaluate(near, human.gt_joints, human.joint_parents, **_kw(human)).recall == 1.0
    assert evaluate(far, human.gt_joints, human.joint_parents, threshold=1.0,
                    **_kw(human)).recall == 1.0


def _brute_force(cost: np.ndarray, tau: float) -> tuple[int, float]:
    P, J = cost.shape
    best = (0, 0.0)
    for k in range(min(P, J), 0, -1):
        for rows in itertools.permutations(range(P), k):
            for cols in itertools.combinations(range(J), k):
                c = cost[list(rows), list(cols)]
                if (c < tau).all():
                    tot = float(c.sum())
                    if k > best[0] or (k == best[0] and tot < best[1]):
                        best = (k, tot)
        if best[0] == k:
            return best
    return best


@pytest.mark.parametrize("seed", range(6))
def test_matching_is_optimal_against_brute_force(seed):
    rng = np.random.default_rng(seed)
    F, J, P = 3, 4, int(rng.integers(2, 5))
    g = rng.random((F, J, 3))
    p = rng.random((F, P, 3))
    rep = evaluate(p, g, np.full(J, -1), threshold=0.5)
    cost = np.linalg.norm(p[:, :, None] - g[:, None], axis=3).mean(0)
    k, tot = _brute_force(cost, 0.5)
    assert rep.n_matched == k
    got = sum(cost[r.matched, j] for j, r in enumerate(rep.rows) if r.matched >= 0)
    assert got == pytest.approx(tot, abs=1e-12)
    assert rep.raw_error == pytest.approx(tot / k if k else np.nan, nan_ok=True)


def _three_parts():
    """Five joints on hand-made parts: 0 root (static part), 1 rotates 40 deg about itself,
    2 is rigidly attached to 1 (no swing), 3 duplicates 1 (same place, same motion, child of 0),
    4 has no surface samples."""
    F = 10
    rng = np.random.default_rng(1)
    j1 = np.array([0.5, 0.0, 0.0])
    ang = np.radians(np.linspace(0, 40, F))
    R = rodrigues(np.array([0.0, 0.0, 1.0]), ang)  # (F, 3, 3)
    part0 = rng.random((50, 3)) * [0.5, 0.2, 0.2]
    part1 = j1 + rng.random((50, 3)) * [0.5, 0.1, 0.1]
    part2 = j1 + [0.5, 0, 0] + rng.random((30, 3)) * [0.2, 0.1, 0.1]
    part3 = j1 + rng.random((30, 3)) * [0.3, 0.05, 0.05]
    surf = np.zeros((F, 160, 3))
    surf[:, :50] = part0
    for k, part in ((1, part1), (2, part2), (3, part3)):
        lo = {1: 50, 2: 100, 3: 130}[k]
        surf[:, lo:lo + len(part)] = np.einsum("fij,mj->fmi", R, part - j1) + j1
    labels = np.repeat([0, 1, 2, 3], [50, 50, 30, 30])
    joints = np.zeros((F, 5, 3))
    joints[:, 1] = j1
    joints[:, 2] = np.einsum("fij,j->fi", R, [0.5, 0, 0]) + j1
    joints[:, 3] = j1
    joints[:, 4] = [0.2, 0.5, 0.0]
    parents = np.array([-1, 0, 1, 0, 0])
    return joints, parents, surf, labels


def test_scorable_rules():
    joints, parents, surf, labels = _three_parts()
    mask, reasons, swing = scorable_joints(joints, parents, surface=surf, surface_labels=labels,
                                           names=["a", "b", "c", "d", "e"])
    assert mask.tolist() == [True, True, False, False, False]
    assert reasons[2].startswith("static") and swing[2] < 1e-9
    assert reasons[3] == "duplicate of b"
    assert reasons[4] == "no skin"
    assert swing[1] > 0.1
    # without surface samples only the duplicate rule applies
    mask2, _, _ = scorable_joints(joints, parents)
    assert mask2.tolist() == [True, True, True, False, True]


def _lbs_chain(F: int = 12):
    """A 4-bone rig with LBS skin and its exact transforms ``T_frame_rest``.

    Bones: 0 root (moves in the world, no skin), 1 torso (skinned, rigid to 0), 2 upper arm
    (turns against 1 about the shoulder), 3 forearm (rigid to 2). The upper arm's samples are
    blended between bones 1 and 2 (smooth skinning, as in artist rigs); every other sample
    follows one bone. Returns joints (F, 4, 3), parents, surface (F, S, 3), labels (S,),
    R (F, 4, 3, 3), T (F, 4, 3), rest (S, 3).
    """
    rng = np.random.default_rng(3)
    shoulder, elbow = np.array([0.2, 0.5, 0.0]), np.array([0.5, 0.5, 0.0])
    torso = rng.uniform([-0.2, -0.5, -0.1], [0.2, 0.5, 0.1], (200, 3))
    upper = rng.uniform([0.2, 0.45, -0.05], [0.5, 0.55, 0.05], (80, 3))
    fore = rng.uniform([0.5, 0.45, -0.05], [0.8, 0.55, 0.05], (80, 3))
    rest = np.concatenate([torso, upper, fore])
    labels = np.repeat([1, 2, 3], [200, 80, 80])
    t = np.linspace(0.0, 1.0, F)
    R = np.zeros((F, 4, 3, 3))
    T = np.zeros((F, 4, 3))
    for f in range(F):
        Rw = rodrigues(np.array([0.0, 1.0, 0.0]), 0.4 * t[f])  # the root turns and walks
        Tw = np.array([0.3 * t[f], 0.0, 2.0])
        Ra = rodrigues(np.array([0.0, 0.0, 1.0]), 1.2 * np.sin(3 * t[f]))  # shoulder
        R[f, 0] = R[f, 1] = Rw
        T[f, 0] = T[f, 1] = Tw
        R[f, 2] = R[f, 3] = Rw @ Ra
        T[f, 2] = T[f, 3] = Rw @ (shoulder - Ra @ shoulder) + Tw
    # upper-arm samples: weight of bone 2 rises from 0.3 at the shoulder to 1 at the elbow
    w = np.zeros((len(rest), 4))
    w[labels == 1, 1] = w[labels == 3, 3] = 1.0
    a = 0.3 + 0.7 * (upper[:, 0] - 0.2) / 0.3
    w[labels == 2, 2], w[labels == 2, 1] = a, 1.0 - a
    surf = np.einsum("mb,fbij,mj->fmi", w, R, rest) + np.einsum("mb,fbi->fmi", w, T)
    joints = np.stack([np.einsum("fij,j->fi", R[:, b], p) + T[:, b] for b, p in
                       enumerate([np.zeros(3), np.zeros(3), shoulder, elbow])], axis=1)
    return joints, np.array([-1, 0, 1, 2]), surf, labels, R, T, rest


def test_articulation_from_bone_transforms():
    """The forearm never turns against the upper arm, but the upper arm's skin blends with the
    torso: the surface rule (Kabsch of the blended upper-arm samples) sees the forearm swing
    and scores its joint; the rig's transforms do not. The torso is rigid to the root, which
    moves in the world without skin: measured against the root bone it is static (the surface
    rule measures it against the world). Oracle: direct evaluation of the transforms."""
    joints, parents, surf, labels, R, T, rest = _lbs_chain()
    kw = dict(surface=surf, surface_labels=labels, names=["root", "torso", "upper", "fore"],
              skinned=np.array([False, True, True, True]))
    m_s, _, sw_s = scorable_joints(joints, parents, swing_source="surface", **kw)
    m_b, reasons, sw_b = scorable_joints(joints, parents, bone_rotations=R, bone_translations=T,
                                         rest_surface=rest, **kw)
    # "auto" picks the transforms when they are given
    assert np.array_equal(m_b, scorable_joints(joints, parents, bone_rotations=R,
                                               bone_translations=T, rest_surface=rest,
                                               swing_source="bones", **kw)[0])
    assert m_s.tolist() == [False, True, True, True]  # the flaw of the surface rule
    assert m_b.tolist() == [False, False, True, False]
    assert sw_b[3] < 1e-12 and sw_b[1] < 1e-12 and reasons[3].startswith("static")
    # the upper arm: its samples turned back through the torso's motion (rigid root + torso)
    q = rest[labels == 2]
    x = np.einsum("fij,mj->fmi", R[:, 2], q) + T[:, 2, None]
    back = np.stack([(x[f] - T[f, 1]) @ R[f, 1] for f in range(len(x))])
    expect = max(np.sqrt(((back[f] - back[0]) ** 2).sum(1).mean()) for f in range(len(x)))
    assert sw_b[2] == pytest.approx(expect, rel=1e-12)
    assert expect > 0.05


def test_articulation_from_scaled_bone_matrices():
    """Bone matrices that carry scale (squash and stretch): a child rigid to its scaled parent
    does not swing (the parent's motion is inverted exactly, not transposed)."""
    joints, parents, surf, labels, R, T, rest = _lbs_chain()
    scale = 1.0 + 0.2 * np.sin(np.linspace(0.0, 3.0, len(R)))
    R = R.copy()
    R[:, 2:] *= scale[:, None, None, None]  # upper arm and forearm: the same scaled matrix
    _, _, sw = scorable_joints(joints, parents, surface=surf, surface_labels=labels,
                               bone_rotations=R, bone_translations=T, rest_surface=rest,
                               skinned=np.array([False, True, True, True]))
    assert sw[3] < 1e-12


def test_articulation_in_metres_whatever_the_rest_units():
    """A rig bound in centimetres (rest samples 100x, bone matrices carrying 0.01): the same
    world motion, so the same swings, in metres."""
    joints, parents, surf, labels, R, T, rest = _lbs_chain()
    kw = {"surface": surf, "surface_labels": labels, "bone_translations": T,
          "skinned": np.array([False, True, True, True])}
    _, _, sw = scorable_joints(joints, parents, bone_rotations=R, rest_surface=rest, **kw)
    _, _, sw_cm = scorable_joints(joints, parents, bone_rotations=R / 100.0,
                                  rest_surface=rest * 100.0, **kw)
    assert np.nanmax(sw) > 0.01
    np.testing.assert_allclose(sw_cm, sw, rtol=1e-9, atol=1e-12)


def test_articulation_through_an_unskinned_bone():
    """A skinned child rigid to an unskinned bone that turns against a skinned grandparent
    articulates (against the grandparent)."""
    joints, parents, surf, labels, R, T, rest = _lbs_chain()
    # bone 2 loses its skin: its samples go to bone 3, which is rigid to 2
    labels = np.where(labels == 2, 3, labels)
    kw = dict(surface=surf, surface_labels=labels, skinned=np.array([False, True, False, True]))
    mask, _, sw = scorable_joints(joints, parents, bone_rotations=R, bone_translations=T,
                                  rest_surface=rest, **kw)
    assert mask.tolist() == [False, False, False, True] and sw[3] > 0.05


def test_pivot_errors_of_joints_at_their_turning_points():
    """The upper arm turns against the torso about the shoulder's hinge axis, where its joint
    lies; the forearm is rigid to the upper arm (no relative motion: its own rest position).
    Both pivot errors vanish; roots and parts without samples read nan."""
    joints, parents, _surf, labels, R, T, _rest = _lbs_chain()
    pe = pivot_errors(joints, parents, R, T, labels)
    assert np.isnan(pe[0])
    assert pe[2] < 1e-9 and pe[3] < 1e-9


def test_pivot_error_of_a_joint_held_off_its_turning_point():
    """The upper arm loses its skin: the forearm (skinned) hangs from it and turns against the
    torso about the shoulder's hinge axis (z through the shoulder), while its joint is the
    elbow, 0.3 m from that axis. Closed form: a joint at the pivot (the point of the axis
    nearest the elbow, the shoulder) is 0.3 m from the elbow in every frame. The report flags
    the joint as off pivot when the threshold is below that."""
    joints, parents, surf, labels, R, T, rest = _lbs_chain()
    labels = np.where(labels == 2, 3, labels)
    pe = pivot_errors(joints, parents, R, T, labels)
    assert pe[3] == pytest.approx(0.3, abs=1e-9)
    names = ["root", "torso", "upper", "fore"]
    kw = dict(gt_names=names, surface=surf, surface_labels=labels, bone_rotations=R,
              bone_translations=T, rest_surface=rest,
              skinned=np.array([False, True, False, True]))
    rep = evaluate(joints[:, [3]], joints, parents, threshold=0.2, **kw)
    assert rep.n_scorable == 1 and rep.n_off_pivot == 1 and rep.recall == 1.0
    assert rep.rows[3].pivot_error == pytest.approx(0.3, abs=1e-9)
    assert "off pivot (30.0 cm)" in rep.format_table()
    assert rep.to_dict()["n_off_pivot"] == 1
    assert evaluate(joints[:, [3]], joints, parents, threshold=0.35, **kw).n_off_pivot == 0


def test_pivot_error_of_a_sliding_joint():
    """A forearm animated by translation along the upper arm (no relative turn): the best
    joint moves half with each part, so its error is half the slide, mean over frames."""
    joints, parents, _surf, labels, R, T, _rest = _lbs_chain()
    F = len(R)
    slide = 0.4 * np.sin(np.linspace(0.0, 3.0, F))
    d = np.einsum("fij,j->fi", R[:, 2], np.array([1.0, 0.0, 0.0])) * slide[:, None]
    T = T.copy()
    T[:, 3] += d
    joints = joints.copy()
    joints[:, 3] += d
    pe = pivot_errors(joints, parents, R, T, labels)
    assert pe[3] == pytest.approx(0.5 * np.abs(slide).mean(), rel=1e-6)
    assert pe[2] < 1e-9


def test_swing_source_errors(tmp_path):
    joints, parents, surf, labels, R, T, rest = _lbs_chain()
    with pytest.raises(ConfigError, match="swing_source"):
        scorable_joints(joints, parents, surface=surf, surface_labels=labels,
                        swing_source="skin")
    with pytest.raises(InputError, match="bone_rotations"):
        scorable_joints(joints, parents, surface=surf, surface_labels=labels,
                        swing_source="bones")
    with pytest.raises(InputError, match=r"gt\.npz.*do not match 12 frames"):
        evaluate(joints, joints, parents, surface=surf, surface_labels=labels,
                 bone_rotations=R[:5], bone_translations=T, rest_surface=rest,
                 gt_source=tmp_path / "gt.npz")


def test_static_figure_joints_are_not_scored():
    seq = synthesize("arm", n_frames=8, amplitude=0.0, noise=NoiseConfig.clean(),
                     camera=Camera.kinect(320))
    mask, reasons, _ = scorable_joints(seq.gt_joints, seq.joint_parents, surface=seq.surface,
                                       surface_labels=seq.surface_labels)
    assert mask.tolist() == [True, False, False]  # root only: nothing articulates


def test_malformed_predictions(tmp_path, human):
    g = human.gt_joints
    with pytest.raises(InputError, match="shape"):
        evaluate(g[:, :, :2], g, human.joint_parents)
    bad = g.copy()
    bad[3, 2, 1] = np.nan
    with pytest.raises(InputError, match="NaN"):
        evaluate(bad, g, human.joint_parents)
    with pytest.raises(InputError, match="frames"):
        evaluate(g[:5], g, human.joint_parents, pred_source="pred.json")
    p = tmp_path / "skeleton.json"
    p.write_text("{not json")
    with pytest.raises(InputError, match="skeleton.json"):
        load_prediction(p)
    p.write_text(json.dumps({"format": "something/else"}))
    with pytest.raises(InputError, match="skeleton.json.*format"):
        load_prediction(p)
    p.write_text(json.dumps({"format": "pointrig.skeleton/1", "joints": [
        {"name": "a", "parent": -1, "rest_position": [0, 0, 0]}],
        "joint_positions": [[[0, 0]]]}))
    with pytest.raises(InputError, match="skeleton.json"):
        load_prediction(p)
    npz = tmp_path / "pred.npz"
    np.savez(npz, other=np.zeros(3))
    with pytest.raises(InputError, match="pred.npz"):
        load_prediction(npz)
    with pytest.raises(InputError, match="not found"):
        load_prediction(tmp_path / "none.json")


def test_files_and_cli(tmp_path, capsys):
    seq = synthesize("arm", n_frames=12, seed=3, camera=Camera.kinect(320),
                     noise=NoiseConfig(seed=2))
    out = seq.write(tmp_path / "arm")
    J = len(seq.joint_names)
    sk = Skeleton(list(seq.joint_names), seq.joint_parents, seq.gt_joints[0],
                  seq.gt_joints + 0.02, seq.joint_parents[1:],
                  np.arange(1, J))
    sk.save_json(tmp_path / "skeleton.json")
    rep = evaluate_files(tmp_path / "skeleton.json", out)
    assert rep.recall == 1.0 and rep.raw_error == pytest.approx(np.sqrt(3) * 0.02, abs=1e-5)
    # frame selection as in `pointrig extract --stride 2`
    sk2 = Skeleton(list(seq.joint_names), seq.joint_parents, seq.gt_joints[0],
                   seq.gt_joints[::2], sk.bone_heads, sk.bone_tails)
    sk2.save_json(tmp_path / "s2.json")
    assert evaluate_files(tmp_path / "s2.json", out, stride=2).raw_error < 1e-5
    assert main(["evaluate", str(tmp_path / "skeleton.json"), str(out), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["recall"] == 1.0 and len(doc["joints"]) == J
    assert doc["swing_source"] == "bones"  # gt.npz carries the bone transforms
    assert main(["evaluate", str(tmp_path / "skeleton.json"), str(out), "--json",
                 "--swing-source", "surface"]) == 0
    assert json.loads(capsys.readouterr().out)["swing_source"] == "surface"
    assert main(["evaluate", str(tmp_path / "skeleton.json"), str(out)]) == 0
    assert "normalised error" in capsys.readouterr().out
    assert main(["evaluate", str(tmp_path / "s2.json"), str(out)]) == 1
    assert "s2.json" in capsys.readouterr().err


def test_cli_synth_and_preview(tmp_path, capsys):
    out = tmp_path / "seq"
    png = tmp_path / "p.png"
    assert main(["synth", "snake", "-o", str(out), "--frames", "3", "--resolution", "320",
                 "--preview", str(png)]) == 0
    assert (out / "gt.npz").exists() and len(list((out / "frames").glob("*.ply"))) == 3
    from PIL import Image

    with Image.open(png) as im:
        arr = np.asarray(im)
    assert arr.shape[0] >= 240 and (arr.std(axis=(0, 1)) > 0).all()
    assert main(["preview", str(out), "--frame", "2", "-o", str(tmp_path / "q.png")]) == 0
    assert main(["preview", str(out), "--frame", "7", "-o", str(tmp_path / "r.png")]) == 1
    assert main(["synth", "unicorn", "-o", str(out)]) == 1
    assert "unknown source" in capsys.readouterr().err


def test_match_pairs_against_brute_force() -> None:
    """The evaluation's matching on random small cost matrices equals the brute-force optimum:
    the most pairs under the threshold, then the least total cost among those."""
    rng = np.random.default_rng(3)
    for _ in range(200):
        P, J = rng.integers(1, 5, size=2)
        cost = rng.uniform(0.0, 1.0, size=(P, J))
        thr = float(rng.uniform(0.2, 0.9))
        best = (0, 0.0)
        for k in range(min(P, J) + 1):
            for rows in itertools.permutations(range(P), k):
                for cols in itertools.combinations(range(J), k):
                    c = cost[list(rows), list(cols)]
                    if np.all(c < thr) and (k, -c.sum()) > (best[0], -best[1]):
                        best = (k, float(c.sum()))
        got = match_pairs(cost, thr)
        assert len(got) == best[0]
        assert abs(sum(cost[a, b] for a, b in got) - best[1]) < 1e-9
        assert len({a for a, _ in got}) == len(got) == len({b for _, b in got})
    assert match_pairs(np.zeros((3, 0)), 1.0) == []


def test_far_joints_hand_built_case():
    # joints 0 and 1 carry skin (subject size 1 m: far at 10 cm), joint 2 does not; frame 1 is
    # frame 0 moved by 0.5 m along z
    g0 = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    shift = np.array([0.0, 0.0, 0.5])
    g = np.stack([g0, g0 + shift])
    pred = np.stack([
        np.array([g0[0] + [0.05, 0, 0], [0.5, 0.5, 0.0], g0[2] + [0, 0.09, 0],
                  g0[2] + [0.02, 0, 0]]),
        np.array([g0[0] + [0.05, 0, 0], [0.5, 0.5, 0.0], g0[2] + [0, 0.12, 0],
                  g0[2] + [0.02, 0, 0]]) + shift,
    ])
    rep = evaluate(pred, g, np.array([-1, 0, 0]), skinned=np.array([True, True, False]))
    assert rep.subject_size == pytest.approx(1.0)
    assert rep.far_distance == pytest.approx(0.1)
    # p1 is 0.71 m from every joint; p2 is 9 then 12 cm from joint 2 (mean 10.5 cm, far
    # although one frame is nearer); p3 sits by the unscored joint 2: near
    assert rep.far.tolist() == [False, True, True, False]
    assert rep.n_far == 2 and rep.far_fraction == pytest.approx(0.5)
    assert rep.to_dict()["far_fraction"] == pytest.approx(0.5)
    assert "far joints 2/4" in rep.format_table()
    # the fraction of the size is a parameter
    assert evaluate(pred, g, np.array([-1, 0, 0]), skinned=np.array([True, True, False]),
                    far_fraction=0.2).far.tolist() == [False, True, False, False]


def test_duplicates_and_near_misses_hand_built_case():
    # three skinned joints, threshold 10 cm (near miss below 15 cm); two static frames
    g0 = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    p0 = np.array([g0[0] + [0.02, 0, 0],   # matches joint 0
                   g0[0] + [0, 0.05, 0],   # a second joint at joint 0: a duplicate
                   g0[1] + [0, 0.12, 0],   # 12 cm from joint 1: joint 1 is a near miss
                   g0[2] + [0, 0.5, 0]])   # 50 cm from joint 2: joint 2 is simply missed
    rep = evaluate(np.stack([p0, p0]), np.stack([g0, g0]), np.array([-1, 0, 0]),
                   skinned=np.ones(3, dtype=bool), threshold=0.1)
    assert rep.n_matched == 1 and [r.matched for r in rep.rows] == [0, -1, -1]
    assert rep.duplicate.tolist() == [False, True, False, False]
    assert rep.near_miss.tolist() == [False, True, False]
    assert rep.n_duplicate == 1 and rep.n_near_miss == 1
    assert rep.to_dict()["n_near_miss"] == 1
    assert "duplicates 1   near misses 1" in rep.format_table()
    # the factor is a parameter: at 1.1 x the threshold joint 1 is not a near miss
    assert evaluate(np.stack([p0, p0]), np.stack([g0, g0]), np.array([-1, 0, 0]),
                    skinned=np.ones(3, dtype=bool), threshold=0.1,
                    near_miss_factor=1.1).n_near_miss == 0
    # a joint 12 cm from a matched joint and nothing else near it: not a near miss (the
    # prediction there is the other joint's); with a free prediction at 13 cm it is one
    g1 = np.array([[0.0, 0.0, 0.0], [0.12, 0.0, 0.0]])
    skinned = np.ones(2, dtype=bool)
    lone = evaluate(np.stack([g1[:1], g1[:1]]), np.stack([g1, g1]), np.array([-1, 0]),
                    skinned=skinned, threshold=0.1)
    assert [r.matched for r in lone.rows] == [0, -1] and lone.n_near_miss == 0
    p1 = np.array([g1[0], g1[1] + [0, 0.13, 0]])
    free = evaluate(np.stack([p1, p1]), np.stack([g1, g1]), np.array([-1, 0]),
                    skinned=skinned, threshold=0.1)
    assert free.near_miss.tolist() == [False, True]
    # an unmatched prediction 14 cm from joint 1 but 2 cm from joint 0 (a duplicate of joint 0)
    # is not joint 1's
    p2 = np.array([g1[0], g1[0] - [0.02, 0, 0]])
    dup = evaluate(np.stack([p2, p2]), np.stack([g1, g1]), np.array([-1, 0]),
                   skinned=skinned, threshold=0.1)
    assert dup.n_duplicate == 1 and dup.n_near_miss == 0


def test_far_joints_against_brute_force():
    rng = np.random.default_rng(3)
    pred = rng.normal(size=(4, 7, 3))
    gt = rng.normal(size=(4, 5, 3))
    nearest = np.array([min(np.mean([np.linalg.norm(pred[t, p] - gt[t, j]) for t in range(4)])
                            for j in range(5)) for p in range(7)])
    cut = float(np.median(nearest))  # some far, some not
    far = far_joints(pred, gt, cut)
    assert far.tolist() == (nearest >= cut).tolist()
    assert 0 < far.sum() < 7
    assert far_joints(pred[:, :0], gt, 0.1).shape == (0,)
