"""The input data model: a sequence of point-cloud frames.

Notation follows the paper (§3): frame ``t`` holds ``N_t`` original points ``V^t``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .errors import EmptyFrameError, InputError

__all__ = ["MAX_COORD", "PointSequence", "check_units", "frame_extent"]

#: Largest coordinate magnitude (metres) a point may have, as the native core accepts
#: (``rust/core/error.rs`` ``MAX_COORD``): far beyond any depth camera's reach.
MAX_COORD = 1e12


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
        ``"depth-png"``, a recording format of
        :data:`pointrig.io.recordings.RECORDING_FORMATS`, or ``"memory"``).
    meta
        What the reader used besides the frames, JSON-able, recorded with the results: for depth
        PNGs ``{"intrinsics": {"path": ..., "fx": ..., ...}}`` (pixels; ``depth_scale`` in
        metres per unit); for recordings also ``device``, ``resolution``, ``fps``,
        ``timestamps_s``, ``duration_s`` (:class:`pointrig.io.depthcam.Recording`); with
        subject isolation ``isolation``.
    """

    frames: list[np.ndarray]
    source: str = "<memory>"
    names: list[str] = field(default_factory=list)
    fmt: str = "memory"
    meta: dict[str, Any] = field(default_factory=dict)

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
            far = np.abs(arr).max(axis=1) > MAX_COORD
            if far.any():
                raise InputError(
                    f"{int(far.sum())} point(s) farther than {MAX_COORD:g} m from the origin "
                    f"(first at row {int(np.argmax(far))}); pointrig works in metres",
                    self.source, frame=i)
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
            **self.meta,
        }

    def with_frames(self, frames: list[np.ndarray],
                    names: list[str] | None = None) -> "PointSequence":
        """A new sequence of ``frames`` (checked as any) with this one's source, format and
        meta, and its frame names unless ``names`` are given."""
        return PointSequence(frames, self.source, list(self.names if names is None else names),
                             self.fmt, dict(self.meta))

    def subset(self, start: int = 0, stop: int | None = None, stride: int = 1) -> "PointSequence":
        """Frames ``start:stop:stride`` as a new sequence."""
        idx = list(range(len(self.frames)))[start:stop:stride]
        return self.with_frames([self.frames[i] for i in idx], [self.names[i] for i in idx])

    @staticmethod
    def source_path(source: str) -> Path:
        """The source as a path."""
        return Path(source)


def frame_extent(points: np.ndarray, quantile: float = 0.005) -> float:
    """Robust size of one frame: the diagonal of the box between the ``quantile`` and
    ``1 - quantile`` quantiles of each coordinate (a few stray points do not count).

    Parameters
    ----------
    points
        ``(N, 3)`` float64, in the file's units.
    quantile
        Fraction of the points ignored at each end of each axis.

    Returns
    -------
    float
        The diagonal, same units (0 for an empty frame).
    """
    if len(points) == 0:
        return 0.0
    lo, hi = np.quantile(points, [quantile, 1.0 - quantile], axis=0)
    return float(np.linalg.norm(hi - lo))


def check_units(seq: PointSequence, max_extent: float) -> None:
    """Refuse a sequence that is evidently not in metres.

    Every parameter of the pipeline is in metres (noise, sigma^2, radii). A frame whose
    :func:`frame_extent` exceeds ``max_extent`` metres cannot come from one depth camera in
    metres; most often the file is in millimetres, and the pipeline would run on it and
    return one bone with nothing but "tracking lost" warnings.

    Parameters
    ----------
    seq
        The frames, ``(N_t, 3)`` each, after any scaling.
    max_extent
        Largest plausible frame extent, metres (``<= 0``: no check).

    A frame of no extent at all (its points coincide) is refused too, whatever
    ``max_extent``: no motion or surface can be read from it.

    Raises
    ------
    InputError
        Naming the widest frame (its file, when the sequence was read from a folder), its
        extent and the scale factor that would bring it to metres; or naming a frame whose
        points coincide.
    """
    ext = np.array([frame_extent(v) for v in seq.frames])
    src = PointSequence.source_path(seq.source)
    flat = np.flatnonzero(ext == 0)
    if len(flat):
        t = int(flat[0])
        raise InputError(
            "the frame's points coincide (extent 0 m): nothing to register; check the input "
            "and --scale", src / seq.names[t] if src.is_dir() else src, frame=t)
    if not max_extent > 0:
        return
    if not len(ext) or ext.max() <= max_extent:
        return
    t = int(np.argmax(ext))
    path = src / seq.names[t] if src.is_dir() else src
    # the unit that turns the extent into what one depth camera sees (5 cm to 10 m)
    units = [f"{name}? scale by {f:g}" for f, name in ((0.01, "centimetres"),
                                                        (0.001, "millimetres"))
             if 0.05 <= ext[t] * f <= 10.0]
    hint = " or ".join(units) or "scale it to metres"
    raise InputError(
        f"the points span {ext[t]:.4g} units, more than a depth camera sees in metres "
        f"(max_extent {max_extent:g} m); pointrig works in metres: {hint} "
        "(CLI --scale, read_sequence(scale=...)), or crop the scene", path, frame=t)
