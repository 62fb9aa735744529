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

def gmm_estep(
    y: npt.NDArray[np.float64],
    x: npt.NDArray[np.float64],
    sigma2: float,
    omega: float,
    cutoff: float | None = None,
    single: bool = False,
) -> tuple[
    npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64], dict[str, float]
]:
    """E-step of Eq. 4 as sufficient statistics, never forming the (M, N) matrix.

    ``y`` (M, 3) are the GMM centroids (template), ``x`` (N, 3) the data, metres;
    ``p_mi = e_mi / (sum_k e_ki + c0)`` with ``e_mi = exp(-|x_i - y_m|^2 / (2 sigma2))`` and
    ``c0 = (2 pi sigma2)^{3/2} omega M / ((1 - omega) N)``.

    Returns ``P1 (M,) = P 1``, ``Pt1 (N,) = P^T 1``, ``PX (M, 3) = P X`` (input coordinates),
    and ``stats``: ``n_p = sum p_mi`` (N_p of Eq. 5b); ``sum_sq = sum p_mi |x_i - y_m|^2``
    (numerator of Eq. 12, m^2); ``sum_x2 = sum_i Pt1_i |x_i|^2``; ``nll`` = Eq. 3 (negative
    log-likelihood of the mixture at y, sigma2); ``e_gmm`` = Eq. 5b at y
    (``sum_sq / (2 sigma2) + 1.5 n_p log sigma2``); ``trunc_bound``; ``n_pairs``.

    ``cutoff=None``: exact dense E-step (float64: ~1e-15 relative). ``cutoff=c``: only pairs
    with ``|x_i - y_m| < c * sqrt(sigma2)`` count (as if ``e_mi = 0`` beyond), and
    ``trunc_bound`` is an a-posteriori bound on ``sum_mi |p~_mi - p_mi|`` versus the dense
    E-step (hence on the L1 error of P1, Pt1, on |dN_p|; |dPX| <= bound * max|x|;
    |d sum_sq| <= c^2 sigma2 bound). ``single=True`` uses float32 inner loops (~1e-6
    relative), about 3x faster. Results are bitwise identical for any number of threads.
    Raises ValueError for sigma2 <= 0, omega outside [0, 1), cutoff <= 0 or bad shapes.
    """

class DeformGraph:
    """Embedded deformation graph (Eq. 2) with the M-step solvers of §4.3 and one-frame EM.

    ``rest (M, 3)``, ``nodes (J, 3)``, ``pn_idx (M, k) int64`` / ``pn_w (M, k)`` (nodes driving
    each point and weights, normalised per row), ``edges (E, 2) int64`` directed ``(j, k)``,
    ``k in N(n_j)`` for Eq. 6. Node transforms are ``R (J, 3, 3)``, ``T (J, 3)``.
    """

    n_nodes: int
    n_points: int
    n_edges: int

    def __init__(
        self,
        rest: npt.NDArray[np.float64],
        nodes: npt.NDArray[np.float64],
        pn_idx: npt.NDArray[np.int64],
        pn_w: npt.NDArray[np.float64],
        edges: npt.NDArray[np.int64],
    ) -> None: ...
    def deform(self, r: npt.NDArray[np.float64], t: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """Deformed points ``y'`` (M, 3), Eq. 2."""
    def energy(
        self, r: npt.NDArray[np.float64], t: npt.NDArray[np.float64],
        r_pre: npt.NDArray[np.float64], t_pre: npt.NDArray[np.float64],
        p1: npt.NDArray[np.float64], px: npt.NDArray[np.float64],
        sum_x2: float, n_p: float, sigma2: float, beta_smooth: float, beta_small: float,
    ) -> float:
        """Eq. 8a from E-step statistics (``gmm_estep``), E_small relative to ``(r_pre, t_pre)``."""
    def node_update(
        self, j: int, r: npt.NDArray[np.float64], t: npt.NDArray[np.float64],
        r_pre: npt.NDArray[np.float64], t_pre: npt.NDArray[np.float64],
        p1: npt.NDArray[np.float64], px: npt.NDArray[np.float64],
        sigma2: float, beta_smooth: float, beta_small: float,
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """Closed-form update of node ``j`` with the others fixed (Eqs. 9, 11): ``R_j, T_j``."""
    def gauss_newton_step(
        self, r: npt.NDArray[np.float64], t: npt.NDArray[np.float64],
        p1: npt.NDArray[np.float64], px: npt.NDArray[np.float64],
        sigma2: float, beta_smooth: float, beta_small: float,
        damping: float = 0.0, cg_tol: float = 1e-8, cg_max: int = 500,
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """One joint Gauss-Newton step on all nodes: new ``R, T``."""
    def register_frame(
        self, x: npt.NDArray[np.float64], r: npt.NDArray[np.float64], t: npt.NDArray[np.float64], *,
        sigma2_start: float, omega: float, beta_smooth: float, beta_relative: bool,
        beta_small: float, sigma2_min: float, anneal: float, anneal_floor: float,
        max_iter: int, tol: float, cutoff: float | None, single: bool, rigid_iters: int,
        solver: str, damping: float, cg_tol: float, cg_max: int,
    ) -> dict:
        """Algorithm 1 on one frame (see docs/registration.md): dict with ``R``, ``T``,
        ``points (M, 3)``, ``sigma2``, ``iterations``, ``energy``, ``n_p``, ``n_data``,
        ``history (iterations, 2)`` = (sigma^2, energy) per iteration."""
