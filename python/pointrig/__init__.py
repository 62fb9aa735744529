"""pointrig: articulated skeletons from single depth-camera point cloud sequences.

Implements and extends Lu et al., "3D Articulated Skeleton Extraction Using a Single
Consumer-Grade Depth Camera" (CVIU 2019): registration (§4), skeletal structure (§5) and
LBS-based joint learning (§6).
"""

from __future__ import annotations

from . import _core
from .config import (
    JointsConfig,
    PipelineConfig,
    PreprocessConfig,
    RegistrationConfig,
    RigConfig,
    StructureConfig,
    load_config,
)
from .errors import (
    ConfigError,
    ConvergenceError,
    EmptyFrameError,
    FormatError,
    InputError,
    NumericalError,
    OutputError,
    PointrigError,
    TrackingLostError,
)
from .io import read_sequence, write_sequence
from .sequence import PointSequence
from .skeleton import Skeleton, load_skeleton_json

__version__: str = _core.__version__

# The pipeline steps import scipy; load them on first use so
# that `import pointrig` and `pointrig --help` stay fast.
_LAZY = {
    "RegistrationResult": "registration",
    "register_sequence": "registration",
    "refine_registration": "registration",
    "StructureResult": "structure",
    "extract_structure": "structure",
    "structure_from_labels": "structure",
    "JointsResult": "joints",
    "learn_joints": "joints",
}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    raise AttributeError(f"module 'pointrig' has no attribute {name!r}")

__all__ = [
    "ConfigError",
    "ConvergenceError",
    "EmptyFrameError",
    "FormatError",
    "InputError",
    "JointsConfig",
    "JointsResult",
    "NumericalError",
    "OutputError",
    "PipelineConfig",
    "PointSequence",
    "PointrigError",
    "PreprocessConfig",
    "RegistrationConfig",
    "RegistrationResult",
    "RigConfig",
    "Skeleton",
    "StructureConfig",
    "StructureResult",
    "TrackingLostError",
    "__version__",
    "extract_structure",
    "learn_joints",
    "load_config",
    "load_skeleton_json",
    "read_sequence",
    "refine_registration",
    "register_sequence",
    "structure_from_labels",
    "write_sequence",
]
