"""The typed exception hierarchy of pointrig.

Every error pointrig raises on purpose derives from :class:`PointrigError`. The Rust core's
error enum (``rust/core/error.rs``) maps onto these classes in one place
(``rust/py/mod.rs::to_pyerr``): ``InvalidInput`` (a bad shape, size or value, coordinates
beyond 1e12 m) and ``NonFinite`` -> :class:`InputError`, ``Convergence`` ->
:class:`ConvergenceError`, ``Numerical`` -> :class:`NumericalError`.
"""

from __future__ import annotations

from pathlib import Path

__all__ = [
    "PointrigError",
    "InputError",
    "FormatError",
    "EmptyFrameError",
    "ConfigError",
    "ConvergenceError",
    "NumericalError",
    "TrackingLostError",
    "OutputError",
]


class PointrigError(Exception):
    """Base class of every error raised by pointrig on purpose."""


class InputError(PointrigError, ValueError):
    """Bad input data: a missing, unreadable or malformed file, or bad array contents.

    Parameters
    ----------
    message
        What is wrong.
    path
        The file or directory concerned, if any.
    frame
        The 0-based frame index concerned, if any.
    """

    def __init__(self, message: str, path: str | Path | None = None, frame: int | None = None):
        self.path = None if path is None else Path(path)
        self.frame = frame
        self.problem = message
        where = []
        if path is not None:
            where.append(str(path))
        if frame is not None:
            where.append(f"frame {frame}")
        prefix = (": ".join(where) + ": ") if where else ""
        super().__init__(prefix + message)


class FormatError(InputError):
    """A file whose format is unknown, mixed with other formats, or truncated."""


class EmptyFrameError(InputError):
    """A frame with no points, or with fewer points than the pipeline needs."""


class ConfigError(PointrigError, ValueError):
    """An invalid parameter value or an unreadable configuration file."""


class ConvergenceError(PointrigError, RuntimeError):
    """An iterative solver failed to make progress."""


class NumericalError(PointrigError, ArithmeticError):
    """A singular system or another numerical failure in the core."""


class TrackingLostError(PointrigError, RuntimeError):
    """Registration lost the subject (almost no data mass matched the template)."""


class OutputError(PointrigError, OSError):
    """An output folder that cannot take the results: a file in its place, not writable, too
    little free space, a write that failed, or another run writing into it.

    Parameters
    ----------
    message
        What is wrong.
    path
        The output folder or file concerned, if any.
    """

    def __init__(self, message: str, path: str | Path | None = None):
        self.path = None if path is None else Path(path)
        self.problem = message
        super().__init__(f"{path}: {message}" if path is not None else message)

    def __str__(self) -> str:
        return self.args[0]
