"""Step 1 interrupted after some frames resumes where it stopped, with the same result bit for
bit as an uninterrupted run (the oracle: that uninterrupted run)."""

from __future__ import annotations

import numpy as np
import pytest

from pointrig.config import RegistrationConfig
from pointrig.registration import PartialRegistration, cache_key, register_sequence
from pointrig.sequence import PointSequence
from pointrig.synth import NoiseConfig, synthesize


class _Stop(Exception):
    pass


@pytest.fixture(scope="module")
def seq() -> PointSequence:
    return PointSequence(synthesize("arm", n_frames=8, seed=4, noise=NoiseConfig()).frames)


def _assert_same(a, b) -> None:
    for name in ("rest_points", "points", "sigma2", "iterations", "energy", "matched"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert a.params == b.params and a.key == b.key


@pytest.mark.parametrize("stop_after", [1, 3, 6])  # after the rest frame / in both chains
def test_an_interrupted_registration_resumes_to_the_same_result(seq, tmp_path, stop_after):
    config = RegistrationConfig()
    whole = register_sequence(seq, config)

    def interrupt(partial: PartialRegistration) -> None:
        if partial.n_frames() >= stop_after:
            raise _Stop

    state = PartialRegistration(cache_key(seq, config))
    with pytest.raises(_Stop):
        register_sequence(seq, config, partial=state, on_frame=interrupt)
    assert stop_after <= state.n_frames() < len(seq)
    path = tmp_path / "partial.npz"
    state.save(path)
    loaded = PartialRegistration.load(path)
    assert loaded.key == state.key and loaded.n_frames() == state.n_frames()
    redone = []
    resumed = register_sequence(seq, config, partial=loaded,
                                on_frame=lambda p: redone.append(p.n_frames()))
    _assert_same(resumed, whole)
    # none of the saved frames was registered again, every other one was
    assert redone == list(range(state.n_frames() + 1, loaded.n_frames() + 1))
    assert loaded.n_frames() % len(seq) == 0
