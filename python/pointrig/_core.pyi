"""Type stubs for the private native module ``pointrig._core`` (hand-written).

All point arrays are float64, C-contiguous, shape ``(n, 3)``, metres. Functions raise
``ValueError`` on wrong shapes or non-contiguous input and
``pointrig.errors.InputError`` on NaN/inf values.
"""

import numpy as np
import numpy.typing as npt

__version__: str

def kabsch(
    src: npt.NDArray[np.float64],
    dst: npt.NDArray[np.float64],
    weights: npt.NDArray[np.float64] | None = None,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Weighted absolute orientation (Eq. 14, Lemma 1): ``R (3, 3)``, ``t (3,)`` with
    ``dst ~ src @ R.T + t``."""

def cluster_fit(
    rest: npt.NDArray[np.float64],
    points_seq: npt.NDArray[np.float64],
    labels: npt.NDArray[np.int64],
    n_clusters: int,
    weights: npt.NDArray[np.float64] | None = None,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.int64]]:
    """Per cluster and frame weighted Kabsch (Eq. 14) from ``rest (M, 3)`` to
    ``points_seq (F, M, 3)`` given ``labels (M,)`` int64 in ``[0, n_clusters)`` (negative =
    ignored): ``R (F, K, 3, 3)``, ``T (F, K, 3)``, ``counts (K,)``. Empty cluster: identity."""

def cluster_residuals(
    rest: npt.NDArray[np.float64],
    points_seq: npt.NDArray[np.float64],
    rotations: npt.NDArray[np.float64],
    translations: npt.NDArray[np.float64],
    candidates: npt.NDArray[np.int64],
) -> npt.NDArray[np.float64]:
    """``(M, C)`` residuals ``sum_t |y_m^t - (R_k^t q_m + T_k^t)|^2`` (m^2) for the candidate
    bones ``candidates (M, C)`` int64 (``-1`` -> ``inf``)."""

def swap_residuals(
    rest: npt.NDArray[np.float64],
    points_seq: npt.NDArray[np.float64],
    labels: npt.NDArray[np.int64],
    rotations: npt.NDArray[np.float64],
    translations: npt.NDArray[np.float64],
    pairs: npt.NDArray[np.int64],
) -> npt.NDArray[np.float64]:
    """``(P, 2)`` directed halves of the Eq. 15 edge weight for ``pairs (P, 2)``: mean over
    cluster i of its residual under bone j's transforms, and vice versa (m^2)."""
