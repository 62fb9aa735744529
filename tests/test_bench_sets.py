"""The sequence sets of benchmarks/bench_refine.py: the validation set is held back from the
suite (no sequence of one is a sequence of the other) and every entry can be synthesised."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import bench_refine  # noqa: E402

from pointrig.synth import FIGURES  # noqa: E402


def _key(source: str, kw: dict) -> tuple:
    return (Path(source).name, tuple(sorted(kw.items())))


def test_validation_set_is_disjoint_from_the_suite() -> None:
    """No name, and no (figure or rig, synthesis keywords) pair, is in both sets; every seed of
    the validation set is one the suite does not use, so its noise and motion are new too."""
    suite, val = bench_refine.SEQUENCES, bench_refine.VALIDATION
    assert not set(suite) & set(val)
    assert not {_key(*v) for v in suite.values()} & {_key(*v) for v in val.values()}
    assert not {kw["seed"] for _, kw in suite.values()} & {kw["seed"] for _, kw in val.values()}
    assert set(bench_refine.SETS) == {"suite", "validation", "fresh", "spread", "all", "limbs",
                                      "hands"}


@pytest.mark.parametrize("held", ["fresh", "spread"])
def test_later_held_back_sets_are_disjoint_from_the_earlier_sets(held: str) -> None:
    """The second and third held-back sets share no name, (source, keywords) pair or seed with
    the suite, the validation set or each other."""
    later = bench_refine.SETS[held]
    earlier = {"fresh": ("suite", "validation"), "spread": ("suite", "validation", "fresh")}
    for other in (bench_refine.SETS[k] for k in earlier[held]):
        assert not set(later) & set(other)
        assert not {_key(*v) for v in later.values()} & {_key(*v) for v in other.values()}
        assert not ({kw["seed"] for _, kw in later.values()}
                    & {kw["seed"] for _, kw in other.values()})


def test_hands_set_is_new_hands() -> None:
    """The hands set (session 56) holds only the procedural hand, at seeds no hand of another
    set uses, and shares no name or (source, keywords) pair with any other set."""
    hands = bench_refine.HANDS
    assert {src for src, _ in hands.values()} == {"hand"}
    others = [v for k, v in bench_refine.SETS.items() if k != "hands"]
    other_hand_seeds = {kw["seed"] for o in others for src, kw in o.values() if src == "hand"}
    assert not {kw["seed"] for _, kw in hands.values()} & other_hand_seeds
    for o in others:
        assert not set(hands) & set(o)
        assert not {_key(*v) for v in hands.values()} & {_key(*v) for v in o.values()}


#: The entries of every set but the suite and ALL (their union), by name.
_OTHER_ENTRIES = {**bench_refine.VALIDATION, **bench_refine.FRESH, **bench_refine.SPREAD,
                  **bench_refine.LIMBS, **bench_refine.HANDS}


@pytest.mark.parametrize("name", sorted(_OTHER_ENTRIES))
def test_validation_entries_name_a_figure_or_a_rig(name: str) -> None:
    """Each source (of the validation, fresh, spread, limbs and hands sets) is a procedural
    figure or a .glb under the shared models folder, and the keywords are ones the benchmark's
    synthesis takes."""
    source, kw = _OTHER_ENTRIES[name]
    if source.endswith(".glb"):
        assert Path(source).parent == bench_refine._MODELS
    else:
        assert source in FIGURES
    assert set(kw) <= {"seed", "yaw", "walk", "clip", "start", "camera"}


def test_selected_checks_names_against_the_chosen_set() -> None:
    """``--only`` names are checked against the set in use: a validation name is unknown to
    the suite and known to the validation set."""
    ap = argparse.ArgumentParser()
    assert bench_refine.selected(ap, "v_hand,v_human", bench_refine.VALIDATION) == {
        "v_hand", "v_human"}
    with pytest.raises(SystemExit):
        bench_refine.selected(ap, "v_hand")
    with pytest.raises(SystemExit):
        bench_refine.selected(ap, "human", bench_refine.VALIDATION)


def test_suite_iterates_the_chosen_set(monkeypatch: pytest.MonkeyPatch) -> None:
    """``suite(..., sequences)`` yields the chosen set's names in order, synthesising each
    with its own keywords."""
    calls = []
    monkeypatch.setattr(bench_refine, "_synth", lambda src, kw, frames: calls.append(
        (src, kw, frames)) or len(calls))
    sub = {n: bench_refine.VALIDATION[n] for n in ("v_human", "v_hand")}
    got = list(bench_refine.suite(5, set(), sub))
    assert [n for n, _ in got] == ["v_human", "v_hand"]
    assert calls == [(s, kw, 5) for s, kw in sub.values()]


def test_set_option_defaults_to_the_suite_and_names_every_set() -> None:
    """``--set`` parses to a key of ``SETS`` (the suite by default) and rejects other names."""
    ap = argparse.ArgumentParser()
    bench_refine.add_set_option(ap)
    assert ap.parse_args([]).set == "suite"
    assert bench_refine.SETS[ap.parse_args(["--set", "validation"]).set] is \
        bench_refine.VALIDATION
    with pytest.raises(SystemExit):
        ap.parse_args(["--set", "heldout"])


def test_chosen_gives_the_set_and_its_selected_names() -> None:
    """``chosen`` returns the sequences of ``--set`` and the ``--only`` names checked against
    them."""
    ap = argparse.ArgumentParser()
    bench_refine.add_set_option(ap)
    ap.add_argument("--only", default="")
    seqs, only = bench_refine.chosen(ap, ap.parse_args(["--set", "validation", "--only",
                                                        "v_hand"]))
    assert seqs is bench_refine.VALIDATION and only == {"v_hand"}
    seqs, only = bench_refine.chosen(ap, ap.parse_args([]))
    assert seqs is bench_refine.SEQUENCES and only == set()
    with pytest.raises(SystemExit):
        bench_refine.chosen(ap, ap.parse_args(["--only", "v_hand"]))


def test_all_is_the_four_figure_sets_together() -> None:
    """``--set all`` holds every sequence of the suite, validation, fresh and spread sets with
    its own keywords, and nothing else (their names are disjoint, so none is lost)."""
    parts = ("suite", "validation", "fresh", "spread")
    assert sum(len(bench_refine.SETS[k]) for k in parts) == len(bench_refine.ALL)
    for k in parts:
        for name, entry in bench_refine.SETS[k].items():
            assert bench_refine.ALL[name] == entry
