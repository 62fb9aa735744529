"""Same seed, same result, whatever the thread count.

The whole pipeline runs in two fresh processes with RAYON_NUM_THREADS=1 and =2 on the same
synthetic sequence; joint trajectories must agree to 1e-9 m (the kernels reduce in a fixed
order, so in practice they agree bit for bit).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np

from pointrig.synth import Camera, NoiseConfig, synthesize

TOL_M = 1e-9


def test_pipeline_is_thread_count_independent(tmp_path):
    syn = synthesize("arm", n_frames=6, seed=3, camera=Camera.kinect(320),
                     noise=NoiseConfig(seed=3))
    syn.write(tmp_path / "seq")
    outs = []
    for threads in (1, 2):
        out = tmp_path / f"out{threads}"
        env = dict(os.environ, RAYON_NUM_THREADS=str(threads))
        subprocess.run([sys.executable, "-m", "pointrig", "extract", str(tmp_path / "seq" / "frames"),
                        "-o", str(out), "-q", "--no-pictures"], check=True, env=env,
                       capture_output=True)
        outs.append(json.loads((out / "skeleton.json").read_text()))
    a, b = outs
    assert [j["parent"] for j in a["joints"]] == [j["parent"] for j in b["joints"]]
    np.testing.assert_allclose(np.asarray(a["joint_positions"]),
                               np.asarray(b["joint_positions"]), atol=TOL_M, rtol=0)


def test_pipeline_is_worker_count_independent():
    """Step 1's forward and backward chains, the refinement's frames, step 2's ensemble seeds
    and a tracked frame's two hypotheses run side by side on ``workers`` threads
    (``[registration]``, ``[structure]``, ``[joints] workers``): two workers give bit for bit
    the skeleton of one (one after the other)."""
    import dataclasses

    from pointrig.config import PipelineConfig
    from pointrig.pipeline import extract

    syn = synthesize("arm", n_frames=8, seed=4, camera=Camera.kinect(320),
                     noise=NoiseConfig(seed=4))
    seq = syn.to_point_sequence()

    def with_workers(n: int) -> PipelineConfig:
        cfg = PipelineConfig()
        return dataclasses.replace(
            cfg, registration=dataclasses.replace(cfg.registration, workers=n),
            structure=dataclasses.replace(cfg.structure, workers=n),
            joints=dataclasses.replace(cfg.joints, workers=n))

    cfg = with_workers(2)
    assert cfg.registration.refine_rounds >= 1 and cfg.structure.ensemble_seeds > 1
    assert cfg.joints.init == "track"
    side = extract(seq, cfg, None, pictures=False)
    alone = extract(seq, with_workers(1), None, pictures=False)
    np.testing.assert_array_equal(side.registration.points, alone.registration.points)
    np.testing.assert_array_equal(side.refined_registration.points,
                                  alone.refined_registration.points)
    np.testing.assert_array_equal(side.structure.labels, alone.structure.labels)
    np.testing.assert_array_equal(side.joints.R, alone.joints.R)
    np.testing.assert_array_equal(side.skeleton.joint_positions, alone.skeleton.joint_positions)


def test_pool_size_follows_workers_and_tasks(monkeypatch):
    """``workers = 0`` means the machine's cores; never more threads than tasks, never none."""
    from pointrig.config import pool_size

    monkeypatch.setattr(os, "cpu_count", lambda: 6)
    assert pool_size(0, 100) == 6 and pool_size(0, 2) == 2
    assert pool_size(3, 100) == 3 and pool_size(3, 1) == 1 and pool_size(1, 0) == 1
    monkeypatch.setattr(os, "cpu_count", lambda: None)
    assert pool_size(0, 4) == 1


def test_rest_frame_candidates_side_by_side_equal_one_after_another():
    """The rest-frame candidates of ``rest_frame = "fit"`` register side by side on
    ``[registration] workers`` threads: with two workers the chosen registration and every
    candidate's misfit are bit for bit those of one worker (one after the other), on a
    sequence with three candidates."""
    from pointrig.config import RegistrationConfig
    from pointrig.registration import register_sequence, rest_candidates

    syn = synthesize("human", n_frames=8, seed=4, camera=Camera.kinect(320),
                     noise=NoiseConfig(seed=4), speed=3.0)
    seq = syn.to_point_sequence()
    assert len(rest_candidates(RegistrationConfig(rest_candidates=3), seq.frames)) == 3
    side = register_sequence(seq, RegistrationConfig(rest_candidates=3, workers=2))
    alone = register_sequence(seq, RegistrationConfig(rest_candidates=3, workers=1))
    assert side.params["rest_candidates_misfit"] == alone.params["rest_candidates_misfit"]
    assert side.params["rest_frame_index"] == alone.params["rest_frame_index"]
    np.testing.assert_array_equal(side.rest_points, alone.rest_points)
    np.testing.assert_array_equal(side.points, alone.points)
