"""benchmarks/bench_slide.py: the along/across split of the registration's offsets against
closed forms."""

from __future__ import annotations

import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from bench_slide import axial_offsets, bone_slides  # noqa: E402


def _frame(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors perpendicular to ``axis (3,)`` and to each other."""
    a = axis / np.linalg.norm(axis)
    p = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
    p /= np.linalg.norm(p)
    return p, np.cross(a, p)


def test_axial_offsets_split_a_known_slide_from_a_known_sideways_move() -> None:
    """Points moved by ``s_t`` along a turning axis and by a fixed 2 cm across it, in a
    direction that turns about the axis from point to point: along = s_t exactly, across =
    0.02 exactly, whatever the axis length."""
    rng = np.random.default_rng(3)
    F, n = 7, 40
    truth = rng.normal(size=(F, n, 3))
    head = rng.normal(size=(F, 3))
    dirs = rng.normal(size=(F, 3))
    tail = head + dirs * rng.uniform(0.2, 3.0, size=(F, 1))
    s = rng.normal(scale=0.1, size=F)
    pts = np.empty_like(truth)
    for t in range(F):
        a = dirs[t] / np.linalg.norm(dirs[t])
        p, q = _frame(a)
        phi = rng.uniform(0, 2 * np.pi, size=n)
        side = 0.02 * (np.cos(phi)[:, None] * p + np.sin(phi)[:, None] * q)
        pts[t] = truth[t] + s[t] * a + side
    along, across = axial_offsets(pts, truth, head, tail)
    np.testing.assert_allclose(along, s, atol=1e-12)
    np.testing.assert_allclose(across, 0.02, atol=1e-12)
    # the sign follows the axis: swapping head and tail flips it
    np.testing.assert_allclose(axial_offsets(pts, truth, tail, head)[0], -s, atol=1e-12)


def test_bone_slides_reports_the_bones_with_one_child_and_their_slide() -> None:
    """A three-joint chain (root -> knee -> ankle) with a 'shin' of samples on the knee-ankle
    segment: registered points = the exact ones moved 5 cm towards the knee in every frame. The
    shin reads -0.05 along, 0 across; the root (one child, no displaced points) reads 0; the
    ankle (no child) is left out."""
    F = 5
    t = np.linspace(0.05, 0.95, 30)  # the two segments' samples stay apart at the knee
    knee, ankle = np.array([0.0, 0.0, 2.0]), np.array([0.0, 0.4, 2.0])
    root = np.array([0.0, -0.4, 2.0])
    shin = knee + t[:, None] * (ankle - knee) + np.array([0.03, 0.0, 0.0])
    thigh = root + t[:, None] * (knee - root) + np.array([0.03, 0.0, 0.0])
    rest_surface = np.concatenate([thigh, shin])
    labels = np.array([0] * 30 + [1] * 30)
    shift = np.linspace(0.0, 0.1, F)[:, None]  # the whole figure drifts in x over the frames
    surface = rest_surface[None] + np.array([1.0, 0.0, 0.0]) * shift[..., None]
    gt = np.stack([root, knee, ankle])[None] + np.array([1.0, 0.0, 0.0]) * shift[..., None]
    syn = SimpleNamespace(surface=surface, surface_labels=labels, joint_names=["root", "knee",
                          "ankle"], joint_parents=np.array([-1, 0, 1]), gt_joints=gt)
    registered = surface.copy()
    registered[:, 30:] += np.array([0.0, -0.05, 0.0])  # 5 cm up the shin, towards the knee
    rows = {name: (n, al, ac) for name, n, al, ac in
            bone_slides(rest_surface, registered, syn, rest_index=2)}
    assert set(rows) == {"root", "knee"}
    n, al, ac = rows["knee"]
    assert n == 30
    np.testing.assert_allclose(al, -0.05, atol=1e-12)
    np.testing.assert_allclose(ac, 0.0, atol=1e-12)
    np.testing.assert_allclose(rows["root"][1], 0.0, atol=1e-12)
