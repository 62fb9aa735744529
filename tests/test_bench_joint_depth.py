"""benchmarks/bench_joint_depth.py applies each reading of the joint-depth pass to one
pipeline run; its "off" and "visible" rows must be what the pipeline itself gives with the
pass off and with the default (the oracle: two full runs of :func:`pointrig.pipeline.extract`)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import bench_joint_depth  # noqa: E402
import bench_refine  # noqa: E402
from bench_registration_downstream import score_joints  # noqa: E402

from pointrig.config import PipelineConfig, apply_overrides  # noqa: E402
from pointrig.pipeline import extract  # noqa: E402


def test_bench_rows_match_the_pipeline_with_the_pass_off_and_on(capsys):
    seqs = {"upper_body": ("upper_body", {"seed": 2})}
    rows = bench_joint_depth.run(seqs, set(), 16, 10)
    assert set(rows) == {v[0] for v in bench_joint_depth.VARIANTS}
    syn = next(bench_refine.suite(16, set(), seqs))[1]
    seq = syn.to_point_sequence()
    for label, cfg in (("off", apply_overrides({"joints": {"joint_depth": "off"}})),
                       ("visible", PipelineConfig())):
        r = score_joints(extract(seq, cfg, None, pictures=False).skeleton.joint_positions, syn)
        got = rows[label]["upper_body"]
        assert got[0] == r.recall and got[1] == r.precision
        assert got[3] == pytest.approx(r.raw_error, abs=1e-6)
    assert rows["visible"]["upper_body"][3] != rows["off"]["upper_body"][3]  # joints moved
    assert "upper_body" in capsys.readouterr().out
