"""Tests of benchmarks/corpus.py: the subject split and the corpus's coverage of the models."""

from __future__ import annotations

import hashlib
import sys
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import corpus  # noqa: E402


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


def test_takes_use_their_subjects_models_and_every_model_is_accounted_for():
    for s in corpus.SUBJECTS:
        assert s.category in corpus.CATEGORIES and s.group in corpus.GROUPS
        assert s.takes and all(t.model in s.models for t in s.takes)
    listed = [m for s in corpus.SUBJECTS for m in s.models if m not in corpus.FIGURES]
    listed += list(corpus.EXCLUDED) + list(corpus.UNUSED)
    assert len(listed) == len(set(listed))  # each model in one place only
    files = {p.name for p in corpus.models_dir().iterdir()
             if p.suffix in (".glb", ".bvh")}
    assert files == set(listed)
