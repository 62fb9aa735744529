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


def test_pipeline_is_worker_count_independent(monkeypatch):
    """Step 1's forward and backward chains, a tracked frame's two hypotheses, the
    refinement's frames and step 2's ensemble seeds two at a time
    (``pointrig.registration._CHAIN_WORKERS``, ``pointrig.joints._TRACK_WORKERS``,
    ``pointrig.registration._REFINE_WORKERS``, ``pointrig.structure._ENSEMBLE_WORKERS``) give
    bit for bit the skeleton of one after the other."""
    import pointrig.joints as joints_mod
    import pointrig.registration as reg_mod
    import pointrig.structure as structure_mod
    from pointrig.config import PipelineConfig
    from pointrig.pipeline import extract

    syn = synthesize("arm", n_frames=8, seed=4, camera=Camera.kinect(320),
                     noise=NoiseConfig(seed=4))
    seq = syn.to_point_sequence()
    cfg = PipelineConfig()
    assert cfg.joints.track_from_structure and cfg.registration.refine_rounds >= 1
    assert cfg.structure.ensemble_seeds > 1
    assert min(joints_mod._TRACK_WORKERS, reg_mod._REFINE_WORKERS, reg_mod._CHAIN_WORKERS,
               structure_mod._ENSEMBLE_WORKERS) > 1
    side = extract(seq, cfg, None, pictures=False)
    monkeypatch.setattr(joints_mod, "_TRACK_WORKERS", 1)
    monkeypatch.setattr(reg_mod, "_REFINE_WORKERS", 1)
    monkeypatch.setattr(reg_mod, "_CHAIN_WORKERS", 1)
    monkeypatch.setattr(structure_mod, "_ENSEMBLE_WORKERS", 1)
    alone = extract(seq, cfg, None, pictures=False)
    np.testing.assert_array_equal(side.registration.points, alone.registration.points)
    np.testing.assert_array_equal(side.refined_registration.points,
                                  alone.refined_registration.points)
    np.testing.assert_array_equal(side.structure.labels, alone.structure.labels)
    np.testing.assert_array_equal(side.skeleton.joint_positions, alone.skeleton.joint_positions)
