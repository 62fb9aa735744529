"""Kabsch rotation-noise variance of the §5.4 merge test (closed form, correlated residuals)."""
import numpy as np

from pointrig.config import StructureConfig
from pointrig.structure import rotation_noise_var


def _oracle(q: np.ndarray, res_sum: float, F: int) -> float:
    qc = q - q.mean(0)
    J = np.trace(qc.T @ qc) * np.eye(3) - qc.T @ qc  # inertia tensor
    s2 = res_sum / (F * (3 * len(q) - 6))
    return s2 * np.trace(np.linalg.inv(J))


def test_rotation_noise_var_closed_form_and_correlation_exponent():
    rng = np.random.default_rng(3)
    Q = np.concatenate([rng.normal(size=(40, 3)) * [0.1, 0.03, 0.02],
                        rng.normal(size=(90, 3)) * 0.05 + 1.0])
    labels = np.repeat([0, 1], [40, 90])
    own = rng.uniform(1e-5, 3e-5, size=len(Q))
    F = 7
    ref = np.array([_oracle(Q[labels == b], own[labels == b].sum(), F) for b in (0, 1)])
    np.testing.assert_allclose(rotation_noise_var(Q, labels, own, 2, F), ref, rtol=1e-10)
    # correlated residuals: only n^(1-a) points are independent -> variance times n^a
    for a in (0.5, 1.0):
        np.testing.assert_allclose(rotation_noise_var(Q, labels, own, 2, F, a),
                                   ref * np.array([40.0, 90.0]) ** a, rtol=1e-10)
    assert StructureConfig().noise_corr_exponent == 0.5  # default: correlated (drifting) residuals


def test_merge_stat_noise_discount_uses_the_chi3_quantile():
    from scipy.spatial.transform import Rotation
    from scipy.stats import chi

    from pointrig.structure import _merge_stat, relative_rotation_range

    rng = np.random.default_rng(5)
    F, B = 12, 3
    R = Rotation.from_rotvec(rng.normal(scale=0.3, size=(F * B, 3))).as_matrix().reshape(F, B, 3, 3)
    pairs = [(0, 1), (1, 2)]
    var = np.array([1e-3, 4e-3, 2e-3])
    got = _merge_stat(R, pairs, 90.0, var, margin=1.5)
    raw = np.percentile(relative_rotation_range(R, np.array(pairs)), 90.0, axis=1)
    noise = 1.5 * chi.ppf(0.9, 3) / np.sqrt(3.0) * np.sqrt(var[[0, 1]] + var[[1, 2]])
    np.testing.assert_allclose(got, np.degrees(np.sqrt(np.maximum(raw**2 - noise**2, 0))),
                               rtol=1e-12)
    assert np.all(got < np.degrees(raw))
