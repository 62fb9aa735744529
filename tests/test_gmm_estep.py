"""E-step sufficient statistics (Eq. 4) of the Rust kernel against a numpy oracle."""

from __future__ import annotations

import numpy as np
import pytest

from pointrig import _core


def oracle(y: np.ndarray, x: np.ndarray, sigma2: float, omega: float, cutoff: float | None = None):
    """Dense posterior matrix of Eq. 4 (M, N) and its statistics, in float64 numpy."""
    m, n = len(y), len(x)
    d2 = ((y[:, None, :] - x[None, :, :]) ** 2).sum(-1)
    e = np.exp(-d2 / (2 * sigma2))
    if cutoff is not None:
        e = np.where(d2 < (cutoff**2) * sigma2, e, 0.0)
    c0 = (2 * np.pi * sigma2) ** 1.5 * omega * m / ((1 - omega) * n)
    den = e.sum(0) + c0
    p = e / den
    nll = -np.sum(np.log((1 - omega) / m * (2 * np.pi * sigma2) ** -1.5 * e.sum(0) + omega / n))
    return p, {
        "P1": p.sum(1),
        "Pt1": p.sum(0),
        "PX": p @ x,
        "n_p": p.sum(),
        "sum_sq": (p * d2).sum(),
        "sum_x2": (p.sum(0) * (x**2).sum(1)).sum(),
        "nll": nll,
        "e_gmm": (p * d2).sum() / (2 * sigma2) + 1.5 * p.sum() * np.log(sigma2),
    }


def clouds(seed: int, m: int = 400, n: int = 900, offset: float = 2.0):
    rng = np.random.default_rng(seed)
    y = rng.uniform(-0.3, 0.3, size=(m, 3)) + offset
    x = y[rng.integers(0, m, n)] + rng.normal(scale=0.01, size=(n, 3))
    x[: n // 10] = rng.uniform(-0.5, 0.5, size=(n // 10, 3)) + offset  # outliers
    return y, x


@pytest.mark.parametrize("sigma2,omega", [(6e-4, 0.01), (1e-4, 0.1), (0.05, 0.0), (2e-5, 0.5)])
def test_dense_matches_numpy_oracle(sigma2: float, omega: float) -> None:
    y, x = clouds(1)
    p1, pt1, px, st = _core.gmm_estep(y, x, sigma2, omega)
    _, ref = oracle(y, x, sigma2, omega)
    np.testing.assert_allclose(p1, ref["P1"], rtol=0, atol=1e-10)
    np.testing.assert_allclose(pt1, ref["Pt1"], rtol=0, atol=1e-10)
    np.testing.assert_allclose(px, ref["PX"], rtol=0, atol=1e-10)
    for key in ("n_p", "sum_sq", "sum_x2", "nll", "e_gmm"):
        assert st[key] == pytest.approx(ref[key], rel=1e-10, abs=1e-10), key
    assert st["n_pairs"] == len(y) * len(x)
    assert st["trunc_bound"] == 0.0


def test_truncated_equals_oracle_with_same_cutoff_and_is_within_bound() -> None:
    y, x = clouds(2)
    sigma2, omega, c = 2e-4, 0.01, 3.0
    p1, pt1, px, st = _core.gmm_estep(y, x, sigma2, omega, cutoff=c)
    # Exactly the cut-off oracle (same semantics: pairs with |x - y| >= c sigma dropped).
    _, cut = oracle(y, x, sigma2, omega, cutoff=c)
    np.testing.assert_allclose(p1, cut["P1"], atol=1e-10)
    np.testing.assert_allclose(px, cut["PX"], atol=1e-10)
    # And within its a-posteriori bound of the dense E-step.
    pd, dense = oracle(y, x, sigma2, omega)
    pc, _ = oracle(y, x, sigma2, omega, cutoff=c)
    l1 = np.abs(pd - pc).sum()
    assert l1 <= st["trunc_bound"] + 1e-12
    assert np.abs(p1 - dense["P1"]).sum() <= st["trunc_bound"] + 1e-12
    assert np.abs(pt1 - dense["Pt1"]).sum() <= st["trunc_bound"] + 1e-12
    assert abs(st["n_p"] - dense["n_p"]) <= st["trunc_bound"] + 1e-12
    assert np.abs(px - dense["PX"]).max() <= st["trunc_bound"] * np.abs(x).max() + 1e-12
    assert abs(st["sum_sq"] - dense["sum_sq"]) <= c**2 * sigma2 * st["trunc_bound"] + 1e-12
    assert st["n_pairs"] < len(y) * len(x)


def test_truncated_bound_is_tight_enough_to_be_useful() -> None:
    # Without isolated outliers (an outlier with no template point within c sigma gets the
    # trivial per-point bound 2: its posterior is then dominated by the unseen far pairs).
    y, x = clouds(3)
    x = x[len(x) // 10 :]
    sigma2 = 1e-4
    _, _, _, st = _core.gmm_estep(y, x, sigma2, 0.01, cutoff=6.0)
    pd, _ = oracle(y, x, sigma2, 0.01)
    pc, _ = oracle(y, x, sigma2, 0.01, cutoff=6.0)
    assert np.abs(pd - pc).sum() <= st["trunc_bound"] < 1e-3 * len(x)


def test_single_precision_close_and_thread_independent() -> None:
    y, x = clouds(4)
    p1, pt1, px, st = _core.gmm_estep(y, x, 6e-4, 0.01)
    q1, qt1, qx, sq = _core.gmm_estep(y, x, 6e-4, 0.01, single=True)
    np.testing.assert_allclose(q1, p1, atol=2e-5 * max(1.0, p1.max()))
    np.testing.assert_allclose(qx, px, atol=1e-4)
    assert sq["n_p"] == pytest.approx(st["n_p"], rel=1e-5)


def test_rejects_bad_arguments() -> None:
    y, x = clouds(5, 10, 10)
    with pytest.raises(ValueError):
        _core.gmm_estep(y, x, -1.0, 0.01)
    with pytest.raises(ValueError):
        _core.gmm_estep(y, x, 1e-3, 1.0)
    with pytest.raises(ValueError):
        _core.gmm_estep(y[:, :2].copy(), x, 1e-3, 0.01)
    bad = x.copy()
    bad[0, 0] = np.nan
    from pointrig.errors import InputError

    with pytest.raises(InputError):
        _core.gmm_estep(y, bad, 1e-3, 0.01)
