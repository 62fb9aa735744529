"""The public Python API: every name in ``pointrig.__all__`` resolves, the lazily loaded
step functions are the modules' own objects, and unknown names raise AttributeError."""

from __future__ import annotations

import importlib

import pytest

import pointrig


def test_every_public_name_resolves() -> None:
    for name in pointrig.__all__:
        assert getattr(pointrig, name) is not None, name


@pytest.mark.parametrize("name, module", [
    ("register_sequence", "registration"), ("refine_registration", "registration"),
    ("extract_structure", "structure"), ("structure_from_labels", "structure"),
    ("learn_joints", "joints"), ("StructureResult", "structure"),
])
def test_lazy_names_are_the_step_modules_objects(name: str, module: str) -> None:
    mod = importlib.import_module(f"pointrig.{module}")
    assert getattr(pointrig, name) is getattr(mod, name)
    assert name in pointrig.__all__ and name in mod.__all__


def test_unknown_name_raises_attribute_error() -> None:
    with pytest.raises(AttributeError, match="no_such_thing"):
        pointrig.no_such_thing  # noqa: B018
