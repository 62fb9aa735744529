"""benchmarks/bench_fit_bias.py: the refinement from a given pose and the slide summary,
against the capsules' material points and a constructed chain."""

from __future__ import annotations

import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_fit_bias import refine_from, slide_summary  # noqa: E402
from bench_slide import nearest_samples  # noqa: E402
from bench_structure_oracle import exact_points  # noqa: E402
from registration_helpers import capsule_arm  # noqa: E402

from pointrig.config import RegistrationConfig  # noqa: E402
from pointrig.preprocess import rest_surface  # noqa: E402


def _chain() -> tuple[np.ndarray, SimpleNamespace]:
    """Root -> knee -> ankle, 30 samples on each segment, the figure drifting in x."""
    F = 4
    t = np.linspace(0.05, 0.95, 30)
    root, knee, ankle = (np.array([0.0, -0.4, 2.0]), np.array([0.0, 0.0, 2.0]),
                         np.array([0.0, 0.4, 2.0]))
    rest = np.concatenate([root + t[:, None] * (knee - root),
                           knee + t[:, None] * (ankle - knee)]) + np.array([0.03, 0.0, 0.0])
    shift = np.array([1.0, 0.0, 0.0]) * np.linspace(0.0, 0.1, F)[:, None, None]
    syn = SimpleNamespace(surface=rest[None] + shift, surface_labels=np.repeat([0, 1], 30),
                          joint_names=["root", "knee", "ankle"],
                          joint_parents=np.array([-1, 0, 1]),
                          gt_joints=np.stack([root, knee, ankle])[None] + shift)
    return rest, syn


def test_slide_summary_reads_a_known_slide_and_offset() -> None:
    """The shin's points moved 6 cm towards the knee in every frame, the thigh's left alone:
    correspondence = 3 cm (half the points 6 cm off), the point-weighted mean |along| 3 cm,
    the worst bone the knee's at 6.0/6.0 cm."""
    rest, syn = _chain()
    nn = nearest_samples(rest, syn, 1)
    moved = syn.surface.copy()
    moved[:, 30:] += np.array([0.0, -0.06, 0.0])
    corr, along, worst = slide_summary(rest, moved, syn, 1, nn)
    assert abs(corr - 0.03) < 1e-12 and abs(along - 0.03) < 1e-12
    assert worst == "knee 6.0/6.0"
    corr, along, _ = slide_summary(rest, syn.surface, syn, 1, nn)
    assert corr < 1e-12 and along < 1e-12


def test_refine_from_the_exact_pose_stays_and_from_a_shifted_one_comes_back() -> None:
    """On the bending capsule arm, the refinement started from the true motion of the rest
    points stays within 2 mm of it on average (0.3-0.7 mm measured); started from that motion
    shifted 3 cm across the arm in every frame but the rest frame, it comes back to within
    half of the shift (oracle: the capsules' material points)."""
    frames, truth = capsule_arm(6, 8.0, n=6000)
    cfg = RegistrationConfig(n_rest_points=800, n_nodes=60, mls_neighbors=0)
    r0 = 3
    rest = rest_surface(frames[r0], 800, mls_neighbors=0)
    exact = exact_points(rest, truth, r0)
    err = np.linalg.norm(refine_from(frames, rest, r0, exact, cfg) - exact, axis=2)
    assert err.mean() < 0.002, err.mean(axis=1)
    shifted = exact + np.array([0.0, 0.03, 0.0])
    shifted[r0] = exact[r0]
    back = np.linalg.norm(refine_from(frames, rest, r0, shifted, cfg) - exact, axis=2)
    others = [t for t in range(len(frames)) if t != r0]
    assert back[others].mean() < 0.015, back.mean(axis=1)
