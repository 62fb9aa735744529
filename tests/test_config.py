"""Parameters (pointrig.config): every bad value is refused where the config is made, naming
``[stage] field``; each stage's ``paper()`` is the paper's configuration and runs end to end."""

from __future__ import annotations

import dataclasses
import json
import re

import numpy as np
import pytest

from pointrig.config import (
    JointsConfig,
    PipelineConfig,
    PreprocessConfig,
    RegistrationConfig,
    RigConfig,
    StructureConfig,
    apply_overrides,
)
from pointrig.errors import ConfigError

STAGES = {PreprocessConfig: "preprocess", RegistrationConfig: "registration",
          StructureConfig: "structure", JointsConfig: "joints", RigConfig: "rig"}

#: (stage, field, a value it refuses): every field of every stage at least once
BAD = [
    (RigConfig, "fps", 0.0),
    (RigConfig, "fps", float("nan")),
    (RigConfig, "names", "human"),
    (RigConfig, "mesh", "yes"),
    (RigConfig, "usd", "usdz"),
    (RigConfig, "faces", 10),
    (RigConfig, "voxel", -0.01),
    (RigConfig, "fill_frames", -1),
    (RigConfig, "report", "html"),
    (RigConfig, "report_points", 0),
    (PreprocessConfig, "crop_min", (0.0, 1.0)),
    (PreprocessConfig, "crop_min", (0.0, float("nan"), 1.0)),
    (PreprocessConfig, "crop_max", (0.0, 0.0, "1")),
    (PreprocessConfig, "voxel_size", -0.01),
    (PreprocessConfig, "frame_start", -1),
    (PreprocessConfig, "frame_stop", 1.5),
    (PreprocessConfig, "frame_stride", 0),
    (PreprocessConfig, "min_points", 0),
    (PreprocessConfig, "max_extent", -1.0),
    (PreprocessConfig, "background", "remove"),
    (PreprocessConfig, "background_threshold", 0.0),
    (PreprocessConfig, "sparse_neighbors", 0),
    (PreprocessConfig, "sparse_ratio", 1.0),
    (PreprocessConfig, "sparse_ratio", float("inf")),
    (RegistrationConfig, "rest_frame", "middle"),
    (RegistrationConfig, "rest_frame", "visible"),
    (RegistrationConfig, "rest_frame", -1),
    (RegistrationConfig, "rest_frame", True),
    (RegistrationConfig, "rest_cover_tolerance", 1.0),
    (RegistrationConfig, "rest_candidates", 0),
    (RegistrationConfig, "rest_fit_margin", -0.1),
    (RegistrationConfig, "n_rest_points", 9),
    (RegistrationConfig, "n_nodes", 0),
    (RegistrationConfig, "k_point_nodes", 0),
    (RegistrationConfig, "k_node_neighbors", -1),
    (RegistrationConfig, "node_geodesic_ratio", 0.5),
    (RegistrationConfig, "omega", 1.0),
    (RegistrationConfig, "beta_smooth", -1.0),
    (RegistrationConfig, "beta_small", float("nan")),
    (RegistrationConfig, "sigma2_init", 0.0),
    (RegistrationConfig, "max_iterations", 0),
    (RegistrationConfig, "tolerance", -1e-5),
    (RegistrationConfig, "seed", -1),
    (RegistrationConfig, "solver", "newton"),
    (RegistrationConfig, "beta_smooth_mode", "auto"),
    (RegistrationConfig, "beta_smooth_rel", -0.1),
    (RegistrationConfig, "sigma2_start", "residual"),
    (RegistrationConfig, "sigma2_start_max", 0.0),
    (RegistrationConfig, "sigma2_min", -1e-5),
    (RegistrationConfig, "sigma2_anneal", 0.0),
    (RegistrationConfig, "sigma2_anneal", 1.5),
    (RegistrationConfig, "rigid_iterations", -1),
    (RegistrationConfig, "predict_velocity", -1.0),
    (RegistrationConfig, "predict_check", 1.5),
    (RegistrationConfig, "cutoff", -3.5),
    (RegistrationConfig, "gn_damping", -1.0),
    (RegistrationConfig, "cg_tolerance", 0.0),
    (RegistrationConfig, "cg_max_iterations", 0),
    (RegistrationConfig, "subsample", -1.0),
    (RegistrationConfig, "normal_kappa", -1.0),
    (RegistrationConfig, "normal_radius", 0.0),
    (RegistrationConfig, "motion_tol", -0.1),
    (RegistrationConfig, "lost_fraction", 1.0),
    (RegistrationConfig, "sor_neighbors", 0),
    (RegistrationConfig, "sor_std_ratio", 0.0),
    (RegistrationConfig, "mls_neighbors", -1),
    (RegistrationConfig, "rest_sparse_neighbors", 0),
    (RegistrationConfig, "rest_sparse_ratio", 0.5),
    (RegistrationConfig, "refine_rounds", 1.5),
    (RegistrationConfig, "workers", -1),
    (StructureConfig, "n_clusters", 0),
    (StructureConfig, "cluster_rounds", -1),
    (StructureConfig, "seed", 0.5),
    (StructureConfig, "ensemble_seeds", 0),
    (StructureConfig, "ensemble_radius", 0.0),
    (StructureConfig, "kmeans_iterations", 0),
    (StructureConfig, "trajectory_weight", -1.0),
    (StructureConfig, "kmeans_frames", 0),
    (StructureConfig, "vote_neighbors", 0),
    (StructureConfig, "vote_radius_ratio", 0.0),
    (StructureConfig, "vote_guard_ratio", -1.0),
    (StructureConfig, "post_merge_rounds", -1),
    (StructureConfig, "neighbor_stretch", 0.5),
    (StructureConfig, "touch_min_pairs", 0),
    (StructureConfig, "graph_radius_ratio", 0.0),
    (StructureConfig, "bridge_joint_prior", -0.05),
    (StructureConfig, "bridge_gap_weight", -0.1),
    (StructureConfig, "edge_weight", "swap"),
    (StructureConfig, "edge_joint_prior", float("inf")),
    (StructureConfig, "merge_angle_deg", 0.0),
    (StructureConfig, "merge_rule", "displacement"),
    (StructureConfig, "merge_displacement", 0.0),
    (StructureConfig, "merge_percentile", 101.0),
    (StructureConfig, "noise_margin", -1.0),
    (StructureConfig, "noise_corr_exponent", 1.5),
    (StructureConfig, "min_cluster_fraction", 1.0),
    (StructureConfig, "leaf_min_fraction", -0.01),
    (StructureConfig, "band_ratio", -1.5),
    (StructureConfig, "short_bone_ratio", -0.75),
    (StructureConfig, "invisible_bone_fraction", -0.005),
    (StructureConfig, "refine_passes", -1),
    (StructureConfig, "max_joints", -1),
    (StructureConfig, "eta", -1.0),
    (StructureConfig, "root_end_alignment", 1.5),
    (StructureConfig, "root_choice", "center"),
    (StructureConfig, "leaf_root", "middle"),
    (StructureConfig, "centre_tolerance", 1.0),
    (StructureConfig, "joint_penalty", -1.0),
    (StructureConfig, "joint_frames", 0),
    (StructureConfig, "view_depth_quantile", 0.5),
    (StructureConfig, "camera_position", None),
    (StructureConfig, "single_view", "maybe"),
    (StructureConfig, "workers", 2.0),
    (JointsConfig, "omega", -0.01),
    (JointsConfig, "eta", float("nan")),
    (JointsConfig, "zeta", -1.0),
    (JointsConfig, "gamma", -0.1),
    (JointsConfig, "alpha_init", -1.0),
    (JointsConfig, "alpha_growth", 0.0),
    (JointsConfig, "max_bones_per_point", 0),
    (JointsConfig, "tau_init", 0.0),
    (JointsConfig, "tau_min", 0.0),
    (JointsConfig, "max_iterations", -1),
    (JointsConfig, "tolerance", -1.0),
    (JointsConfig, "mode", "soft"),
    (JointsConfig, "joint_prior", -1.0),
    (JointsConfig, "gmm_density_normalize", 1),
    (JointsConfig, "weight_candidates", "some"),
    (JointsConfig, "update_weights", "yes"),
    (JointsConfig, "zeta_scale", -0.001),
    (JointsConfig, "tau_init_relative", None),
    (JointsConfig, "joint_tolerance", -5e-4),
    (JointsConfig, "min_iterations", -1),
    (JointsConfig, "bone_sweeps", 0),
    (JointsConfig, "rotation_smoothing", -0.01),
    (JointsConfig, "bone_twist", "none"),
    (JointsConfig, "twist_min_elongation", -2.0),
    (JointsConfig, "twist_min_roll_deg", 270.0),
    (JointsConfig, "joint_depth", "quantile"),
    (JointsConfig, "depth_frames", 0),
    (JointsConfig, "init", "registration"),
    (JointsConfig, "track_iterations", 0),
    (JointsConfig, "track_sweeps", 0),
    (JointsConfig, "track_velocity", -1.0),
    (JointsConfig, "track_tau_max", 0.0),
    (JointsConfig, "track_anneal", 0.0),
    (JointsConfig, "track_predict_check", 2.0),
    (JointsConfig, "track_normal_kappa", -1.0),
    (JointsConfig, "normal_radius", 0.0),
    (JointsConfig, "estep_radius_sigmas", 0.0),
    (JointsConfig, "estep_max_points", -1),
    (JointsConfig, "workers", True),
]


@pytest.mark.parametrize("cls,name,value", BAD,
                         ids=[f"{STAGES[c]}.{n}={v!r}" for c, n, v in BAD])
def test_a_bad_value_is_a_config_error_naming_stage_and_field(cls, name, value):
    with pytest.raises(ConfigError, match=rf"^\[{STAGES[cls]}\] {name} must be"):
        cls(**{name: value})
    # the same through a config file's overrides (booleans and strings are checked there)
    with pytest.raises(ConfigError, match=rf"\[{STAGES[cls]}\] {name} must be"):
        apply_overrides({STAGES[cls]: {name: list(value) if isinstance(value, tuple)
                                       else value}})


def test_every_field_has_a_bad_value_case():
    covered = {(cls, name) for cls, name, _ in BAD}
    for cls in STAGES:
        for f in dataclasses.fields(cls):
            assert (cls, f.name) in covered, f"{cls.__name__}.{f.name}"


def test_cross_field_checks_name_the_field():
    with pytest.raises(ConfigError, match=r"^\[preprocess\] crop_max must be above crop_min"):
        PreprocessConfig(crop_min=(0.0, 0.0, 0.0), crop_max=(1.0, 0.0, 1.0))
    with pytest.raises(ConfigError, match=r"^\[preprocess\] frame_stop must be None or above"):
        PreprocessConfig(frame_start=5, frame_stop=5)
    assert PreprocessConfig(crop_min=(0, 0, 0), crop_max=(1, 1, 1), frame_start=2,
                            frame_stop=3).frame_stop == 3


def test_off_values_and_open_ends_are_accepted():
    """The documented "0 = off" values and the limits of each range are valid."""
    PreprocessConfig(sparse_ratio=0.0, voxel_size=0.0, max_extent=0.0)
    RegistrationConfig(rest_frame=0, node_geodesic_ratio=0.0, rest_sparse_ratio=0.0,
                       cutoff=0.0, subsample=0.0, motion_tol=0.0, lost_fraction=0.0,
                       normal_kappa=0.0, mls_neighbors=0, refine_rounds=0, sigma2_anneal=1.0,
                       predict_check=0.0, workers=1)
    StructureConfig(neighbor_stretch=0.0, vote_guard_ratio=0.0, band_ratio=0.0,
                    invisible_bone_fraction=0.0, view_depth_quantile=0.0, max_joints=3)
    StructureConfig(view_depth_quantile=1.0, root_end_alignment=0.0)
    JointsConfig(max_iterations=0, alpha_init=0.0, zeta=0.0, joint_tolerance=0.0,
                 rotation_smoothing=0.0, estep_max_points=0, track_anneal=1.0)


def test_paper_presets_hold_table1_and_the_papers_method():
    """Table 1 and §7.2's values; the paper's choice wherever pointrig has its own."""
    pre, reg = PreprocessConfig.paper(), RegistrationConfig.paper()
    st, jt = StructureConfig.paper(), JointsConfig.paper()
    assert pre.background == "keep" and pre.sparse_ratio == 0.0
    # §4, Table 1, §7.2
    assert (reg.omega, reg.beta_smooth, reg.beta_small, reg.sigma2_init) == (0.01, 1e5, 1.0,
                                                                            6e-4)
    assert reg.solver == "sweeps" and reg.beta_smooth_mode == "fixed"
    assert reg.sigma2_start == "fixed" and reg.rest_frame == 0
    assert (reg.rigid_iterations, reg.predict_velocity, reg.sigma2_anneal, reg.normal_kappa,
            reg.node_geodesic_ratio, reg.subsample, reg.motion_tol, reg.refine_rounds) == (
        0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0)
    # §5
    assert st.edge_weight == "eq15" and st.root_choice == "centroid"
    assert st.ensemble_seeds == 1 and st.merge_rule == "angle" and st.single_view == "no"
    assert st.cluster_rounds == 10 and st.eta == 1.0 and st.root_end_alignment == 0.0
    assert (st.vote_guard_ratio, st.neighbor_stretch, st.band_ratio,
            st.invisible_bone_fraction) == (0.0,) * 4
    assert st.leaf_root == "keep" and st.joint_penalty == 0.0
    assert st.leaf_min_fraction == 0.01 and StructureConfig().leaf_min_fraction == 0.0
    # §6, Algorithm 2, Table 1, §7.2
    assert (jt.omega, jt.eta, jt.zeta, jt.gamma, jt.tau_init) == (0.01, 1.0, 1e4, 0.1, 6e-4)
    assert jt.mode == "paper" and jt.init == "structure" and jt.alpha_init is None
    assert jt.alpha_growth == 1.45 and jt.max_iterations == 20 and jt.zeta_scale == 1.0
    assert jt.update_weights and jt.weight_candidates == "all"
    assert not jt.gmm_density_normalize and not jt.tau_init_relative
    assert jt.joint_tolerance == 0.0 and jt.rotation_smoothing == 0.0
    assert jt.bone_twist == "fit" and jt.joint_depth == "off" and jt.estep_max_points == 0
    # overrides on top, checked as usual
    assert RegistrationConfig.paper(rest_frame=3).rest_frame == 3
    with pytest.raises(ConfigError, match=r"\[joints\] zeta must be"):
        JointsConfig.paper(zeta=-1.0)
    cfg = PipelineConfig.paper()
    assert (cfg.preprocess, cfg.registration, cfg.structure, cfg.joints) == (pre, reg, st, jt)
    json.dumps(cfg.to_dict())


def test_paper_pipeline_runs_end_to_end(tmp_path):
    """``PipelineConfig.paper()`` on a short synthetic arm: the paper's registration (node
    sweeps from the first frame), structure (Eq. 15 tree, centroid root) and Algorithm 2 as
    printed give a valid skeleton: one tree, finite joints in every frame, 4-sparse convex
    weights, written and read back as the skeleton contract."""
    from pointrig.pipeline import extract
    from pointrig.skeleton import load_skeleton_json
    from pointrig.synth import Camera, NoiseConfig, synthesize

    syn = synthesize("arm", n_frames=5, seed=2, camera=Camera.kinect(320),
                     noise=NoiseConfig(seed=2))
    seq = syn.to_point_sequence()
    cfg = PipelineConfig.paper()
    res = extract(seq, cfg, tmp_path, pictures=False)
    reg, jr, sk = res.registration, res.joints, res.skeleton
    assert reg.params["solver"] == "sweeps" and reg.params["rest_frame_index"] == 0
    assert res.refined_registration is None
    assert jr.diagnostics["mode"] == "paper" and jr.diagnostics["init"] == "structure"
    alpha = jr.diagnostics["alpha"]
    assert alpha[0] == pytest.approx(cfg.joints.zeta * len(reg.rest_points))
    np.testing.assert_allclose(np.diff(alpha) / np.asarray(alpha[:-1]), 0.45, rtol=1e-12)
    J = sk.n_joints
    assert J >= 2
    parents = np.asarray(sk.parents)
    assert int(np.sum(parents < 0)) == 1
    for j in range(J):  # every joint reaches the root: a tree
        seen, k = set(), j
        while parents[k] >= 0:
            assert k not in seen
            seen.add(k)
            k = parents[k]
    assert sk.joint_positions.shape == (seq.n_frames, J, 3)
    assert np.isfinite(sk.joint_positions).all()
    W = sk.weights
    assert np.all(W >= 0) and np.allclose(W.sum(1), 1.0) and np.all((W > 0).sum(1) <= 4)
    back = load_skeleton_json(tmp_path / "skeleton.json")
    np.testing.assert_allclose(back.joint_positions, sk.joint_positions, atol=1e-6)  # µm JSON
    doc = json.loads((tmp_path / "skeleton.json").read_text())
    assert doc["params"]["joints"]["mode"] == "paper"
    assert re.fullmatch(r"j\d+", back.joint_names[0])


def test_presets_by_name():
    """:meth:`PipelineConfig.preset` names the default, fast and paper configurations; any
    other name is a one-line ConfigError listing them."""
    from pointrig.config import PRESETS

    assert PRESETS == ("default", "fast", "paper")
    assert PipelineConfig.preset("default") == PipelineConfig()
    assert PipelineConfig.preset("paper") == PipelineConfig.paper()
    assert PipelineConfig.preset("fast") == PipelineConfig.fast() != PipelineConfig()
    with pytest.raises(ConfigError, match="unknown preset 'quick'; known: default, fast, paper"):
        PipelineConfig.preset("quick")
