"""The output data model: an articulated skeleton and the ``skeleton.json`` contract.

``skeleton.json`` (format ``pointrig.skeleton/1``) is stable; see the README. Joints form a
tree (``parent = -1`` for the root). Bone ``b`` goes from joint ``bones[b].head_joint`` to
``bones[b].tail_joint``. Bone transforms map rest-pose points to frame ``t``:
``x = R[t, b] @ q + T[t, b]`` (Eq. 13), i.e. ``R, T`` is ``T_frame_rest`` of the bone.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .errors import InputError
from .io.atomic import write_json, write_npz
from .jsonfile import read_json

__all__ = ["SKELETON_FORMAT", "Skeleton", "load_skeleton_json"]

SKELETON_FORMAT = "pointrig.skeleton/1"


@dataclass
class Skeleton:
    """An articulated skeleton extracted from a sequence.

    Attributes
    ----------
    joint_names
        ``J`` names.
    parents
        ``(J,)`` int, parent joint index, ``-1`` for the root.
    rest_positions
        ``(J, 3)`` float64, metres, joint positions in the rest pose (rest-frame coordinates).
    joint_positions
        ``(F, J, 3)`` float64, metres, joint positions per frame, input coordinates.
    bone_heads, bone_tails
        ``(B,)`` int, joint index at each end of bone ``b``.
    bone_rotations
        ``(F, B, 3, 3)`` float64, ``R`` of ``T_frame_rest`` per bone and frame, or ``None``.
    bone_translations
        ``(F, B, 3)`` float64, metres, ``T`` of ``T_frame_rest``, or ``None``.
    weights
        ``(M, B)`` float64 skinning weights of the rest points (rows sum to 1, at most 4
        non-zeros), or ``None``.
    rest_points
        ``(M, 3)`` float64, metres, the rest-pose points the weights refer to, or ``None``.
    labels
        ``(M,)`` int, hard bone label of each rest point (step 2), or ``None``.
    bone_names
        ``B`` names (default ``b0, b1, ...``).
    fps
        Frame rate of ``joint_positions``, Hz, or ``None`` (unknown).
    """

    joint_names: list[str]
    parents: np.ndarray
    rest_positions: np.ndarray
    joint_positions: np.ndarray
    bone_heads: np.ndarray
    bone_tails: np.ndarray
    bone_rotations: np.ndarray | None = None
    bone_translations: np.ndarray | None = None
    weights: np.ndarray | None = None
    rest_points: np.ndarray | None = None
    labels: np.ndarray | None = None
    bone_names: list[str] = field(default_factory=list)
    fps: float | None = None

    def __post_init__(self) -> None:
        self.parents = np.asarray(self.parents, dtype=np.int64)
        self.rest_positions = np.asarray(self.rest_positions, dtype=np.float64).reshape(-1, 3)
        self.joint_positions = np.asarray(self.joint_positions, dtype=np.float64)
        self.bone_heads = np.asarray(self.bone_heads, dtype=np.int64)
        self.bone_tails = np.asarray(self.bone_tails, dtype=np.int64)
        J = len(self.joint_names)
        if self.parents.shape != (J,) or self.rest_positions.shape != (J, 3):
            raise ValueError("parents and rest_positions must have one entry per joint")
        if self.joint_positions.ndim != 3 or self.joint_positions.shape[1:] != (J, 3):
            raise ValueError(f"joint_positions must be (F, {J}, 3), got {self.joint_positions.shape}")
        if not self.bone_names:
            self.bone_names = [f"b{i}" for i in range(len(self.bone_heads))]

    @property
    def n_joints(self) -> int:
        """Number of joints ``J``."""
        return len(self.joint_names)

    @property
    def n_bones(self) -> int:
        """Number of bones ``B``."""
        return len(self.bone_heads)

    @property
    def n_frames(self) -> int:
        """Number of frames ``F``."""
        return int(self.joint_positions.shape[0])

    def to_json_dict(self, source: dict[str, Any] | None = None,
                     params: dict[str, Any] | None = None) -> dict[str, Any]:
        """The ``pointrig.skeleton/1`` document."""
        doc: dict[str, Any] = {
            "format": SKELETON_FORMAT,
            "units": "m",
            "joints": [
                {"name": n, "parent": int(p), "rest_position": [float(v) for v in r]}
                for n, p, r in zip(self.joint_names, self.parents, self.rest_positions)
            ],
            "joint_positions": np.round(self.joint_positions, 6).tolist(),
            "bones": [
                {"name": n, "head_joint": int(h), "tail_joint": int(t)}
                for n, h, t in zip(self.bone_names, self.bone_heads, self.bone_tails)
            ],
            "source": source or {},
            "params": params or {},
        }
        if self.fps is not None:
            doc["fps"] = float(self.fps)
        return doc

    def save_json(self, path: str | Path, source: dict[str, Any] | None = None,
                  params: dict[str, Any] | None = None) -> None:
        """Write ``skeleton.json`` atomically."""
        write_json(path, self.to_json_dict(source, params))

    def save_weights(self, path: str | Path) -> None:
        """Write ``weights.npz`` (rest points, weights, labels, bone transforms), atomically."""
        arrays: dict[str, Any] = {"bone_heads": self.bone_heads, "bone_tails": self.bone_tails}
        for key in ("weights", "rest_points", "labels", "bone_rotations", "bone_translations"):
            val = getattr(self, key)
            if val is not None:
                arrays[key] = val
        write_npz(path, **arrays)


def load_skeleton_json(path: str | Path) -> Skeleton:
    """Read a ``skeleton.json`` written by pointrig.

    Raises
    ------
    InputError
        If the file is missing, not JSON, or not a ``pointrig.skeleton/1`` document.
    """
    p = Path(path)
    doc = read_json(p, missing="file not found", invalid="not valid JSON")
    if not isinstance(doc, dict) or doc.get("format") != SKELETON_FORMAT:
        raise InputError(f"not a {SKELETON_FORMAT} document (missing or wrong 'format')", p)
    try:
        joints = doc["joints"]
        names = [str(j["name"]) for j in joints]
        parents = np.array([int(j["parent"]) for j in joints], dtype=np.int64)
        rest = np.array([j["rest_position"] for j in joints], dtype=np.float64).reshape(-1, 3)
        jp = np.asarray(doc["joint_positions"], dtype=np.float64)
        if jp.size == 0:
            jp = jp.reshape(0, len(names), 3)
        bones = doc.get("bones", [])
        heads = np.array([int(b["head_joint"]) for b in bones], dtype=np.int64)
        tails = np.array([int(b["tail_joint"]) for b in bones], dtype=np.int64)
        bnames = [str(b.get("name", f"b{i}")) for i, b in enumerate(bones)]
        fps = doc.get("fps")
        return Skeleton(names, parents, rest, jp, heads, tails, bone_names=bnames,
                        fps=None if fps is None else float(fps))
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"malformed skeleton document: {exc}", p) from None
