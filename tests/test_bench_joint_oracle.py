"""The joint-placement oracle of benchmarks/bench_joint_oracle.py against closed forms."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from bench_joint_oracle import joint_maps, oracle_rest_position  # noqa: E402

from pointrig.evaluate import pair_errors  # noqa: E402
from pointrig.kinematics import joint_trajectories  # noqa: E402


def normalised_error(q: np.ndarray, g: np.ndarray) -> float:
    return pair_errors(q, g)[1]


def _motions(rng: np.random.Generator, F: int, B: int) -> tuple[np.ndarray, np.ndarray]:
    R = Rotation.random(F * B, random_state=rng.integers(1 << 31)).as_matrix().reshape(F, B, 3, 3)
    T = rng.normal(size=(F, B, 3))
    return R, T


def test_joint_maps_reproduce_the_output_trajectories() -> None:
    rng = np.random.default_rng(0)
    parent = np.array([-1, 0, 1, 1, 0])
    R, T = _motions(rng, 7, 5)
    c = rng.normal(size=(5, 3))
    A, b = joint_maps(R, T, parent)
    np.testing.assert_allclose(np.einsum("fkij,kj->fki", A, c) + b,
                               joint_trajectories(c, R, T, parent), atol=1e-12)


def test_oracle_recovers_a_point_carried_by_the_motion() -> None:
    """g_t = A_t c + b_t + a constant offset: the oracle returns c and a zero error."""
    rng = np.random.default_rng(1)
    R, T = _motions(rng, 30, 1)
    A, b = R[:, 0], T[:, 0]
    c = np.array([0.1, -0.3, 0.25])
    g = np.einsum("fij,j->fi", A, c) + b + np.array([0.05, 0.0, -0.02])
    c_star = oracle_rest_position(A, b, g)
    np.testing.assert_allclose(c_star, c, atol=1e-10)
    assert normalised_error(np.einsum("fij,j->fi", A, c_star) + b, g) < 1e-10


def test_oracle_is_the_least_squares_minimum() -> None:
    """On noisy targets no other rest position scores a lower squared centred error."""
    rng = np.random.default_rng(2)
    R, T = _motions(rng, 40, 1)
    A, b = R[:, 0], T[:, 0]
    g = np.einsum("fij,j->fi", A, np.array([0.2, 0.1, 0.0])) + b + 0.05 * rng.normal(size=(40, 3))

    def sq(c: np.ndarray) -> float:
        e = np.einsum("fij,j->fi", A, c) + b - g
        return float(((e - e.mean(0)) ** 2).sum())

    c_star = oracle_rest_position(A, b, g)
    for _ in range(50):
        assert sq(c_star) <= sq(c_star + 0.01 * rng.normal(size=3)) + 1e-12


def test_oracle_moves_the_start_only_where_the_motion_determines_it() -> None:
    """A joint that only turns about z: its z coordinate stays at the start's."""
    rng = np.random.default_rng(3)
    ang = rng.uniform(-1.0, 1.0, size=25)
    A = Rotation.from_rotvec(np.outer(ang, [0.0, 0.0, 1.0])).as_matrix()
    b = rng.normal(size=(25, 3)) * 0.01
    c = np.array([0.3, -0.2, 0.7])
    g = np.einsum("fij,j->fi", A, c) + b
    start = np.array([0.0, 0.0, -0.4])
    c_star = oracle_rest_position(A, b, g, start)
    np.testing.assert_allclose(c_star[:2], c[:2], atol=1e-10)
    assert abs(c_star[2] - start[2]) < 1e-10


def test_min_turn_leaves_weakly_determined_directions_at_the_start() -> None:
    """Turning up to 15 deg about z and 0.2 deg about x: with min_turn 0.05 rad only x, y
    move."""
    rng = np.random.default_rng(4)
    F = 40
    rv = np.zeros((F, 3))
    rv[:, 2] = rng.uniform(-0.26, 0.26, F)
    rv[:, 0] = rng.uniform(-0.004, 0.004, F)
    A = Rotation.from_rotvec(rv).as_matrix()
    b = np.zeros((F, 3))
    c = np.array([0.2, 0.1, 0.3])
    g = np.einsum("fij,j->fi", A, c)
    start = np.zeros(3)
    exact = oracle_rest_position(A, b, g, start)
    np.testing.assert_allclose(exact, c, atol=1e-8)
    trunc = oracle_rest_position(A, b, g, start, min_turn=0.05)
    np.testing.assert_allclose(trunc[:2], c[:2], atol=1e-3)
    assert abs(trunc[2]) < 1e-3
