"""benchmarks/stages.py: per-stage seconds exclusive of nested stages, the functions restored,
and the Python seconds of a pure-Python stage against its own CPU clock."""

from __future__ import annotations

import time
import types

import pytest
from benchmarks import stages


@pytest.fixture
def fake(monkeypatch: pytest.MonkeyPatch) -> types.SimpleNamespace:
    """A module with two stage functions, ``outer`` calling ``inner`` twice; the stage list
    replaced by them."""
    mod = types.SimpleNamespace()

    def inner() -> None:
        time.sleep(0.05)

    def outer() -> int:
        time.sleep(0.02)
        mod.inner()
        mod.inner()
        return 7

    def python_loop() -> float:
        t0, x = time.thread_time(), 0.0
        while time.thread_time() - t0 < 0.1:
            x += sum(i * 0.5 for i in range(200))
        return x

    mod.inner, mod.outer, mod.python_loop = inner, outer, python_loop
    monkeypatch.setattr(stages, "STAGES", (("inner", mod, "inner"), ("outer", mod, "outer"),
                                           ("loop", mod, "python_loop")))
    return mod


def test_nested_stages_are_exclusive_and_functions_restored(fake: types.SimpleNamespace
                                                             ) -> None:
    """The outer stage's seconds leave out the inner stage's (oracle: the sleeps); the
    counts and the whole block; the module's functions are its own again afterwards."""
    originals = (fake.inner, fake.outer)
    prof = stages.StageProfile()
    with prof.recording():
        assert fake.outer() == 7
    assert (fake.inner, fake.outer) == originals
    inner, outer = prof.times["inner"], prof.times["outer"]
    assert (inner.calls, outer.calls) == (2, 1)
    assert inner.wall >= 0.1
    assert 0.02 <= outer.wall < inner.wall
    assert prof.total.wall >= inner.wall + outer.wall
    assert prof.other().wall >= 0.0
    assert "inner" in stages.table(prof) and "total" in stages.table(prof)


def test_python_seconds_of_a_python_loop(fake: types.SimpleNamespace) -> None:
    """A stage that is a Python loop burning 0.1 s of its thread's CPU: its Python seconds are
    most of that and no more than the stage's CPU; a sleeping stage has almost none."""
    prof = stages.StageProfile(python=True)
    with prof.recording():
        fake.python_loop()
        fake.inner()
    loop = prof.times["loop"]
    assert 0.05 <= loop.python <= loop.cpu + 0.02
    assert prof.times["inner"].python < 0.01
