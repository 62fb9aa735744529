"""benchmarks/bench_pivots.py's row against closed forms on a three-bone hinge rig."""

from __future__ import annotations

import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from bench_pivots import pivot_row  # noqa: E402

from pointrig.synth.figures import rodrigues  # noqa: E402


def _hinge_rig(arm_skinned: bool, F: int = 16) -> SimpleNamespace:
    """Bones: 0 body (skinned, static at 2 m), 1 arm turning against it about the z axis
    through the shoulder (0.2, 0, 2), 2 hand rigid to the arm, its joint 0.4 m out along x.
    With ``arm_skinned`` False the arm has no samples: the hand hangs from a skinless bone
    and its joint lies 0.4 m from where it turns against the body."""
    rng = np.random.default_rng(1)
    shoulder, wrist = np.array([0.2, 0.0, 2.0]), np.array([0.6, 0.0, 2.0])
    body = rng.uniform([-0.2, -0.5, 1.9], [0.2, 0.5, 2.1], (300, 3))
    arm = rng.uniform([0.2, -0.05, 1.95], [0.6, 0.05, 2.05], (60, 3))
    hand = rng.uniform([0.6, -0.05, 1.95], [0.8, 0.05, 2.05], (40, 3))
    rest = np.concatenate([body, arm, hand])
    labels = np.repeat([0, 1 if arm_skinned else 2, 2], [300, 60, 40])
    R = np.tile(np.eye(3), (F, 3, 1, 1))
    T = np.zeros((F, 3, 3))
    for f in range(F):
        Ra = rodrigues(np.array([0.0, 0.0, 1.0]), 0.8 * np.sin(0.4 * f))
        R[f, 1] = R[f, 2] = Ra
        T[f, 1] = T[f, 2] = shoulder - Ra @ shoulder
    bone = np.where(labels == 0, 0, np.where(np.arange(len(rest)) < 360, 1, 2))
    surface = np.einsum("fmij,mj->fmi", R[:, bone], rest) + T[:, bone]
    heads = np.stack([np.zeros(3), shoulder, wrist])
    joints = np.einsum("fbij,bj->fbi", R, heads) + T
    kw = {"gt_names": ["body", "arm", "hand"], "skinned": np.array([True, arm_skinned, True]),
          "surface": surface, "surface_labels": labels, "bone_rotations": R,
          "bone_translations": T, "rest_surface": rest}
    return SimpleNamespace(gt_joints=joints, joint_parents=np.array([-1, 0, 1]),
                           eval_kwargs=lambda: kw)


def test_joints_at_their_turning_points_are_on_pivot() -> None:
    row = pivot_row(_hinge_rig(arm_skinned=True))
    assert row["n_scorable"] == 2 and row["off"] == []


def test_a_hand_hung_from_a_skinless_arm_is_off_pivot() -> None:
    """The hand turns about the shoulder's axis; its joint is 0.4 m from it (closed form).
    A prediction of the true joints matches it (recall 1) and no on-pivot joint is left (the
    root is matched by the first predicted joint)."""
    syn = _hinge_rig(arm_skinned=False)
    row = pivot_row(syn)
    assert [n for n, _ in row["off"]] == ["hand"]
    assert abs(row["off"][0][1] - 0.4) < 1e-9
    scored = pivot_row(syn, syn.gt_joints)
    assert scored["recall"] == 1.0 and scored["recall_on"] == 1.0
    # a prediction with the hand at the shoulder (its turning point): recall 1/2, on pivot 1
    P = syn.gt_joints[:, [0, 1]].copy()
    at_pivot = pivot_row(syn, P)
    assert at_pivot["recall"] == 0.5 and at_pivot["recall_on"] == 1.0
