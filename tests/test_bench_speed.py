"""The serial reference form of benchmarks/bench_speed.py."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import bench_speed  # noqa: E402

import pointrig.joints as joints_mod  # noqa: E402
import pointrig.registration as reg_mod  # noqa: E402
from pointrig.preprocess import chamfer_misfit  # noqa: E402


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


def test_serial_form_sets_and_restores_the_workers() -> None:
    """Inside ``serial()`` every worker count is 1 and the modules use the reference chamfer;
    afterwards (also after an error) the defaults are back. Every module-level worker count
    of the package is one the serial form sets."""
    import pointrig

    before = {(m, n): getattr(m, n) for m, n in bench_speed.PATCHED}
    with pytest.raises(RuntimeError):
        with bench_speed.serial():
            assert all(getattr(m, n) == 1 for m, n in bench_speed.WORKERS)
            assert joints_mod.chamfer_misfit is bench_speed.chamfer_full_search
            assert reg_mod.chamfer_misfit is bench_speed.chamfer_full_search
            raise RuntimeError("inside")
    assert {(m, n): getattr(m, n) for m, n in bench_speed.PATCHED} == before
    assert all(v > 1 for (m, n), v in before.items() if n.endswith("_WORKERS"))
    found = set()
    for path in Path(pointrig.__file__).parent.glob("*.py"):
        for line in path.read_text().splitlines():
            if line.startswith("_") and line.split("=")[0].strip().endswith("_WORKERS"):
                found.add((path.stem, line.split("=")[0].strip()))
    assert found == {(m.__name__.rsplit(".", 1)[1], n) for m, n in bench_speed.WORKERS}
