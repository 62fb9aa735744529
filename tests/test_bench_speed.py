"""The serial reference form of benchmarks/bench_speed.py."""

from __future__ import annotations

import numpy as np
import pytest
from benchmarks import bench_speed

import pointrig.joints as joints_mod
import pointrig.registration as reg_mod
from pointrig.config import PipelineConfig
from pointrig.geometry import (
    chamfer_misfit,
    farthest_point_sampling,
    nearest_distances,
    remove_sparse_points,
)


def test_full_search_chamfer_equals_the_capped_search() -> None:
    """The reference chamfer (every search to the end, capped afterwards) and the pipeline's
    (searches stopped at the cap) against all pairwise distances in numpy, with caps below,
    inside and above the distances' range."""
    rng = np.random.default_rng(5)
    a = rng.normal(size=(300, 3))
    b = rng.normal(size=(500, 3)) + [0.8, 0.0, 0.0]
    d = np.linalg.norm(a[:, None] - b[None], axis=2)
    for cap in (1e-3, 0.2, 0.5, 50.0):
        ref = np.minimum(d.min(1), cap).mean() + np.minimum(d.min(0), cap).mean()
        assert bench_speed.chamfer_full_search(a, b, cap) == pytest.approx(ref, rel=1e-12)
        assert chamfer_misfit(a, b, cap) == pytest.approx(ref, rel=1e-12)


def test_serial_form_sets_and_restores_its_functions() -> None:
    """Inside ``serial()`` every worker count is 1 and the modules use the reference chamfer;
    afterwards (also after an error) the defaults are back. Every module-level worker count
    of the package is one the serial form sets."""

    before = {(m, n): getattr(m, n) for m, n in bench_speed.PATCHED}
    with pytest.raises(RuntimeError):
        with bench_speed.serial():
            assert joints_mod.chamfer_misfit is bench_speed.chamfer_full_search
            assert reg_mod.chamfer_misfit is bench_speed.chamfer_full_search
            for m, n in bench_speed.FUNCTIONS:
                assert getattr(m, n) is bench_speed.REFERENCE[n]
            raise RuntimeError("inside")
    assert {(m, n): getattr(m, n) for m, n in bench_speed.PATCHED} == before
    cfg = bench_speed.serial_config(PipelineConfig())
    assert (cfg.registration.workers, cfg.structure.workers, cfg.joints.workers) == (1, 1, 1)


def test_reference_forms_equal_the_pipeline_s() -> None:
    """The reference forms (numpy farthest-point loop, scipy k-d tree sparse filter and nearest
    distances) give what the pipeline's Rust grid gives, so the serial form does the same
    arithmetic."""
    rng = np.random.default_rng(8)
    pts = rng.normal(size=(3000, 3)) * [0.3, 0.8, 0.1]
    pts[:40] = rng.uniform(-3, 3, (40, 3))
    np.testing.assert_array_equal(bench_speed.fps_numpy(pts, 300, 4),
                                  farthest_point_sampling(pts, 300, 4))
    np.testing.assert_array_equal(bench_speed.remove_sparse_kd(pts, 10, 4.0),
                                  remove_sparse_points(pts, 10, 4.0))
    q = rng.normal(size=(500, 3))
    np.testing.assert_allclose(bench_speed.nearest_kd(q, pts), nearest_distances(q, pts),
                               rtol=0, atol=1e-12)


def test_preset_table_times_the_defaults_against_the_preset(capsys) -> None:
    """``--preset fast`` prints a default row, a fast row with each form's joint count and
    a speed-up row whose total is the ratio of the two rows' totals as printed."""
    assert bench_speed.main(["--preset", "fast", "--only", "upper_body", "--frames", "6"]) == 0
    rows = {ln.split()[1]: ln.split()[2:] for ln in capsys.readouterr().out.splitlines()
            if ln.startswith("upper_body")}
    assert set(rows) == {"default", "fast", "speed-up"}
    total = len(bench_speed.STAGES)
    t_default, t_fast = (float(rows[f][total].rstrip("s")) for f in ("default", "fast"))
    assert float(rows["speed-up"][total].rstrip("x")) == pytest.approx(t_default / t_fast,
                                                                        abs=0.01)
    assert int(rows["default"][-1]) >= 2 and int(rows["fast"][-1]) >= 2
