"""The input data model: a sequence of point-cloud frames.

Notation follows the paper (§3): frame ``t`` holds ``N_t`` original points ``V^t``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import EmptyFrameError, InputError

__all__ = ["PointSequence"]


@dataclass
class PointSequence:
    """A sequence of point clouds from one depth camera.

    Attributes
    ----------
    frames
        ``F`` arrays, each ``(N_t, 3)`` float64, metres, in the camera (or input) frame.
    source
        Where the frames came from (a path), for messages and provenance.
    names
        One name per frame (usually the file name), for messages.
    fmt
        The detected input format (``"ply"``, ``"pcd"``, ``"xyz"``, ``"npy"``, ``"npz"``,
        ``"depth-png"`` or ``"memory"``).
    """

    frames: list[np.ndarray]
    source: str = "<memory>"
    names: list[str] = field(default_factory=list)
    fmt: str = "memory"

    def __post_init__(self) -> None:
        if not self.names:
            self.names = [f"frame {i}" for i in range(len(self.frames))]
        checked = []
        for i, pts in enumerate(self.frames):
            arr = np.asarray(pts, dtype=np.float64)
            if arr.ndim != 2 or arr.shape[1] != 3:
                raise InputError(
                    f"expected points of shape (N, 3), got {arr.shape}", self.source, frame=i
                )
            if arr.shape[0] == 0:
                raise EmptyFrameError("frame has no points", self.source, frame=i)
            bad = ~np.isfinite(arr).all(axis=1)
            if bad.any():
                raise InputError(
                    f"{int(bad.sum())} point(s) with NaN/inf coordinates "
                    f"(first at row {int(np.argmax(bad))})",
                    self.source,
                    frame=i,
                )
            checked.append(np.ascontiguousarray(arr))
        self.frames = checked

    def __len__(self) -> int:
        return len(self.frames)

    def __getitem__(self, t: int) -> np.ndarray:
        return self.frames[t]

    @property
    def n_frames(self) -> int:
        """Number of frames ``F``."""
        return len(self.frames)

    @property
    def counts(self) -> np.ndarray:
        """Points per frame, ``(F,)`` int."""
        return np.array([f.shape[0] for f in self.frames], dtype=np.int64)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounds over all frames, two ``(3,)`` arrays (min, max), metres."""
        lo = np.min([f.min(axis=0) for f in self.frames], axis=0)
        hi = np.max([f.max(axis=0) for f in self.frames], axis=0)
        return lo, hi

    def summary(self) -> dict:
        """A JSON-able summary: frame count, points per frame, bounds, format."""
        c = self.counts
        lo, hi = self.bounds()
        return {
            "source": str(self.source),
            "format": self.fmt,
            "frames": int(len(c)),
            "points_min": int(c.min()),
            "points_median": int(np.median(c)),
            "points_max": int(c.max()),
            "bounds_min": [float(x) for x in lo],
            "bounds_max": [float(x) for x in hi],
        }

    def subset(self, start: int = 0, stop: int | None = None, stride: int = 1) -> "PointSequence":
        """Frames ``start:stop:stride`` as a new sequence."""
        idx = list(range(len(self.frames)))[start:stop:stride]
        return PointSequence(
            [self.frames[i] for i in idx], self.source, [self.names[i] for i in idx], self.fmt
        )

    @staticmethod
    def source_path(source: str) -> Path:
        """The source as a path."""
        return Path(source)
