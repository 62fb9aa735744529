"""The sequence sets of benchmarks/sets.py: the held-back sets share nothing with the suite
or with each other, every entry names a figure or a rig, and the options choose among them."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pytest
from benchmarks import sets as bench_sets

from pointrig.config import PipelineConfig, RegistrationConfig
from pointrig.sequence import PointSequence
from pointrig.synth import FIGURES


def _key(source: str, kw: dict) -> tuple:
    return (Path(source).name, tuple(sorted(kw.items())))


def test_validation_set_is_disjoint_from_the_suite() -> None:
    """No name, and no (figure or rig, synthesis keywords) pair, is in both sets; every seed of
    the validation set is one the suite does not use, so its noise and motion are new too."""
    suite, val = bench_sets.SEQUENCES, bench_sets.VALIDATION
    assert not set(suite) & set(val)
    assert not {_key(*v) for v in suite.values()} & {_key(*v) for v in val.values()}
    assert not {kw["seed"] for _, kw in suite.values()} & {kw["seed"] for _, kw in val.values()}
    assert set(bench_sets.SETS) == {"suite", "validation", "fresh", "spread", "all", "limbs",
                                    "hands"}


@pytest.mark.parametrize("held", ["fresh", "spread"])
def test_later_held_back_sets_are_disjoint_from_the_earlier_sets(held: str) -> None:
    """The second and third held-back sets share no name, (source, keywords) pair or seed with
    the suite, the validation set or each other."""
    later = bench_sets.SETS[held]
    earlier = {"fresh": ("suite", "validation"), "spread": ("suite", "validation", "fresh")}
    for other in (bench_sets.SETS[k] for k in earlier[held]):
        assert not set(later) & set(other)
        assert not {_key(*v) for v in later.values()} & {_key(*v) for v in other.values()}
        assert not ({kw["seed"] for _, kw in later.values()}
                    & {kw["seed"] for _, kw in other.values()})


def test_hands_set_is_new_hands() -> None:
    """The hands set holds only the procedural hand, at seeds no hand of another set uses, and
    shares no name or (source, keywords) pair with any other set."""
    hands = bench_sets.HANDS
    assert {src for src, _ in hands.values()} == {"hand"}
    others = [v for k, v in bench_sets.SETS.items() if k != "hands"]
    other_hand_seeds = {kw["seed"] for o in others for src, kw in o.values() if src == "hand"}
    assert not {kw["seed"] for _, kw in hands.values()} & other_hand_seeds
    for o in others:
        assert not set(hands) & set(o)
        assert not {_key(*v) for v in hands.values()} & {_key(*v) for v in o.values()}


#: The entries of every set, by name (ALL is the union of four of them).
_ENTRIES = {**bench_sets.ALL, **bench_sets.LIMBS, **bench_sets.HANDS}


@pytest.mark.parametrize("name", sorted(_ENTRIES))
def test_entries_name_a_figure_or_a_rig(name: str) -> None:
    """Each source is a procedural figure or a .glb in the models folder, and the keywords
    are ones the benchmark's synthesis takes, with a seed."""
    source, kw = _ENTRIES[name]
    if source.endswith(".glb"):
        assert Path(source).parent == bench_sets.MODELS
    else:
        assert source in FIGURES
    assert set(kw) <= {"seed", "yaw", "walk", "clip", "start", "camera"}
    assert "seed" in kw


def test_selected_checks_names_against_the_chosen_set() -> None:
    """``--only`` names are checked against the set in use: a validation name is unknown to
    the suite and known to the validation set."""
    ap = argparse.ArgumentParser()
    assert bench_sets.selected(ap, "v_hand,v_human", bench_sets.VALIDATION) == {
        "v_hand", "v_human"}
    with pytest.raises(SystemExit):
        bench_sets.selected(ap, "v_hand")
    with pytest.raises(SystemExit):
        bench_sets.selected(ap, "human", bench_sets.VALIDATION)


def test_suite_iterates_the_chosen_set(monkeypatch: pytest.MonkeyPatch) -> None:
    """``suite(..., sequences)`` yields the chosen set's names in order, synthesising each
    with its own keywords."""
    calls = []
    monkeypatch.setattr(bench_sets, "synthesize_entry", lambda src, kw, frames: calls.append(
        (src, kw, frames)) or len(calls))
    sub = {n: bench_sets.VALIDATION[n] for n in ("v_human", "v_hand")}
    got = list(bench_sets.suite(5, set(), sub))
    assert [n for n, _ in got] == ["v_human", "v_hand"]
    assert calls == [(s, kw, 5) for s, kw in sub.values()]


def test_set_option_defaults_to_the_suite_and_names_every_set() -> None:
    """``--set`` parses to a key of ``SETS`` (the suite by default) and rejects other names."""
    ap = argparse.ArgumentParser()
    bench_sets.add_sequence_options(ap)
    assert ap.parse_args([]).set == "suite"
    assert bench_sets.SETS[ap.parse_args(["--set", "validation"]).set] is \
        bench_sets.VALIDATION
    with pytest.raises(SystemExit):
        ap.parse_args(["--set", "heldout"])


def test_chosen_gives_the_set_and_its_selected_names() -> None:
    """``chosen`` returns the sequences of ``--set`` and the ``--only`` names checked against
    them."""
    ap = argparse.ArgumentParser()
    bench_sets.add_sequence_options(ap)
    seqs, only = bench_sets.chosen(ap, ap.parse_args(["--set", "validation", "--only",
                                                        "v_hand"]))
    assert seqs is bench_sets.VALIDATION and only == {"v_hand"}
    seqs, only = bench_sets.chosen(ap, ap.parse_args([]))
    assert seqs is bench_sets.SEQUENCES and only == set()
    with pytest.raises(SystemExit):
        bench_sets.chosen(ap, ap.parse_args(["--only", "v_hand"]))


def test_all_is_the_four_figure_sets_together() -> None:
    """``--set all`` holds every sequence of the suite, validation, fresh and spread sets with
    its own keywords, and nothing else (their names are disjoint, so none is lost)."""
    parts = ("suite", "validation", "fresh", "spread")
    assert sum(len(bench_sets.SETS[k]) for k in parts) == len(bench_sets.ALL)
    for k in parts:
        for name, entry in bench_sets.SETS[k].items():
            assert bench_sets.ALL[name] == entry


def test_synthesize_entry_renders_at_the_named_camera_with_outliers() -> None:
    """``camera "320"`` renders at 320x240 (no more pixels than points), and 2 % of the points
    are outliers (label -1); the default camera is 640 wide."""
    syn = bench_sets.synthesize_entry("upper_body", {"seed": 2, "camera": "320"}, 2)
    assert syn.camera.width == 320 and syn.camera.height == 240
    assert all(len(f) <= 320 * 240 for f in syn.frames)
    labels = np.concatenate(syn.point_labels)
    assert abs(np.mean(labels < 0) - 0.02) < 0.01
    assert bench_sets.synthesize_entry("upper_body", {"seed": 2}, 1).camera.width == 640


def test_jittered_moves_every_coordinate_by_at_most_a_nanometre() -> None:
    """Repeat ``k`` moves each coordinate by a nonzero amount of at most 1e-9 m, the same for
    the same ``k`` and a different one for another ``k``; the frames' shapes are kept."""
    rng = np.random.default_rng(0)
    seq = PointSequence([rng.normal(size=(50, 3)), rng.normal(size=(40, 3))], source="x")
    a, b, c = (bench_sets.jittered(seq, k) for k in (1, 1, 2))
    for f0, fa, fb, fc in zip(seq.frames, a.frames, b.frames, c.frames):
        d = fa - f0
        assert d.shape == f0.shape and 0 < np.abs(d).max() <= 1e-9
        np.testing.assert_array_equal(fa, fb)
        assert not np.array_equal(fa, fc)
    assert a.source == "x"


def test_score_joints_of_the_truth_is_perfect_and_of_a_shift_is_the_shift() -> None:
    """Scoring the ground-truth joints finds every scorable joint with no error; moving every
    joint by 3 cm gives a 3 cm raw error (an independent oracle: the shift itself)."""
    syn = bench_sets.synthesize_entry("human", {"seed": 2, "camera": "320"}, 6)
    truth = syn.gt_joints
    rep = bench_sets.score_joints(truth, syn)
    assert rep.n_scorable >= 5 and rep.recall == 1.0
    assert rep.raw_error == pytest.approx(0.0, abs=1e-9)
    shifted = bench_sets.score_joints(truth + [0.0, 0.03, 0.0], syn)
    assert shifted.raw_error == pytest.approx(0.03, rel=1e-6)


def test_paper_config_is_the_paper_s_registration_and_step_3() -> None:
    """The paper's reference registers as :meth:`RegistrationConfig.paper` does (no
    refinement) and runs step 3 in the paper's mode; the default does neither."""
    paper = bench_sets.paper_config()
    assert paper.registration == RegistrationConfig.paper()
    assert paper.registration.refine_rounds == 0
    assert paper.joints.mode == "paper"
    assert PipelineConfig().joints.mode != "paper"
    assert PipelineConfig().registration != paper.registration
