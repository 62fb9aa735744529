"""benchmarks/bench_generalise.py's seeds and paired comparison: a variant's seeds raised by the
run's seed, one sequence's runs averaged over the seeds, and the difference of two variants per
sequence with its sign-flip p-value. Oracles: the config's own fields, numpy over hand-built
rows, and the exhaustive sign-flip count written out here."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from benchmarks import bench_generalise as bg


def _row(recall: float, precision: float, n_pred: float, err: float) -> dict:
    return {"recall": recall, "precision": precision, "n_pred": n_pred, "n_scorable": 10,
            "n_matched": 5, "normalized_error_cm": err, "raw_error_cm": err,
            "far_fraction": 0.0, "n_far": 0, "n_duplicate": 1, "n_near_miss": 0,
            "subject_size_m": 1.7, "seconds": 1.0,
            "cpu_seconds": 2.0, "error": "", "group": "animal"}


def test_a_seed_raises_both_seeds_of_the_variant() -> None:
    """Seed 0 is the variant as given; seed k adds k to its registration and structure
    seeds, whatever they were set to, and changes nothing else."""
    base = bg.make_config('{"registration": {"seed": 3}, "joints": {"track_sweeps": 1}}')
    raised = bg.make_config('{"registration": {"seed": 3}, "joints": {"track_sweeps": 1}}', 2)
    assert (base.registration.seed, base.structure.seed) == (3, 0)
    assert (raised.registration.seed, raised.structure.seed) == (5, 2)
    assert raised.joints == base.joints and raised.preprocess == base.preprocess
    assert bg.make_config("paper", 1).structure.seed == bg.make_config("paper").structure.seed + 1


def test_seed_mean_averages_the_scored_runs() -> None:
    """Numbers are averaged over the runs that were scored; a missing precision or error
    (no joint out, no joint matched) is left out of its own mean only; a crashed run (None)
    is left out; nothing scored gives None."""
    rows = [_row(0.5, 0.4, 10, 2.0), None, _row(0.7, float("nan"), 0, float("nan"))]
    m = bg.seed_mean(rows)
    assert m is not None
    assert m["recall"] == pytest.approx(0.6)
    assert m["precision"] == pytest.approx(0.4)
    assert m["n_pred"] == pytest.approx(5.0)
    assert m["normalized_error_cm"] == pytest.approx(2.0)
    assert bg.seed_mean([None, None]) is None


def test_paired_line_reports_the_mean_difference_and_its_exact_p() -> None:
    """Five sequences: the F1 difference is the numpy mean of the per-sequence F1
    differences, and its p-value the share of the 32 sign patterns whose mean is at least as
    large, counted here by brute force."""
    base = [_row(r, p, 10, 2.0) for r, p in
            [(0.5, 0.5), (0.6, 0.4), (0.8, 0.7), (0.3, 0.3), (0.9, 0.6)]]
    run = [_row(r, p, 9, 2.5) for r, p in
           [(0.6, 0.5), (0.6, 0.5), (0.7, 0.7), (0.4, 0.4), (0.9, 0.8)]]
    f1 = lambda r, p: 2 * r * p / (r + p)  # noqa: E731
    d = np.array([f1(y["recall"], y["precision"]) - f1(x["recall"], x["precision"])
                  for x, y in zip(base, run)])
    hits = sum(abs(np.dot(s, d)) >= abs(d.sum()) - 1e-12
               for s in itertools.product((1, -1), repeat=5))
    line = bg.paired_line(base, run)
    assert line.startswith(f"F1 {d.mean():+.3f} (p {hits / 32:.2f})")
    assert "joints -1.0 (p 0.06)" in line and "norm cm +0.50 (p 0.06)" in line
    assert line.endswith(f"F1 up on {int((d > 0).sum())}, down on {int((d < 0).sum())} of 5")


def test_output_stage_variants_may_change_output_parameters_only() -> None:
    """``--output-stage`` reuses the defaults' steps 1-3, so a variant is refused when it
    changes any parameter those steps read (a seed, a tracker setting)."""
    bg.check_output_stage_variant('{"structure": {"joint_penalty": 1, "leaf_root": "keep"}, '
                                  '"joints": {"joint_depth": "off"}}')
    for bad in ('{"joints": {"track_sweeps": 1}}', '{"structure": {"seed": 1}}',
                '{"registration": {"refine_rounds": 0}}', "paper"):
        with pytest.raises(ValueError, match="not an output-stage parameter"):
            bg.check_output_stage_variant(bad)


def test_the_output_stage_rerun_gives_a_whole_runs_joints(tmp_path) -> None:
    """The oracle is a whole run: steps 1-3 of the defaults saved (through an ``.npz``, as the
    cache holds them), then the output stage of a variant, give exactly the joints of
    ``extract`` run whole with that variant (here the joint selection off, which changes the
    skeleton), and with the defaults those of the defaults' run."""
    from pointrig.data import demo_path
    from pointrig.io import read_sequence
    from pointrig.pipeline import extract

    seq = read_sequence(demo_path() / "frames", stop=12)
    base = extract(seq, bg.make_config("{}"), None, pictures=False)
    path = tmp_path / "inputs.npz"
    bg._save_npz(path, bg.output_stage_inputs(base))
    with np.load(path) as z:
        inputs = {k: z[k] for k in z.files}
    np.testing.assert_array_equal(bg.rerun_output_stage(inputs, bg.make_config("{}")),
                                  base.skeleton.joint_positions)
    variant = '{"structure": {"joint_penalty": 0}}'
    whole = extract(seq, bg.make_config(variant), None, pictures=False)
    again = bg.rerun_output_stage(inputs, bg.make_config(variant))
    assert again.shape != base.skeleton.joint_positions.shape
    np.testing.assert_array_equal(again, whole.skeleton.joint_positions)


def test_the_cached_steps_do_not_depend_on_the_output_stage_modules() -> None:
    """``--output-stage`` keys its cached steps 1-3 on the code less the output-stage modules,
    which holds while only the pipeline's output stage imports them (read from the sources),
    and the key differs from the whole pipeline's."""
    import re
    from pathlib import Path

    import pointrig

    root = Path(pointrig.__file__).resolve().parent
    stems = [m.removesuffix(".py") for m in bg.OUTPUT_STAGE_MODULES]
    pattern = re.compile(r"from \.(" + "|".join(stems) + r") import|import pointrig\.("
                         + "|".join(stems) + r")\b")
    importers = {p.name for p in root.rglob("*.py") if pattern.search(p.read_text("utf-8"))}
    assert importers <= {"pipeline.py", *bg.OUTPUT_STAGE_MODULES}
    assert bg.code_fingerprint(steps_1_to_3=True) != bg.code_fingerprint()
