"""Parameters: one frozen dataclass per pipeline stage, with the paper's Table 1 defaults.

Units: every length is in metres and every squared length in m^2. The paper's Table 1 values
assume metres (sigma^2 = 6e-4 m^2 is a 2.4 cm standard deviation); :func:`load_config` and the
readers keep all data in metres, so inputs in millimetres must be scaled on reading
(``scale=0.001``), never by changing these numbers.

Every stage checks its values when it is made (``__post_init__``): a bad value raises
:class:`~pointrig.errors.ConfigError` naming ``[stage] field`` before any step runs. The
defaults are pointrig's method; each stage's ``paper()`` (and :meth:`PipelineConfig.paper`)
is the paper's own configuration.

``workers`` (registration, structure, joints) is the number of threads a stage runs its
independent tasks on (step 1's forward and backward chains and the refinement's frames,
step 2's ensemble seeds, step 3's tracking hypotheses); 0 = ``os.cpu_count()``. Results do not
depend on it. The Rust kernels use their own thread pool (``RAYON_NUM_THREADS``).

A TOML file overrides any field, one table per stage::

    [registration]
    beta_smooth = 1e3
    [joints]
    zeta = 1e4
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import os
import tomllib
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from .errors import ConfigError

__all__ = [
    "PRESETS",
    "JointsConfig",
    "PipelineConfig",
    "PreprocessConfig",
    "RegistrationConfig",
    "RigConfig",
    "StructureConfig",
    "apply_overrides",
    "load_config",
    "pool_size",
]


def pool_size(workers: int, tasks: int) -> int:
    """Threads for ``tasks`` independent tasks: ``workers`` (0 = ``os.cpu_count()``), at most
    ``tasks``, at least 1."""
    n = workers if workers > 0 else (os.cpu_count() or 1)
    return max(1, min(n, tasks))


# ---- value checks (one message form: "[stage] field must be ..., got ...") ----------------


def _fail(stage: str, name: str, want: str, val: Any) -> None:
    raise ConfigError(f"[{stage}] {name} must be {want}, got {val!r}")


def _is_int(v: Any) -> bool:
    return isinstance(v, numbers.Integral) and not isinstance(v, bool)


def _is_real(v: Any) -> bool:
    return isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(v)


def _in(v: float, interval: str) -> bool:
    """``v`` in an interval written ``"[a, b)"`` (``inf`` allowed as an open end)."""
    lo_s, hi_s = interval[1:-1].split(",")
    lo, hi = float(lo_s), float(hi_s)
    return (v >= lo if interval[0] == "[" else v > lo) and (v <= hi if interval[-1] == "]"
                                                            else v < hi)


class _Checks:
    """Checks of one config object's fields, each raising :class:`ConfigError` naming
    ``[stage] field``."""

    def __init__(self, obj: Any, stage: str) -> None:
        self.obj, self.stage = obj, stage

    def _val(self, name: str) -> Any:
        return getattr(self.obj, name)

    def int(self, name: str, lo: int = 0) -> None:
        v = self._val(name)
        if not (_is_int(v) and v >= lo):
            _fail(self.stage, name, f"an integer >= {lo}", v)

    def real(self, name: str, interval: str, off: bool = False) -> None:
        """A finite number in ``interval``; with ``off`` also exactly 0 (the feature off)."""
        v = self._val(name)
        if not (_is_real(v) and (_in(v, interval) or (off and v == 0))):
            _fail(self.stage, name, ("0 (off) or " if off else "") + f"a number in {interval}",
                  v)

    def bool(self, name: str) -> None:
        v = self._val(name)
        if not isinstance(v, bool):
            _fail(self.stage, name, "true or false", v)

    def choice(self, name: str, allowed: tuple[str, ...]) -> None:
        v = self._val(name)
        if not isinstance(v, str) or v not in allowed:
            _fail(self.stage, name, "one of " + ", ".join(repr(a) for a in allowed), v)

    def point(self, name: str, optional: bool = False) -> None:
        """Three finite numbers (metres); with ``optional`` also ``None``."""
        v = self._val(name)
        if optional and v is None:
            return
        try:
            ok = len(v) == 3 and all(_is_real(a) for a in v)
        except TypeError:
            ok = False
        if not ok:
            _fail(self.stage, name, ("None or " if optional else "") + "3 finite numbers", v)


@dataclass(frozen=True)
class PreprocessConfig:
    """Input clean-up before step 1 (paper §3: a bounding box per sequence)."""

    crop_min: tuple[float, float, float] | None = None  # crop box lower corner, metres
    crop_max: tuple[float, float, float] | None = None  # crop box upper corner, metres
    voxel_size: float = 0.0  # voxel downsampling of each frame, metres (0 = off)
    frame_start: int = 0  # first frame read
    frame_stop: int | None = None  # frame after the last one read (None = to the end)
    frame_stride: int = 1  # read every frame_stride-th frame
    min_points: int = 50  # fewer points left in a frame is an error
    # largest robust span of a frame, metres: more means the input is not in metres, an error
    # (pointrig.sequence.check_units); 0 = off
    max_extent: float = 30.0
    # "auto": remove static floor / wall planes (pointrig.background.remove_background);
    # "keep": the points as read (§3 crops by hand)
    background: str = "auto"
    background_threshold: float = 0.03  # inlier distance of the plane search, metres
    # every frame: drop points whose sparse_neighbors-th neighbour is farther than sparse_ratio
    # x the frame's median of that distance (pointrig.preprocess.remove_sparse_frames; 0 = off)
    sparse_neighbors: int = 10
    sparse_ratio: float = 4.0

    def __post_init__(self) -> None:
        c = _Checks(self, "preprocess")
        c.point("crop_min", optional=True)
        c.point("crop_max", optional=True)
        if self.crop_min is not None and self.crop_max is not None \
                and not all(a < b for a, b in zip(self.crop_min, self.crop_max)):
            _fail("preprocess", "crop_max", f"above crop_min {self.crop_min!r} on every axis",
                  self.crop_max)
        c.real("voxel_size", "[0, inf)")
        c.int("frame_start", 0)
        if self.frame_stop is not None:
            c.int("frame_stop", 0)
            if self.frame_stop <= self.frame_start:
                _fail("preprocess", "frame_stop", f"None or above frame_start "
                      f"({self.frame_start})", self.frame_stop)
        c.int("frame_stride", 1)
        c.int("min_points", 1)
        c.real("max_extent", "[0, inf)")
        c.choice("background", ("auto", "keep"))
        c.real("background_threshold", "(0, inf)")
        c.int("sparse_neighbors", 1)
        c.real("sparse_ratio", "(1, inf)", off=True)

    @classmethod
    def paper(cls, **overrides: Any) -> PreprocessConfig:
        """The paper's input (§3): the points as read, cropped by hand (``crop_min`` /
        ``crop_max``), no background or sparse-point removal."""
        return cls(**{"background": "keep", "sparse_ratio": 0.0, **overrides})


@dataclass(frozen=True)
class RegistrationConfig:
    """Step 1, non-rigid registration (§4, Eqs. 1-12, Table 1).

    The paper's parameters keep their Table 1 values. The defaults of the added fields select
    pointrig's variant (joint Gauss-Newton M-step, beta_smooth relative to the data term,
    data-driven coarse sigma^2 start, rigid pre-alignment, constant-velocity prediction,
    normal agreement, refinement from the skeleton); :meth:`paper` returns the plain §4
    configuration. Lengths are metres (sigma^2 in m^2).
    """

    # rest frame (§4: the first, "other frames can also be chosen"): an index, or "fit": the
    # best of rest_candidates registrations (pointrig.registration.register_sequence)
    rest_frame: int | str = "fit"
    # "fit" candidates: surface cover within this fraction of the middle half's largest
    rest_cover_tolerance: float = 0.03
    rest_candidates: int = 1  # most "fit" candidates (1 = the most complete frame, no choice)
    rest_fit_margin: float = 0.05  # fraction by which another candidate must fit better
    n_rest_points: int = 2000  # M, points of the rest-pose point set surface
    n_nodes: int = 200  # deformation-graph nodes n_j (Eq. 2), farthest-point sampled
    k_point_nodes: int = 4  # nodes N(y_m) driving each point (Eq. 2)
    k_node_neighbors: int = 6  # node neighbours of each node in E_smooth (Eq. 6), k-NN
    # node edges whose path over the rest points is longer than this x their straight length
    # are dropped (parts that only touch are not tied; 0 = plain k-NN, §4)
    node_geodesic_ratio: float = 2.0
    omega: float = 0.01  # omega, outlier weight of the GMM (Eq. 1), Table 1
    beta_smooth: float = 1e5  # beta_smooth, E_smooth weight (Eq. 8a), Table 1 ("fixed" mode)
    beta_small: float = 1.0  # beta_small, E_small weight (Eq. 8a), Table 1
    sigma2_init: float = 6e-4  # initial sigma^2 (§7.2), m^2; the floor of the data start
    max_iterations: int = 20  # EM iterations per frame
    tolerance: float = 1e-5  # relative change of Eq. 8a that stops the EM
    seed: int = 0  # seed of the farthest-point sampling and the rest-frame candidates
    solver: str = "gauss_newton"  # M-step: "gauss_newton" (all nodes jointly) | "sweeps" (§4.3)
    # "relative": beta_smooth = beta_smooth_rel x N_p / (sigma^2 x edges) every iteration;
    # "fixed": beta_smooth as given (§4)
    beta_smooth_mode: str = "relative"
    beta_smooth_rel: float = 0.1  # smooth weight per edge over data weight per edge
    # each frame's starting sigma^2: "data" (CPD's, clipped to [sigma2_init, sigma2_start_max])
    # | "fixed" (sigma2_init, §7.2)
    sigma2_start: str = "data"
    sigma2_start_max: float = 0.01  # largest data start, m^2
    sigma2_min: float = 1e-5  # floor of sigma^2 (Eq. 12), m^2
    sigma2_anneal: float = 0.5  # sigma^2 at most this x the last until sigma2_init (1 = Eq. 12)
    rigid_iterations: int = 2  # leading EM iterations that move the template rigidly (Kabsch)
    predict_velocity: float = 1.0  # constant-velocity prediction of the nodes (0 = previous)
    # start from the previous pose when its chamfer misfit to the frame is below this x the
    # prediction's (0 = always predict)
    predict_check: float = 1.0
    cutoff: float = 3.5  # truncated E-step: pairs beyond cutoff x sigma ignored (0 = dense)
    gn_damping: float = 1e-4  # Levenberg damping of the Gauss-Newton step (x diagonal)
    cg_tolerance: float = 1e-6  # relative residual of its conjugate-gradient solve
    cg_max_iterations: int = 300  # iteration cap of that solve
    # coarse E-step on count-weighted voxel centroids of side subsample x sigma while that
    # halves the data (0 = full data)
    subsample: float = 1.0
    # normal agreement: posteriors x exp(normal_kappa (n_data . n_template - 1)) (0 = off)
    normal_kappa: float = 1.0
    normal_radius: float = 1.5  # normals' neighbourhood, x the rest-point spacing
    motion_tol: float = 0.1  # stop when the template moves < this x sigma (RMS; 0 = off)
    lost_fraction: float = 0.05  # N_p / N below this: the frame again from a coarse start
    sor_neighbors: int = 20  # rest surface: statistical outlier removal, neighbours
    sor_std_ratio: float = 2.0  # ... keeps mean neighbour distance < mean + ratio x std
    mls_neighbors: int = 16  # rest surface: MLS projection neighbours (0 = off)
    # rest surface: sparse-point removal as [preprocess] sparse_* (ratio 0 = off)
    rest_sparse_neighbors: int = 10
    rest_sparse_ratio: float = 4.0
    # rounds of re-registration from step 3's skeleton, each followed by steps 2-3
    # (pointrig.registration.refine_registration; 0 = one pass, §4)
    refine_rounds: int = 1
    # threads for the rest-frame candidates, the two chains and the refined frames (0 = all
    # cores)
    workers: int = 0

    def __post_init__(self) -> None:
        c = _Checks(self, "registration")
        rf = self.rest_frame
        if not ((_is_int(rf) and rf >= 0) or rf == "fit"):
            _fail("registration", "rest_frame", "a frame index >= 0 or 'fit'", rf)
        c.real("rest_cover_tolerance", "[0, 1)")
        c.int("rest_candidates", 1)
        c.real("rest_fit_margin", "[0, 1)")
        c.int("n_rest_points", 10)
        c.int("n_nodes", 1)
        c.int("k_point_nodes", 1)
        c.int("k_node_neighbors", 0)
        c.real("node_geodesic_ratio", "[1, inf)", off=True)
        c.real("omega", "[0, 1)")
        c.real("beta_smooth", "[0, inf)")
        c.real("beta_small", "[0, inf)")
        c.real("sigma2_init", "(0, inf)")
        c.int("max_iterations", 1)
        c.real("tolerance", "[0, inf)")
        c.int("seed", 0)
        c.choice("solver", ("gauss_newton", "sweeps"))
        c.choice("beta_smooth_mode", ("relative", "fixed"))
        c.real("beta_smooth_rel", "[0, inf)")
        c.choice("sigma2_start", ("data", "fixed"))
        c.real("sigma2_start_max", "(0, inf)")
        c.real("sigma2_min", "(0, inf)")
        c.real("sigma2_anneal", "(0, 1]")
        c.int("rigid_iterations", 0)
        c.real("predict_velocity", "[0, inf)")
        c.real("predict_check", "[0, 1]")
        c.real("cutoff", "[0, inf)")
        c.real("gn_damping", "[0, inf)")
        c.real("cg_tolerance", "(0, inf)")
        c.int("cg_max_iterations", 1)
        c.real("subsample", "[0, inf)")
        c.real("normal_kappa", "[0, inf)")
        c.real("normal_radius", "(0, inf)")
        c.real("motion_tol", "[0, inf)")
        c.real("lost_fraction", "[0, 1)")
        c.int("sor_neighbors", 1)
        c.real("sor_std_ratio", "(0, inf)")
        c.int("mls_neighbors", 0)
        c.int("rest_sparse_neighbors", 1)
        c.real("rest_sparse_ratio", "(1, inf)", off=True)
        c.int("refine_rounds", 0)
        c.int("workers", 0)

    @classmethod
    def paper(cls, **overrides: Any) -> RegistrationConfig:
        """The plain §4 configuration: Table 1 weights, node sweeps (§4.3), a fixed
        beta_smooth and sigma^2 start (§7.2), the first frame as the rest pose, each frame
        from the previous result, the full data in every E-step, the energy stopping rule
        and none of the additions."""
        base = {
            "rest_frame": 0,
            "node_geodesic_ratio": 0.0,
            "solver": "sweeps",
            "beta_smooth_mode": "fixed",
            "sigma2_start": "fixed",
            "sigma2_anneal": 1.0,
            "rigid_iterations": 0,
            "predict_velocity": 0.0,
            "subsample": 0.0,
            "normal_kappa": 0.0,
            "motion_tol": 0.0,
            "lost_fraction": 0.0,
            "rest_sparse_ratio": 0.0,
            "refine_rounds": 0,
        }
        return cls(**{**base, **overrides})


@dataclass(frozen=True)
class StructureConfig:
    """Step 2, skeletal structure extraction (§5, Eqs. 14-15, 20).

    Every threshold is scale-free (a ratio, an angle, a fraction of M or of the subject size,
    a neighbour count), so the same defaults hold for a hand or a horse. "size" below is the
    rest points' bounding-box diagonal. :meth:`paper` returns the §5 configuration.
    """

    # --- motion-based clustering (§5.2) ---
    n_clusters: int = 30  # initial k of the k-means; the refinement removes the extra ones
    cluster_rounds: int = 10  # rounds of (i) Kabsch fit (Eq. 14), (ii) relabel, (iii) vote
    seed: int = 0  # k-means++ seed; the step is deterministic given it
    # runs from seeds seed .. seed + ensemble_seeds - 1, the medoid kept
    # (pointrig.structure.extract_structure; 1 = one run, §5)
    ensemble_seeds: int = 5
    ensemble_radius: float = 0.03  # cap of a joint's distance between runs, x size
    kmeans_iterations: int = 30  # Lloyd iterations of the k-means
    # weight of the displacement trajectories against the rest positions in the k-means
    # features (pointrig.clustering.kmeans_features; 0 = rest positions only)
    trajectory_weight: float = 1.0
    kmeans_frames: int = 20  # frames (evenly spaced) whose displacements enter the features
    vote_neighbors: int = 10  # rest-pose neighbours: the ball of (iii), the candidates of (ii)
    vote_radius_ratio: float = 2.0  # ball radius, x the median vote_neighbors-th distance
    # (iii) moves a point only to a bone whose residual is at most this x its best
    # candidate's (0 = unguarded, §5.2)
    vote_guard_ratio: float = 2.0
    post_merge_rounds: int = 3  # clustering rounds after each refinement change
    # neighbours count only while within this x the ball radius (graph: x their rest
    # distance) in every frame (0 = rest-pose neighbourhoods, §5.2)
    neighbor_stretch: float = 2.0

    # --- bone graph (§5.3) ---
    touch_min_pairs: int = 3  # two bones touch if this many neighbour pairs straddle them
    graph_radius_ratio: float = 2.0  # graph edges' neighbours: within this x the spacing
    # bridge cost: RMS dislocation at the pair's Eq. 20 joint (its pull to the gap's
    # midpoint: bridge_joint_prior) + bridge_gap_weight x the gap in metres
    bridge_joint_prior: float = 0.05
    bridge_gap_weight: float = 0.1
    # touching edges' weight: "dislocation" (RMS dislocation at the pair's joint, its pull to
    # the contact band: edge_joint_prior) | "eq15" (e_ij of Eq. 15, §5.3)
    edge_weight: str = "dislocation"
    edge_joint_prior: float = 1.0

    # --- refinement (§5.4) ---
    # two bones merge if the merge_percentile-th percentile of their relative rotation's
    # angle between two frames stays below this, degrees
    merge_angle_deg: float = 10.0
    # "angle": that test alone; "both": also that angle x the smaller bone's reach below
    # merge_displacement x size
    merge_rule: str = "both"
    merge_displacement: float = 0.01
    merge_percentile: float = 95.0
    noise_margin: float = 1.0  # angle discounted by this x its Kabsch-noise level (0 = off)
    # that noise's variance x n^noise_corr_exponent, n = the bone's points (0 = independent)
    noise_corr_exponent: float = 0.5
    min_cluster_fraction: float = 0.005  # clusters below this x M points are absorbed
    # a leaf at a branching parent below this x M is pruned (§5.4's first rule; 0 = off: the
    # joint selection on the raw frames decides instead)
    leaf_min_fraction: float = 0.0
    # a bone that a per-point blend of two neighbours' motions fits within this x its own
    # rigid fit's residual variance is a skinning band, not a bone (0 = off)
    band_ratio: float = 1.5
    # close joints (§5.4): a bone whose joints lie within this x its extent is removed
    short_bone_ratio: float = 0.75
    # a bone whose neighbours' motions explain its points within this x size (RMS) beyond its
    # own fit goes to them (0 = off)
    invisible_bone_fraction: float = 0.005
    refine_passes: int = 25  # rounds of merge / prune / rebuild
    max_joints: int = 0  # at most this many bones = output joints (0 = no cap)

    # --- joints (Eq. 20) and root (§5.3) ---
    eta: float = 1.0  # eta, boundary-centroid weight in E_Joint (Eq. 20), Table 1
    # root joint at the root part's far end when its children attach on one side with this
    # alignment (pointrig.structure.root_joint_position; 0 = the centre, §5.3)
    root_end_alignment: float = 1.0
    # root bone: "largest" (most points) | "centroid" (centre nearest the rest centroid, §5.3)
    root_choice: str = "largest"
    # output: a root that is a leaf of a branched tree moves to the body's centre ("centre")
    # or stays ("keep"; pointrig.output.output_tree)
    leaf_root: str = "centre"
    # that centre: the rest points within this x size of the least eccentricity (0 = one point)
    centre_tolerance: float = 0.04
    # output, first: a joint stays only where the raw frames need it, by the Bayesian
    # information criterion on the observed points counted at the model's resolution
    # (pointrig.selection.select_joints): the multiplier of its penalty (1 = BIC, 0 = keep
    # every joint; 0.5 chosen on the corpus's tuning set) and the frames it scores
    joint_penalty: float = 0.5
    joint_frames: int = 30

    # --- single-view depth correction ---
    # c~ moved back along the camera ray to the part's axis depth, q in (1/2, 1]
    # (pointrig.view.view_depth_correct; 0 = off)
    view_depth_quantile: float = 0.95
    camera_position: tuple[float, float, float] = (0.0, 0.0, 0.0)  # in the input frame, m
    # "yes" (one depth camera), "no" (fused or two-sided clouds: the paper's centroids),
    # "auto" (pointrig.view.is_single_view decides)
    single_view: str = "yes"
    workers: int = 0  # threads: the ensemble's seeds, the joint selection (0 = all cores)

    def __post_init__(self) -> None:
        c = _Checks(self, "structure")
        c.int("n_clusters", 1)
        c.int("cluster_rounds", 0)
        c.int("seed", 0)
        c.int("ensemble_seeds", 1)
        c.real("ensemble_radius", "(0, inf)")
        c.int("kmeans_iterations", 1)
        c.real("trajectory_weight", "[0, inf)")
        c.int("kmeans_frames", 1)
        c.int("vote_neighbors", 1)
        c.real("vote_radius_ratio", "(0, inf)")
        c.real("vote_guard_ratio", "[0, inf)")
        c.int("post_merge_rounds", 0)
        c.real("neighbor_stretch", "[1, inf)", off=True)
        c.int("touch_min_pairs", 1)
        c.real("graph_radius_ratio", "(0, inf)")
        c.real("bridge_joint_prior", "[0, inf)")
        c.real("bridge_gap_weight", "[0, inf)")
        c.choice("edge_weight", ("dislocation", "eq15"))
        c.real("edge_joint_prior", "[0, inf)")
        c.real("merge_angle_deg", "(0, 180]")
        c.choice("merge_rule", ("angle", "both"))
        c.real("merge_displacement", "(0, inf)")
        c.real("merge_percentile", "[0, 100]")
        c.real("noise_margin", "[0, inf)")
        c.real("noise_corr_exponent", "[0, 1]")
        c.real("min_cluster_fraction", "[0, 1)")
        c.real("leaf_min_fraction", "[0, 1)")
        c.real("band_ratio", "[0, inf)")
        c.real("short_bone_ratio", "[0, inf)")
        c.real("invisible_bone_fraction", "[0, inf)")
        c.int("refine_passes", 0)
        c.int("max_joints", 0)
        c.real("eta", "[0, inf)")
        c.real("root_end_alignment", "[0, 1]")
        c.choice("root_choice", ("largest", "centroid"))
        c.choice("leaf_root", ("centre", "keep"))
        c.real("centre_tolerance", "[0, 1)")
        c.real("joint_penalty", "[0, inf)")
        c.int("joint_frames", 1)
        c.real("view_depth_quantile", "(0.5, 1]", off=True)
        c.point("camera_position")
        c.choice("single_view", ("yes", "no", "auto"))
        c.int("workers", 0)

    @classmethod
    def paper(cls, **overrides: Any) -> StructureConfig:
        """The §5 configuration: one k-means start, the plain clustering rounds of §5.2, the
        Eq. 15 edge weights, the root at the cluster centre nearest the rest-pose centroid
        (§5.3), the refinement's merges by relative rotation alone, its leaf, tiny-cluster and
        close-joint rules (§5.4), the paper's centroids (no single-view correction) and no
        rules of pointrig's own."""
        base = {
            "ensemble_seeds": 1,
            "vote_guard_ratio": 0.0,
            "neighbor_stretch": 0.0,
            "edge_weight": "eq15",
            "merge_rule": "angle",
            "noise_margin": 0.0,
            "leaf_min_fraction": 0.01,
            "band_ratio": 0.0,
            "invisible_bone_fraction": 0.0,
            "root_end_alignment": 0.0,
            "root_choice": "centroid",
            "leaf_root": "keep",
            "joint_penalty": 0.0,
            "single_view": "no",
        }
        return cls(**{**base, **overrides})


@dataclass(frozen=True)
class JointsConfig:
    """Step 3, LBS-based joint learning (§6, Eqs. 16-26, Algorithm 2, Table 1).

    Paper parameters keep their Table 1 values. ``mode="paper"`` runs Algorithm 2 as printed
    (the soft joint term with the growing alpha, Eqs. 23-26 per bone, Eq. 20 for the joints);
    ``mode="articulated"`` (default) enforces the joint constraint exactly and solves the
    joint positions together with the translations. :meth:`paper` returns the §6
    configuration.
    """

    omega: float = 0.01  # omega', outlier weight (Eq. 16), Table 1
    eta: float = 1.0  # eta, boundary-centroid weight in E_Joint (Eq. 20), Table 1
    zeta: float = 1e4  # zeta, E_Register weight (Eq. 21a), Table 1 (times zeta_scale)
    gamma: float = 0.1  # gamma, E_small weight (Eq. 21a), Table 1
    alpha_init: float | None = None  # alpha at iteration 1 (Eq. 21a); None = zeta x M (§7.2)
    alpha_growth: float = 1.45  # alpha's factor per iteration (§7.2)
    max_bones_per_point: int = 4  # sparsity of W, ||W_m.||_0 <= 4 (Eq. 21b)
    tau_init: float = 6e-4  # initial tau^t (§7.2), m^2
    tau_min: float = 1e-6  # floor of tau^t, m^2
    max_iterations: int = 20  # EM iterations (Algorithm 2; 0 = the start as it is)
    tolerance: float = 1e-5  # stop when |dE_Total| / |E_Total| (Eq. 21a) falls below this
    # "articulated": bones always meet at their joints (pointrig.joints.
    # solve_joints_articulated); "paper": Algorithm 2 as printed
    mode: str = "articulated"
    joint_prior: float = 1.0  # articulated: eta |c - c~|^2 against one frame of data
    gmm_density_normalize: bool = True  # E_GMM x M / N_t (False = Eq. 21a as printed)
    # Eq. 22 bones of a point: its step-2 bone and tree neighbours ("tree") | all ("all", §6)
    weight_candidates: str = "tree"
    # Eq. 22 updates in every iteration (Algorithm 2); False: one fit after the loop
    update_weights: bool = False
    zeta_scale: float = 0.001  # E_Register weight used = zeta x zeta_scale (1 = Table 1)
    tau_init_relative: bool = True  # tau_init x (size / 1.8 m)^2 (Table 1: human-sized)
    # also stop when no joint moves more than this in an iteration, metres (0 = off)
    joint_tolerance: float = 5e-4
    min_iterations: int = 3  # iterations before joint_tolerance may stop the EM
    bone_sweeps: int = 1  # bone-update sweeps (Eqs. 23-26) per M-step
    # articulated: temporal rotation prior sum_t |R^(t-1) - 2 R^t + R^(t+1)|_F^2, weight this
    # x mean data weight x size^2 (0 = off)
    rotation_smoothing: float = 0.01
    # output bones: "minimal" removes limbs' roll about their own axes
    # (pointrig.kinematics.minimal_twist) | "fit": as fitted
    bone_twist: str = "minimal"
    twist_min_elongation: float = 2.0  # a limb: spread along its axis over across it
    twist_min_roll_deg: float = 60.0  # a limb's p90 roll that makes it "minimal", degrees
    # output joints along the camera ray to their parts' axis depth ("chord",
    # pointrig.view.view_depth_joints; single-view input only) | "off"
    joint_depth: str = "chord"
    depth_frames: int = 10  # frames read by the chord rule
    # EM start: "track" (pointrig.joints.track_bones, step 2's skeleton fitted to the raw
    # frames) | "structure" (step 2's bone motions, §6)
    init: str = "track"
    track_iterations: int = 10  # EM iterations per tracked frame
    track_sweeps: int = 3  # articulated sweeps (each with the root shift) per tracker E-step
    track_velocity: float = 1.0  # constant-velocity prediction gain (0 = previous frame)
    track_tau_max: float = 0.01  # cap of a frame's starting tau, m^2 at 1.8 m (scaled)
    track_anneal: float = 0.5  # coarse-to-fine: tau at most this x the previous until tau_init
    track_predict_check: float = 1.0  # as [registration] predict_check, per tracked frame
    track_normal_kappa: float = 1.0  # as [registration] normal_kappa, in the tracker (0 = off)
    normal_radius: float = 1.5  # normals' neighbourhood, x the rest-point spacing
    estep_radius_sigmas: float = 3.5  # truncated E-step (Eq. 4): pairs within this x sqrt(tau)
    estep_max_points: int = 4000  # observed points per frame in the E-steps (0 = all)
    workers: int = 0  # threads for a tracked frame's two hypotheses (0 = all cores)

    def __post_init__(self) -> None:
        c = _Checks(self, "joints")
        c.real("omega", "[0, 1)")
        c.real("eta", "[0, inf)")
        c.real("zeta", "[0, inf)")
        c.real("gamma", "[0, inf)")
        if self.alpha_init is not None:
            c.real("alpha_init", "[0, inf)")
        c.real("alpha_growth", "(0, inf)")
        c.int("max_bones_per_point", 1)
        c.real("tau_init", "(0, inf)")
        c.real("tau_min", "(0, inf)")
        c.int("max_iterations", 0)
        c.real("tolerance", "[0, inf)")
        c.choice("mode", ("articulated", "paper"))
        c.real("joint_prior", "[0, inf)")
        c.bool("gmm_density_normalize")
        c.choice("weight_candidates", ("tree", "all"))
        c.bool("update_weights")
        c.real("zeta_scale", "[0, inf)")
        c.bool("tau_init_relative")
        c.real("joint_tolerance", "[0, inf)")
        c.int("min_iterations", 0)
        c.int("bone_sweeps", 1)
        c.real("rotation_smoothing", "[0, inf)")
        c.choice("bone_twist", ("minimal", "fit"))
        c.real("twist_min_elongation", "[0, inf)")
        c.real("twist_min_roll_deg", "[0, 180]")
        c.choice("joint_depth", ("chord", "off"))
        c.int("depth_frames", 1)
        c.choice("init", ("track", "structure"))
        c.int("track_iterations", 1)
        c.int("track_sweeps", 1)
        c.real("track_velocity", "[0, inf)")
        c.real("track_tau_max", "(0, inf)")
        c.real("track_anneal", "(0, 1]")
        c.real("track_predict_check", "[0, 1]")
        c.real("track_normal_kappa", "[0, inf)")
        c.real("normal_radius", "(0, inf)")
        c.real("estep_radius_sigmas", "(0, inf)")
        c.int("estep_max_points", 0)
        c.int("workers", 0)

    @classmethod
    def paper(cls, **overrides: Any) -> JointsConfig:
        """Algorithm 2 as printed (§6): Table 1 weights with E_Register at full weight, the
        growing alpha (§7.2), Eq. 22 weight updates among all bones every iteration, per-bone
        updates (Eqs. 23-26) and Eq. 20 joints, step 2's bone motions as the start, every
        observed point, Eq. 21a as printed, the energy stopping rule and the output as
        fitted."""
        base = {
            "mode": "paper",
            "gmm_density_normalize": False,
            "weight_candidates": "all",
            "update_weights": True,
            "zeta_scale": 1.0,
            "tau_init_relative": False,
            "joint_tolerance": 0.0,
            "rotation_smoothing": 0.0,
            "bone_twist": "fit",
            "joint_depth": "off",
            "init": "structure",
            "estep_max_points": 0,
        }
        return cls(**{**base, **overrides})


@dataclass(frozen=True)
class RigConfig:
    """The animator's outputs: frame rate, joint names, the skinned surface ``rig.glb``
    (:mod:`pointrig.rig`) and the page to look at the run, ``report.html``
    (:mod:`pointrig.report`)."""

    # frame rate of the recording, Hz; the outputs play at fps / [preprocess] frame_stride
    fps: float = 30.0
    # joint names: "tree" (root, spine_1, arm_l_1, ... by place in the tree) or "index" (j0..)
    names: str = "tree"
    # rig.glb: "auto" (when the rig extra is installed), "on" (an error without it) or "off"
    mesh: str = "auto"
    # rig.usda (UsdSkel) beside rig.glb: "auto" (when the usd extra is installed), "on", "off"
    usd: str = "auto"
    faces: int = 20000  # triangle budget of the surface after decimation
    # voxel of the surface reconstruction, metres (0 = from the rest points' spacing)
    voxel: float = 0.0
    # frames whose points are moved back to the rest pose (inverse LBS) to fill the surface
    fill_frames: int = 8
    # report.html: "auto" (when the report extra, plotly, is installed), "on" or "off"
    report: str = "auto"
    # points of each frame shown in report.html (an even subsample)
    report_points: int = 2000

    def __post_init__(self) -> None:
        c = _Checks(self, "rig")
        c.real("fps", "(0, 1000]")
        c.choice("names", ("tree", "index"))
        c.choice("mesh", ("auto", "on", "off"))
        c.choice("usd", ("auto", "on", "off"))
        c.int("faces", 100)
        c.real("voxel", "[0, 0.2]")
        c.int("fill_frames", 0)
        c.choice("report", ("auto", "on", "off"))
        c.int("report_points", 1)

    @classmethod
    def paper(cls, **overrides: Any) -> RigConfig:
        """Joints named by index (``j0, j1, ...``), as the method numbers its bones."""
        return cls(**{"names": "index", **overrides})


@dataclass(frozen=True)
class PipelineConfig:
    """All stages together."""

    preprocess: PreprocessConfig = field(default_factory=PreprocessConfig)
    registration: RegistrationConfig = field(default_factory=RegistrationConfig)
    structure: StructureConfig = field(default_factory=StructureConfig)
    joints: JointsConfig = field(default_factory=JointsConfig)
    rig: RigConfig = field(default_factory=RigConfig)

    def with_workers(self, threads: int) -> PipelineConfig:
        """This config with every stage's thread pool (``workers``) set to ``threads``
        (0: unchanged). Results do not depend on it."""
        if threads <= 0:
            return self
        return dataclasses.replace(
            self,
            registration=dataclasses.replace(self.registration, workers=threads),
            structure=dataclasses.replace(self.structure, workers=threads),
            joints=dataclasses.replace(self.joints, workers=threads))

    def to_dict(self) -> dict[str, dict[str, Any]]:
        """Every parameter, by stage, as plain JSON-able values."""
        return dataclasses.asdict(self)

    @classmethod
    def paper(cls) -> PipelineConfig:
        """The paper's own configuration, every stage's ``paper()``."""
        return cls(PreprocessConfig.paper(), RegistrationConfig.paper(),
                   StructureConfig.paper(), JointsConfig.paper(), RigConfig.paper())

    @classmethod
    def fast(cls) -> PipelineConfig:
        """The defaults traded for speed, for many recordings: no refinement round
        (``refine_rounds = 0``), and step 3 on at most 2000 observed points a frame with 5
        tracker iterations. Its time and corpus scores against the defaults are in
        docs/parameters.md."""
        d = cls()
        return dataclasses.replace(
            d, registration=dataclasses.replace(d.registration, refine_rounds=0),
            joints=dataclasses.replace(d.joints, estep_max_points=2000, track_iterations=5))

    @classmethod
    def preset(cls, name: str) -> PipelineConfig:
        """The configuration named ``name``: one of :data:`PRESETS`.

        Raises
        ------
        ConfigError
            If ``name`` is not a preset.
        """
        if name not in PRESETS:
            raise ConfigError(f"unknown preset {name!r}; known: {', '.join(PRESETS)}")
        return cls() if name == "default" else getattr(cls, name)()


#: the named configurations of ``pointrig extract --preset`` (:meth:`PipelineConfig.preset`)
PRESETS = ("default", "fast", "paper")


def _coerce(cls: type, stage: str, values: dict[str, Any]) -> Any:
    known = {f.name: f for f in fields(cls)}
    kwargs = {}
    for key, val in values.items():
        if key not in known:
            raise ConfigError(
                f"[{stage}] unknown parameter {key!r}; known: {', '.join(sorted(known))}"
            )
        default = getattr(cls(), key)
        if isinstance(default, bool) and not isinstance(val, bool):
            raise ConfigError(f"[{stage}] {key} must be true or false, got {val!r}")
        if known[key].type in ("str", str) and not isinstance(val, str):
            raise ConfigError(f"[{stage}] {key} must be a string, got {val!r}")
        if isinstance(default, float) and isinstance(val, int) and not isinstance(val, bool):
            val = float(val)
        if isinstance(val, list):
            val = tuple(val)
        kwargs[key] = val
    return cls(**kwargs)


def load_config(path: str | Path | None = None, base: PipelineConfig | None = None) -> PipelineConfig:
    """Read a TOML parameter file over ``base`` (default: Table 1 defaults).

    Raises
    ------
    ConfigError
        If the file is missing, not TOML, or names an unknown stage or parameter.
    """
    base = base or PipelineConfig()
    if path is None:
        return base
    p = Path(path)
    try:
        data = tomllib.loads(p.read_text())
    except FileNotFoundError:
        raise ConfigError(f"{p}: config file not found") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{p}: not valid TOML: {exc}") from None
    return apply_overrides(data, base, where=str(p))


def apply_overrides(data: dict[str, Any], base: PipelineConfig | None = None,
                    where: str = "overrides") -> PipelineConfig:
    """``base`` (default: Table 1 defaults) with ``{"stage": {"parameter": value}}`` on top,
    checked and coerced as a config file is (:func:`load_config`).

    Raises
    ------
    ConfigError
        If ``data`` names an unknown stage or parameter or a value is invalid; messages start
        with ``where``.
    """
    base = base or PipelineConfig()
    stages = {f.name: f for f in fields(PipelineConfig)}
    updates = {}
    for stage, values in data.items():
        if stage not in stages or not isinstance(values, dict):
            raise ConfigError(f"{where}: unknown section [{stage}]; known: {', '.join(stages)}")
        current = dataclasses.asdict(getattr(base, stage))
        current.update(values)
        updates[stage] = _coerce(type(getattr(base, stage)), stage, current)
    return dataclasses.replace(base, **updates)
