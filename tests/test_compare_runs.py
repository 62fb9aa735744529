"""benchmarks/bench_suite.py's comparison of runs: saved ``--json`` runs compared on the
sequences they share, the error means over the sequences where every run matched a joint, the
paired sign-flip test, and the variant arguments."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from benchmarks import bench_suite as compare_runs
from benchmarks.sets import paper_config

from pointrig.config import PipelineConfig
from pointrig.errors import ConfigError


def _write(path: Path, runs: dict[str, tuple[float, float, float | None, float | None]]) -> Path:
    """A file in bench_suite's --json layout: ``"variant/repeat/name"`` -> report."""
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
    assert compare_runs.main(["--compare", str(a), str(b)]) == 0
    out = capsys.readouterr().out
    assert "s1" in out and " *" in out  # the second run differs from the first
    assert "run 1: recall 1.000 precision 0.500 raw 5.00 normalised 4.00" in out
    bad = tmp_path / "bad.json"
    bad.write_text("{}")
    assert compare_runs.main(["--compare", str(a), str(bad)]) == 1
    assert "bad.json: not a bench_suite --json file" in capsys.readouterr().err


def _sign_flip_oracle(d: np.ndarray) -> float:
    """Every sign pattern at once in numpy (rows of a +-1 matrix)."""
    n = len(d)
    signs = 1.0 - 2.0 * ((np.arange(2 ** n)[:, None] >> np.arange(n)) & 1)
    return float(np.mean(np.abs(signs @ d) >= abs(d.sum()) - 1e-12 * np.abs(d).sum()))


def test_sign_flip_p_against_an_enumeration_and_closed_forms() -> None:
    """Closed forms: n equal-signed differences reach |mean| only with all signs the same or
    all flipped, p = 2 / 2^n; no difference gives 1. Oracle: numpy over all 2^n patterns, and
    the sampled test (n > exact_up_to) within its Monte Carlo error of the enumeration."""
    assert compare_runs.sign_flip_p([0.1, 0.2, 0.3, 0.4]) == pytest.approx(2 / 16)
    assert compare_runs.sign_flip_p([0.0, 0.0]) == 1.0
    assert compare_runs.sign_flip_p([]) == 1.0
    assert compare_runs.sign_flip_p([0.05, -0.05]) == 1.0
    rng = np.random.default_rng(4)
    for n in (3, 7, 12):
        d = rng.normal(0.3, 1.0, size=n)
        assert compare_runs.sign_flip_p(list(d)) == pytest.approx(_sign_flip_oracle(d))
    d = rng.normal(0.4, 1.0, size=13)
    exact = _sign_flip_oracle(d)
    sampled = compare_runs.sign_flip_p(list(d), exact_up_to=12, samples=20000)
    assert abs(sampled - exact) < 4 * np.sqrt(exact * (1 - exact) / 20000) + 1e-3
    assert compare_runs.sign_flip_p(list(d), exact_up_to=13) == pytest.approx(exact)


def test_cli_prints_the_paired_differences(tmp_path, capsys) -> None:
    """Three sequences, every one higher in run 1: recall +0.1 with p = 2 / 8."""
    a = _write(tmp_path / "a.json", {f"0/0/s{i}": (0.5, 0.5, 0.05, 0.02) for i in range(3)})
    b = _write(tmp_path / "b.json", {f"0/0/s{i}": (0.6, 0.5, 0.05, 0.02) for i in range(3)})
    assert compare_runs.main(["--compare", str(a), str(b)]) == 0
    out = capsys.readouterr().out
    assert "run 1: recall +0.100 (p 0.25), precision +0.000 (p 1.00)" in out


def test_variant_arguments_give_their_configurations() -> None:
    """``{}`` is the default, a JSON object overrides its stage's fields, ``paper`` is the
    paper's reference, and the cap key is read off; bad JSON, a non-object, an unknown
    parameter and a bad cap are errors naming the variant."""
    assert compare_runs.variant_config("{}", "v0") == (PipelineConfig(), None)
    cfg, cap = compare_runs.variant_config(
        '{"registration": {"refine_rounds": 0}, "max_joints_from": "skinned"}', "v1")
    assert cfg.registration.refine_rounds == 0 and cap == "skinned"
    assert cfg.joints == PipelineConfig().joints
    assert compare_runs.variant_config(" paper ", "v2") == (paper_config(), None)
    with pytest.raises(ValueError):
        compare_runs.variant_config("{not json", "v3")
    with pytest.raises(ValueError, match="v4: a JSON object"):
        compare_runs.variant_config("[1]", "v4")
    with pytest.raises(ConfigError, match="v5.*unknown parameter 'nope'"):
        compare_runs.variant_config('{"joints": {"nope": 1}}', "v5")
    with pytest.raises(ValueError, match="max_joints_from"):
        compare_runs.variant_config('{"max_joints_from": "all"}', "v6")


def test_compare_needs_two_runs(tmp_path) -> None:
    """``--compare`` with one run is a usage error (exit status 2)."""
    a = _write(tmp_path / "a.json", {"0/0/s1": (1.0, 0.5, 0.05, 0.02)})
    with pytest.raises(SystemExit) as exc:
        compare_runs.main(["--compare", str(a)])
    assert exc.value.code == 2
