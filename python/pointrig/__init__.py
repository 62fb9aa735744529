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
    PointrigError,
    TrackingLostError,
)
from .io import read_sequence, write_sequence
from .joints import JointsResult, learn_joints
from .registration import RegistrationResult, register_sequence
from .sequence import PointSequence
from .skeleton import Skeleton, load_skeleton_json
from .structure import StructureResult, extract_structure

__version__: str = _core.__version__

__all__ = [
    "__version__",
    "ConfigError",
    "ConvergenceError",
    "EmptyFrameError",
    "FormatError",
    "InputError",
    "JointsConfig",
    "JointsResult",
    "NumericalError",
    "PipelineConfig",
    "PointSequence",
    "PointrigError",
    "PreprocessConfig",
    "RegistrationConfig",
    "RegistrationResult",
    "Skeleton",
    "StructureConfig",
    "StructureResult",
    "TrackingLostError",
    "extract_structure",
    "learn_joints",
    "load_config",
    "load_skeleton_json",
    "read_sequence",
    "register_sequence",
    "write_sequence",
]
