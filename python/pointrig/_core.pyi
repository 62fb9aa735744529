"""Type stubs for the private native module ``pointrig._core`` (hand-written).

All point arrays are float64, C-contiguous, shape ``(n, 3)``, metres, with coordinates
within 1e12 m of the origin. Functions raise ``pointrig.errors.InputError`` (a ``ValueError``)
on wrong shapes or sizes, non-contiguous arrays, NaN/inf values or coordinates beyond that;
no input makes them panic or abort.
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
# --- step 3, LBS-based joint learning (§6.4); R is (F*B, 9) row-major, T (F*B, 3) ---
def lbs_skin(
    q: npt.NDArray[np.float64], idx: npt.NDArray[np.int64], w: npt.NDArray[np.float64],
    r: npt.NDArray[np.float64], t: npt.NDArray[np.float64], n_frames: int,
) -> npt.NDArray[np.float64]:
    """LBS (Eq. 13) of ``q (M, 3)`` with sparse weights ``idx, w (M, K)``: ``(F*M, 3)``."""
def lbs_fit_weights(
    q: npt.NDArray[np.float64], r: npt.NDArray[np.float64], t: npt.NDArray[np.float64],
    a: npt.NDArray[np.float64], z: npt.NDArray[np.float64], n_frames: int, k: int,
    allowed: npt.NDArray[np.bool_] | None = None,
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Eq. 22 on the reduced data term (weights ``a (F, M)``, targets ``z (F*M, 3)``): the k
    bones with the smallest residuals (among ``allowed (M, B)``), exact simplex QP.
    Returns ``idx (M, k)``, ``w (M, k)``, residual ``(M,)``."""
def lbs_sweep_paper(
    q: npt.NDArray[np.float64], idx: npt.NDArray[np.int64], w: npt.NDArray[np.float64],
    r: npt.NDArray[np.float64], t: npt.NDArray[np.float64], a: npt.NDArray[np.float64],
    z: npt.NDArray[np.float64], r_pre: npt.NDArray[np.float64], t_pre: npt.NDArray[np.float64],
    bone_parent: npt.NDArray[np.int64], joints: npt.NDArray[np.float64], alpha: float,
    gamma: float, n_frames: int,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """One sweep of Eqs. 23-26 over the bones of every frame: new ``(R, T)``."""
def lbs_sweep_articulated(
    q: npt.NDArray[np.float64], idx: npt.NDArray[np.int64], w: npt.NDArray[np.float64],
    r: npt.NDArray[np.float64], t: npt.NDArray[np.float64], a: npt.NDArray[np.float64],
    z: npt.NDArray[np.float64], r_pre: npt.NDArray[np.float64],
    bone_parent: npt.NDArray[np.int64], joints: npt.NDArray[np.float64], gamma: float,
    n_frames: int, smooth: npt.NDArray[np.float64] | None = None,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Joint-constrained sweep: each bone rotates about its head joint with its subtree.
    ``smooth (B,)`` (optional, >= 0) adds
    ``sum_j smooth_j/2 sum_t |R_j^(t-1) - 2 R_j^t + R_j^(t+1)|_F^2`` (second differences); the
    frames ``t mod 3 = 0, 1, 2`` are then updated in turn so the energy never increases."""
def lbs_estep_frames(
    x: npt.NDArray[np.float64], v: npt.NDArray[np.float64], offsets: npt.NDArray[np.int64],
    tau: npt.NDArray[np.float64], omega: float, cutoff: float | None = None,
    single: bool = False, xn: npt.NDArray[np.float64] | None = None,
    vn: npt.NDArray[np.float64] | None = None, kappa: float = 0.0,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64],
           npt.NDArray[np.float64]]:
    """E-step (Eq. 4, §6.2 form) of every frame in one call, parallel over frames (with unit
    normals ``xn (F*M, 3)``, ``vn (sum N_t, 3)`` and ``kappa > 0``, each pair weighed by
    ``exp(kappa (n . n~ - 1))``): centroids
    ``x (F*M, 3)``, observed points ``v (sum N_t, 3)`` with frame t in rows
    ``offsets[t]:offsets[t+1]`` (``offsets (F+1,)``), ``tau (F,)`` m^2; ``cutoff`` and
    ``single`` as in :func:`gmm_estep`. Returns ``P1 (F, M)``, ``PX (F*M, 3)``, ``N_p (F,)``,
    ``sum_i Pt1_i |v_i|^2 (F,)``."""
def lbs_joint_normal_sums(
    ws: npt.NDArray[np.float64], a: npt.NDArray[np.float64], r: npt.NDArray[np.float64],
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64],
           npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Per-frame sums of the articulated joint solve with ``ws (M, E)``, ``a (F, M)``,
    ``r (F*M, 3)``: ``S0 (F,) = sum a``, ``d0 (F, 3) = sum a r``, ``S1 (F, E) = a @ ws``,
    ``S2 (F, E*E) = sum a ws_e ws_g``, ``d1 (F, E*3) = sum a ws_e r``."""
def lbs_track_frame(
    q: npt.NDArray[np.float64], labels: npt.NDArray[np.int64],
    bone_parent: npt.NDArray[np.int64], joints: npt.NDArray[np.float64],
    v: npt.NDArray[np.float64], r: npt.NDArray[np.float64], t_root: tuple[float, float, float],
    iterations: int, tau0: float, tau_max: float, floor: float, anneal: float, omega: float,
    cutoff: float | None, gamma: float, density: float,
    rest_normals: npt.NDArray[np.float64] | None = None,
    v_normals: npt.NDArray[np.float64] | None = None, kappa: float = 0.0,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """One frame of step 3's tracker (``rust/core/track.rs``): the rest points ``q (M, 3)``
    moving rigidly with their bones ``labels (M,)``, bones meeting at the rest ``joints
    (B, 3)``, fitted to ``v (N, 3)`` from the rotations ``r (B, 9)`` and root translation
    ``t_root`` by ``iterations`` EM steps (float32 E-step truncated at ``cutoff sqrt(tau)``,
    joint-constrained sweep with ``gamma``, root shift; data weights ``P1 / tau * density``;
    ``tau`` from 4/3 of the start's mean squared nearest distance clipped to ``[tau0,
    tau_max]``, annealed by ``anneal`` to ``tau0``, then Eq. 12 floored at ``floor``, m^2).
    ``rest_normals (M, 3)``, ``v_normals (N, 3)`` and ``kappa > 0`` weigh pairs by normal
    agreement. Returns ``R (B, 9)``, ``T (B, 3)`` (``T_frame_rest``) and the posed points
    ``(M, 3)``, metres."""
def simplex_qp(h: npt.NDArray[np.float64], g: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Exact argmin of ``0.5 w'Hw - g'w`` s.t. ``w >= 0, sum w = 1`` (k <= 8)."""
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

def surface_normals(
    query: npt.NDArray[np.float64], source: npt.NDArray[np.float64], radius: float,
    camera: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> npt.NDArray[np.float64]:
    """Unit normals ``(n, 3)`` of the least-squares planes of the ``source (N, 3)`` points within
    ``radius`` (metres) of each ``query (n, 3)``, flipped to face ``camera``; zero rows with
    fewer than 3 (or collinear) neighbours."""

def chamfer_misfit(
    template: npt.NDArray[np.float64], data: npt.NDArray[np.float64], trunc: float,
) -> float:
    """Symmetric truncated chamfer misfit (metres) of ``template (M, 3)`` and ``data (N, 3)``
    (both non-empty): the mean capped nearest distance template -> data plus data ->
    template, each distance capped at ``trunc`` (metres, > 0); summed in point order."""

def capped_nn_distances(
    queries: npt.NDArray[np.float64], points_: npt.NDArray[np.float64], cap: float,
) -> npt.NDArray[np.float64]:
    """``(n,)`` exact distance from each of ``queries (n, 3)`` to its nearest of
    ``points_ (N, 3)``, capped at ``cap`` (metres, > 0; ``cap`` everywhere when ``N = 0``)."""

def shortest_chord(
    uv: npt.NDArray[np.float64], centre: npt.NDArray[np.float64],
    directions: npt.NDArray[np.float64], band: float, gap: float,
) -> tuple[float, float, int] | None:
    """The shortest chord through ``centre (2,)`` of the silhouette ``uv (n, 2)`` (rows with a
    non-finite value ignored) over the unit ``directions (K, 2)``: ``(a, b, k)``, the chord from
    ``centre + a d_k`` to ``centre + b d_k``, or ``None`` (``pointrig.view.chord_half_width``)."""

def capped_nn_distances_grouped(
    queries: npt.NDArray[np.float64], query_offsets: npt.NDArray[np.int64],
    points_: npt.NDArray[np.float64], point_offsets: npt.NDArray[np.int64], cap: float,
) -> npt.NDArray[np.float64]:
    """``(n,)`` :func:`capped_nn_distances` of ``G`` groups in one call: the queries in rows
    ``query_offsets[g]:query_offsets[g + 1]`` of ``queries (n, 3)`` against the points in rows
    ``point_offsets[g]:point_offsets[g + 1]`` of ``points_ (N, 3)``; both offsets ``(G + 1,)``,
    from 0 to their row count, not decreasing. The groups run side by side."""

def kth_nn_distances(
    queries: npt.NDArray[np.float64], points_: npt.NDArray[np.float64], k: int,
) -> npt.NDArray[np.float64]:
    """``(n,)`` exact distance (metres) from each of ``queries (n, 3)`` to its ``k``-th
    nearest of ``points_ (N, 3)`` (``1 <= k <= N``; a query among the points is its own
    first, as in a k-d tree's ``query(points, k)``)."""

def farthest_point_sampling(
    points_: npt.NDArray[np.float64], n: int, first: int,
) -> npt.NDArray[np.int64]:
    """``(min(n, m),)`` indices of farthest-point samples of ``points_ (m, 3)`` from index
    ``first``: each next one farthest from those chosen (first index on a tie)."""

class DeformGraph:
    """Embedded deformation graph (Eq. 2) with the M-step solvers of §4.3 and one-frame EM.

    ``rest (M, 3)``, ``nodes (J, 3)``, ``pn_idx (M, k) int64`` / ``pn_w (M, k)`` (nodes driving
    each point and weights, normalised per row), ``edges (E, 2) int64`` directed ``(j, k)``,
    ``k in N(n_j)`` for Eq. 6. Node transforms are ``R (J, 3, 3)``, ``T (J, 3)``.
    ``normals (M, 3)`` (optional) are unit rest-pose surface normals: with them,
    ``FrameParams(kappa > 0)`` and ``register_frame(..., x_normals=(N, 3))`` each posterior
    carries the von Mises-Fisher factor ``exp(kappa (n_i . n~_m - 1))``.
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
        normals: npt.NDArray[np.float64] | None = None,
    ) -> None: ...
    def deform(self, r: npt.NDArray[np.float64], t: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """Deformed points ``y'`` (M, 3), Eq. 2."""
    def deform_normals(self, r: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """Deformed unit normals ``normalise(sum_j w R_j n)`` (M, 3); ValueError without
        rest normals."""
    def energy(
        self, r: npt.NDArray[np.float64], t: npt.NDArray[np.float64],
        r_pre: npt.NDArray[np.float64], t_pre: npt.NDArray[np.float64],
        p1: npt.NDArray[np.float64], px: npt.NDArray[np.float64],
        sum_x2: float, n_p: float, sigma2: float, beta_smooth: float, beta_small: float,
    ) -> float:
        """Eq. 8a from E-step statistics (``gmm_estep``), E_small relative to
        ``(r_pre, t_pre)``."""
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
        self, x: npt.NDArray[np.float64], r: npt.NDArray[np.float64],
        t: npt.NDArray[np.float64], params: FrameParams, *, sigma2_start: float,
        rigid_iters: int, x_normals: npt.NDArray[np.float64] | None = None,
    ) -> dict:
        """Algorithm 1 on one frame ``x (N, 3)`` from node transforms ``r (J, 3, 3)``,
        ``t (J, 3)`` with the sequence's ``params``, starting at ``sigma2_start`` (m^2) with
        ``rigid_iters`` leading rigid (Kabsch) iterations; ``x_normals (N, 3)`` are the data
        normals of the normal agreement (used when ``params`` has ``kappa > 0`` and the graph
        rest normals).
        Returns a dict with ``R``, ``T``, ``points (M, 3)``, ``sigma2``, ``iterations``,
        ``energy``, ``n_p``, ``n_data``, ``history (iterations, 2)`` = (sigma^2, energy) per
        iteration."""

class FrameParams:
    """The parameters of :meth:`DeformGraph.register_frame` that stay the same for every frame
    of a sequence, built once from ``RegistrationConfig`` (see it for the meanings):
    ``omega`` (Eq. 1), ``beta_smooth`` (absolute, or the ratio lambda with
    ``beta_relative``), ``beta_small``, ``sigma2_min`` (m^2), the coarse-to-fine ``anneal``
    factor down to ``anneal_floor`` (m^2), ``max_iter`` and ``tol`` of the EM, ``cutoff``
    (truncated E-step in sigmas, ``None`` = dense), ``solver`` (``"gauss_newton"`` or
    ``"sweeps"``, ValueError otherwise), the Gauss-Newton ``damping``, ``cg_tol`` and
    ``cg_max``, the coarse-data ``subsample`` (0 = full data), the early stop ``motion_tol``
    (0 = off) and the normal agreement ``kappa`` (0 = off). The E-step runs in float32 with
    float64 sums."""

    def __init__(
        self, *, omega: float, beta_smooth: float, beta_relative: bool, beta_small: float,
        sigma2_min: float, anneal: float, anneal_floor: float, max_iter: int, tol: float,
        cutoff: float | None, solver: str, damping: float, cg_tol: float, cg_max: int,
        subsample: float = 0.0, motion_tol: float = 0.0, kappa: float = 0.0,
    ) -> None: ...
