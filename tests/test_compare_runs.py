"""benchmarks/compare_runs.py: saved ``bench_suite.py --json`` runs compared on the sequences
they share, the error means over the sequences where every run matched a joint."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import compare_runs  # noqa: E402


def _write(path: Path, runs: dict[str, tuple[float, float, float | None, float | None]]) -> Path:
    """A file in bench_suite.py's --json layout: ``"variant/repeat/name"`` -> report."""
    body = {k: {"recall": r, "precision": p, "raw_error": raw, "normalized_error": nrm,
                "seconds": 1.0} for k, (r, p, raw, nrm) in runs.items()}
    path.write_text(json.dumps({"variants": [{}], "runs": body}))
    return path


def test_means_cover_the_shared_sequences_and_the_errors_where_all_matched(tmp_path) -> None:
    """Recall and precision average over the sequences both files hold; the errors only over
    those where both matched a joint; a sequence of one file only is left out. Oracle: numpy
    over hand-built arrays."""
    a = _write(tmp_path / "a.json", {
        "0/0/s1": (1.0, 0.5, 0.05, 0.02), "0/0/s2": (0.5, 0.25, 0.08, 0.04),
        "0/0/s3": (0.0, 0.0, None, None), "0/0/only_a": (1.0, 1.0, 0.01, 0.01),
        "0/1/s1": (0.1, 0.1, 0.9, 0.9)})  # another repeat: not read by default
    b = _write(tmp_path / "b.json", {
        "0/0/s1": (0.8, 0.4, 0.06, 0.03), "0/0/s2": (0.5, 0.5, None, None),
        "0/0/s3": (0.2, 0.1, 0.10, 0.05)})
    runs = [compare_runs.load_run(str(a)), compare_runs.load_run(str(b))]
    names, matched, means = compare_runs.common_means(runs)
    assert names == ["s1", "s2", "s3"]
    assert matched == ["s1"]
    np.testing.assert_allclose(means[0], [np.mean([1.0, 0.5, 0.0]), np.mean([0.5, 0.25, 0.0]),
                                          0.05, 0.02])
    np.testing.assert_allclose(means[1], [np.mean([0.8, 0.5, 0.2]), np.mean([0.4, 0.5, 0.1]),
                                          0.06, 0.03])


def test_variant_and_repeat_are_chosen_by_the_argument(tmp_path) -> None:
    f = _write(tmp_path / "r.json", {"0/0/s": (1.0, 1.0, 0.01, 0.01),
                                     "1/2/s": (0.5, 0.5, 0.02, 0.03)})
    assert compare_runs.load_run(str(f)).rows["s"][0] == 1.0
    assert compare_runs.load_run(f"{f}:1@2").rows["s"] == (0.5, 0.5, 0.02, 0.03)
    with pytest.raises(ValueError, match="no runs of variant 0 repeat 3.*0/0, 1/2"):
        compare_runs.load_run(f"{f}@3")


def test_cli_prints_the_table_and_fails_cleanly_on_a_bad_file(tmp_path, capsys) -> None:
    a = _write(tmp_path / "a.json", {"0/0/s1": (1.0, 0.5, 0.05, 0.02)})
    b = _write(tmp_path / "b.json", {"0/0/s1": (1.0, 0.5, 0.05, 0.04)})
    assert compare_runs.main([str(a), str(b)]) == 0
    out = capsys.readouterr().out
    assert "s1" in out and " *" in out  # the second run differs from the first
    assert "run 1: recall 1.000 precision 0.500 raw 5.00 normalised 4.00" in out
    bad = tmp_path / "bad.json"
    bad.write_text("{}")
    assert compare_runs.main([str(a), str(bad)]) == 1
    assert "bad.json: not a bench_suite.py --json file" in capsys.readouterr().err
