"""Tests of benchmarks/corpus.py: the subject split and the corpus's coverage of the models."""

from __future__ import annotations

import hashlib
from collections import Counter

import pytest
from benchmarks import corpus


def test_split_is_by_subject_and_follows_the_rule():
    seqs = corpus.SEQUENCES
    sets = {}
    for q in seqs.values():
        sets.setdefault(q.subject, set()).add(q.set)
    assert all(len(s) == 1 for s in sets.values())  # no subject in both sets
    # no model file in both sets either
    model_set = {}
    for s in corpus.SUBJECTS:
        for m in s.models:
            model_set.setdefault(m, set()).add(corpus.split()[s.id])
    assert all(len(v) == 1 for v in model_set.values())
    # the rule, recomputed: per category, subjects ordered by SHA-1, alternating from tuning
    for cat in corpus.CATEGORIES:
        ids = [s.id for s in corpus.SUBJECTS if s.category == cat]
        ids.sort(key=lambda i: hashlib.sha1(i.encode()).hexdigest())
        for k, i in enumerate(ids):
            assert corpus.split()[i] == ("tuning", "check")[k % 2]
        n = Counter(corpus.split()[i] for i in ids)
        assert abs(n["tuning"] - n["check"]) <= 1
    assert set(corpus.TUNING) | set(corpus.CHECK) == set(seqs)
    assert not set(corpus.TUNING) & set(corpus.CHECK)
    assert 24 <= len(corpus.TUNING) <= 32 and 24 <= len(corpus.CHECK) <= 32


def _listed() -> list[str]:
    listed = [m for s in corpus.SUBJECTS for m in s.models if m not in corpus.FIGURES]
    return listed + list(corpus.EXCLUDED) + list(corpus.UNUSED)


def test_takes_use_their_subjects_models_and_each_model_is_in_one_place():
    for s in corpus.SUBJECTS:
        assert s.category in corpus.CATEGORIES and s.group in corpus.GROUPS
        assert s.takes and all(t.model in s.models for t in s.takes)
    listed = _listed()
    assert len(listed) == len(set(listed))  # each model in one place only
    assert all(m.endswith((".glb", ".bvh")) for m in listed)


@pytest.mark.skipif(not corpus.models_dir().is_dir(),
                    reason="the models folder (shared/data/models/extra or $POINTRIG_MODELS) "
                           "is not on this machine")
def test_every_model_of_the_folder_is_accounted_for():
    files = {p.name for p in corpus.models_dir().iterdir()
             if p.suffix in (".glb", ".bvh")}
    assert files == set(_listed())
