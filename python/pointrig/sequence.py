"""The input data model: a sequence of point-cloud frames.

Notation follows the paper (§3): frame ``t`` holds ``N_t`` original points ``V^t``.
"""

from __future__ import annotations

import os
import tempfile
import threading
import weakref
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, overload

import numpy as np

from .errors import EmptyFrameError, InputError, OutputError

__all__ = ["MAX_COORD", "PointSequence", "SpilledFrames", "check_frame", "check_units",
           "frame_extent", "frames_like"]

#: Largest coordinate magnitude (metres) a point may have, as the native core accepts
#: (``rust/core/error.rs`` ``MAX_COORD``): far beyond any depth camera's reach.
MAX_COORD = 1e12


def check_frame(points: Any, source: str, frame: int) -> np.ndarray:
    """One frame as :class:`PointSequence` holds it: ``(N, 3)`` C-contiguous float64.

    Raises
    ------
    InputError
        A shape other than ``(N, 3)``, NaN/inf coordinates or a coordinate beyond
        :data:`MAX_COORD` (naming ``source`` and ``frame``).
    EmptyFrameError
        No points.
    """
    arr = np.asarray(points, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise InputError(f"expected points of shape (N, 3), got {arr.shape}", source,
                         frame=frame)
    if arr.shape[0] == 0:
        raise EmptyFrameError("frame has no points", source, frame=frame)
    bad = ~np.isfinite(arr).all(axis=1)
    if bad.any():
        raise InputError(
            f"{int(bad.sum())} point(s) with NaN/inf coordinates "
            f"(first at row {int(np.argmax(bad))})",
            source,
            frame=frame,
        )
    far = np.abs(arr).max(axis=1) > MAX_COORD
    if far.any():
        raise InputError(
            f"{int(far.sum())} point(s) farther than {MAX_COORD:g} m from the origin "
            f"(first at row {int(np.argmax(far))}); pointrig works in metres",
            source, frame=frame)
    return np.ascontiguousarray(arr)


class _SpillFile:
    """The file behind :class:`SpilledFrames`: frames appended as raw float64, removed from
    the folder as soon as it is opened (the open descriptor keeps it until closed, so nothing
    is left behind even when the process is killed)."""

    def __init__(self, folder: Path):
        self.folder = folder
        try:
            folder.mkdir(parents=True, exist_ok=True)
            self.fd, name = tempfile.mkstemp(prefix=".frames-", suffix=".f64", dir=folder)
        except OSError as exc:
            raise OutputError(f"cannot keep the frames on disk: {exc.strerror or exc}",
                              folder) from None
        try:
            os.unlink(name)
            self.name = None
        except OSError:  # a platform that cannot remove an open file: removed when closed
            self.name = name
        self.offsets: list[int] = []  # byte offset of each frame
        self.counts: list[int] = []  # points of each frame
        self.size = 0
        self.lock = threading.Lock()
        weakref.finalize(self, _SpillFile._close, self.fd, self.name)

    @staticmethod
    def _close(fd: int, name: str | None) -> None:
        os.close(fd)
        if name is not None:
            try:
                os.unlink(name)
            except OSError:
                pass

    def append(self, points: np.ndarray) -> None:
        data = memoryview(points).cast("B")
        with self.lock:
            at = self.size
            try:
                done = 0
                while done < len(data):
                    done += os.pwrite(self.fd, data[done:], at + done)
            except OSError as exc:
                raise OutputError(f"cannot keep the frames on disk: {exc.strerror or exc}",
                                  self.folder) from None
            self.offsets.append(at)
            self.counts.append(len(points))
            self.size = at + len(data)

    def read(self, row: int) -> np.ndarray:
        out = np.empty((self.counts[row], 3), dtype=np.float64)
        buf = memoryview(out).cast("B")
        at, done = self.offsets[row], 0
        while done < len(buf):
            got = os.preadv(self.fd, [buf[done:]], at + done) if hasattr(os, "preadv") \
                else _pread_into(self.fd, buf[done:], at + done)
            if got <= 0:
                raise OSError(f"the frame store ends at byte {at + done}")
            done += got
        return out


def _pread_into(fd: int, buf: memoryview, offset: int) -> int:
    """``os.preadv`` where the platform lacks it: read into ``buf`` from ``offset``."""
    data = os.pread(fd, len(buf), offset)
    buf[:len(data)] = data
    return len(data)


class SpilledFrames(Sequence[np.ndarray]):
    """Frames kept on disk and read back on demand: a sequence of ``(N_t, 3)`` float64 arrays,
    metres, whose memory is one frame at a time rather than the whole sequence.

    Each frame is appended once (:meth:`append`) to a file in ``folder`` (which the file
    leaves no trace in: it is unlinked at once) and read back, bit for bit, every time it is
    indexed; the operating system's page cache keeps the reads cheap. Slices are views of the
    same file. The file is closed when the last view of it is gone.

    Parameters
    ----------
    folder
        Where the file is made (created when missing), e.g. the output's staging folder.
    """

    def __init__(self, folder: str | Path, *, _file: _SpillFile | None = None,
                 _rows: list[int] | None = None):
        self._file = _file if _file is not None else _SpillFile(Path(folder))
        self._rows = _rows

    @property
    def folder(self) -> Path:
        """The folder of the file."""
        return self._file.folder

    def __repr__(self) -> str:
        return f"SpilledFrames({len(self)} frames, {self.nbytes} bytes in {self.folder})"

    def append(self, points: np.ndarray) -> None:
        """Add a frame ``(N, 3)`` (float64, metres) at the end.

        Raises
        ------
        OutputError
            When the disk is full or the file cannot be written.
        """
        if self._rows is not None:
            raise TypeError("cannot append to a view of spilled frames")
        self._file.append(np.ascontiguousarray(points, dtype=np.float64))

    def _all_rows(self) -> list[int] | range:
        return self._rows if self._rows is not None else range(len(self._file.counts))

    def __len__(self) -> int:
        return len(self._all_rows())

    @overload
    def __getitem__(self, t: int) -> np.ndarray: ...

    @overload
    def __getitem__(self, t: slice) -> SpilledFrames: ...

    def __getitem__(self, t: int | slice) -> np.ndarray | SpilledFrames:
        rows = self._all_rows()
        if isinstance(t, slice):
            return SpilledFrames(self.folder, _file=self._file, _rows=list(rows[t]))
        return self._file.read(rows[t])

    def select(self, index: Iterable[int]) -> SpilledFrames:
        """The frames at ``index`` (in that order), a view of the same file."""
        rows = self._all_rows()
        return SpilledFrames(self.folder, _file=self._file, _rows=[rows[i] for i in index])

    @property
    def counts(self) -> np.ndarray:
        """Points per frame, ``(F,)`` int64, without reading the frames."""
        c = self._file.counts
        return np.array([c[r] for r in self._all_rows()], dtype=np.int64)

    @property
    def nbytes(self) -> int:
        """Bytes of the frames on disk."""
        return int(self.counts.sum()) * 24


def frames_like(frames: Sequence[np.ndarray]) -> list[np.ndarray] | SpilledFrames:
    """An empty frame store of the kind of ``frames``: new :class:`SpilledFrames` in the
    same folder when they are spilled, else a list (frames in memory)."""
    return SpilledFrames(frames.folder) if isinstance(frames, SpilledFrames) else []


@dataclass
class PointSequence:
    """A sequence of point clouds from one depth camera.

    Attributes
    ----------
    frames
        ``F`` arrays, each ``(N_t, 3)`` float64, metres, in the camera (or input) frame: a
        list (in memory) or :class:`SpilledFrames` (on disk, read on demand; its frames were
        checked as they were added, with :func:`check_frame`).
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

    frames: list[np.ndarray] | SpilledFrames
    source: str = "<memory>"
    names: list[str] = field(default_factory=list)
    fmt: str = "memory"
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not self.names:
            self.names = [f"frame {i}" for i in range(len(self.frames))]
        if not isinstance(self.frames, SpilledFrames):  # spilled frames were checked when added
            self.frames = [check_frame(pts, self.source, i) for i, pts in enumerate(self.frames)]

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
        if isinstance(self.frames, SpilledFrames):
            return self.frames.counts
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

    def with_frames(self, frames: list[np.ndarray] | SpilledFrames,
                    names: list[str] | None = None) -> "PointSequence":
        """A new sequence of ``frames`` (checked as any) with this one's source, format and
        meta, and its frame names unless ``names`` are given."""
        return PointSequence(frames, self.source, list(self.names if names is None else names),
                             self.fmt, dict(self.meta))

    def subset(self, start: int = 0, stop: int | None = None, stride: int = 1) -> "PointSequence":
        """Frames ``start:stop:stride`` as a new sequence."""
        idx = list(range(len(self.frames)))[start:stop:stride]
        frames = self.frames.select(idx) if isinstance(self.frames, SpilledFrames) \
            else [self.frames[i] for i in idx]
        return self.with_frames(frames, [self.names[i] for i in idx])

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
