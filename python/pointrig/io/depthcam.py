"""Depth images to points: the camera models of the recording readers, and subject isolation.

A depth camera's image ``(H, W)`` becomes points through a per-pixel ray table ``(H, W, 2)``:
pixel ``(v, u)`` at depth ``z`` is the camera-frame point ``(rays[v, u, 0] z, rays[v, u, 1] z,
z)`` (x right, y down, z forward, metres). A pinhole camera's rays are closed-form; a lens with
distortion (the Azure Kinect's Brown-Conrady model) gets its rays by inverting the model once
per recording.

Subject isolation (:class:`Isolation`) keeps a depth range ``near <= z <= far`` (metres) and a
pixel box of the image (``--near/--far``, ``--crop``), before back-projection.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ConfigError, PointrigError

__all__ = ["Isolation", "Recording", "pinhole_rays", "brown_conrady_rays",
           "brown_conrady_project", "depth_image_points", "need_extra", "select_frames",
           "may_select"]


def need_extra(module: str, what: str) -> Any:
    """Import an optional dependency of the ``capture`` extra, or raise a one-line
    :class:`PointrigError` saying how to install it."""
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError:
        raise PointrigError(f"reading {what} needs the Python package {module!r}: "
                            "pip install 'pointrig[capture]'") from None


@dataclass(frozen=True)
class Isolation:
    """What part of each depth image is kept.

    Attributes
    ----------
    near, far
        Depth range, metres along the optical axis (``None``: no bound).
    crop
        Pixel box ``(u0, v0, u1, v1)``: columns ``u0 <= u < u1`` and rows ``v0 <= v < v1`` of
        the depth image are kept (``None``: the whole image).
    """

    near: float | None = None
    far: float | None = None
    crop: tuple[int, int, int, int] | None = None

    def __post_init__(self) -> None:
        for name in ("near", "far"):
            val = getattr(self, name)
            if val is not None and not (np.isfinite(val) and val >= 0):
                raise ConfigError(f"--{name} must be a distance >= 0 metres, got {val!r}")
        if self.near is not None and self.far is not None and not self.near < self.far:
            raise ConfigError(f"--near {self.near:g} must be less than --far {self.far:g}")
        if self.crop is not None:
            u0, v0, u1, v1 = self.crop
            if not (0 <= u0 < u1 and 0 <= v0 < v1):
                raise ConfigError(f"--crop U0,V0,U1,V1 needs 0 <= U0 < U1 and 0 <= V0 < V1 "
                                  f"(pixels), got {','.join(str(c) for c in self.crop)}")

    @property
    def active(self) -> bool:
        """Whether anything is cut."""
        return self.near is not None or self.far is not None or self.crop is not None

    def pixel_mask(self, shape: tuple[int, int]) -> np.ndarray:
        """``(H, W)`` bool: the pixels inside the crop box (all when there is none)."""
        mask = np.ones(shape, dtype=bool)
        if self.crop is not None:
            u0, v0, u1, v1 = self.crop
            mask[:] = False
            mask[v0:v1, u0:u1] = True
        return mask

    def depth_mask(self, z: np.ndarray) -> np.ndarray:
        """Bool mask of ``z`` (metres, any shape) inside ``[near, far]``, and ``z > 0``."""
        keep = z > 0
        if self.near is not None:
            keep &= z >= self.near
        if self.far is not None:
            keep &= z <= self.far
        return keep

    def to_dict(self) -> dict[str, Any]:
        """JSON-able, for ``skeleton.json``'s ``source``."""
        return {"near": self.near, "far": self.far,
                "crop": None if self.crop is None else list(self.crop)}


@dataclass
class Recording:
    """The frames of one recording, read.

    Attributes
    ----------
    frames
        ``F`` arrays ``(N_t, 3)`` float64, metres, camera frame (x right, y down, z forward).
    names
        One name per frame (``"depth 12 @ 0.400 s"``), for messages.
    fmt
        The format name (``"mkv"``, ``"rosbag"``, ``"r3d"``, ...).
    meta
        JSON-able description: ``device``, ``resolution`` ``[W, H]``, ``fps``, ``intrinsics``
        (with its ``source``), ``frames_in_file``, ``timestamps_s`` of the frames read,
        ``duration_s`` and, when set, ``isolation``.
    depth
        The depth images read ``(H, W)`` in metres (float32), kept only when asked for (the
        preview shows them); else empty.
    """

    frames: list[np.ndarray]
    names: list[str]
    fmt: str
    meta: dict[str, Any] = field(default_factory=dict)
    depth: list[np.ndarray] = field(default_factory=list)


def select_frames(n: int, start: int, stop: int | None, stride: int) -> list[int]:
    """The indices ``range(n)[start:stop:stride]`` as a list."""
    return list(range(n))[start:stop:stride]


def may_select(i: int, start: int, stop: int | None, stride: int) -> bool:
    """Whether frame ``i`` can be among :func:`select_frames` before the frame count is known
    (a reader keeps only those frames' data while it reads; with a negative ``start`` or
    ``stop`` every frame can be)."""
    if start < 0 or (stop is not None and stop < 0):
        return True
    return i >= start and (stop is None or i < stop) and (i - start) % stride == 0


def pinhole_rays(width: int, height: int, fx: float, fy: float, cx: float,
                 cy: float) -> np.ndarray:
    """Rays of a pinhole camera: ``(H, W, 2)`` float64, ``((u - cx) / fx, (v - cy) / fy)``
    for pixel column ``u`` and row ``v`` (pixel centres at whole numbers)."""
    u = (np.arange(width) - cx) / fx
    v = (np.arange(height) - cy) / fy
    return np.stack(np.broadcast_arrays(u[None, :], v[:, None]), axis=-1).astype(np.float64)


def brown_conrady_project(xy: np.ndarray, k: np.ndarray | tuple[float, ...], p1: float, p2: float) -> np.ndarray:
    """Distort normalised image coordinates with the Azure Kinect's Brown-Conrady model.

    ``r2 = x^2 + y^2``, ``d = (1 + k1 r2 + k2 r2^2 + k3 r2^3) / (1 + k4 r2 + k5 r2^2 +
    k6 r2^3)``, ``x' = x d + (r2 + 2 x^2) p2 + 2 x y p1``, ``y' = y d + (r2 + 2 y^2) p1 +
    2 x y p2`` (the order of ``p1, p2`` is the SDK's).

    Parameters
    ----------
    xy
        ``(..., 2)`` undistorted normalised coordinates (``X / Z, Y / Z``).
    k
        ``(6,)`` radial coefficients ``k1..k6``.
    p1, p2
        Tangential coefficients.

    Returns
    -------
    numpy.ndarray
        ``(..., 2)`` distorted normalised coordinates.
    """
    x, y = xy[..., 0], xy[..., 1]
    r2 = x * x + y * y
    num = 1 + r2 * (k[0] + r2 * (k[1] + r2 * k[2]))
    den = 1 + r2 * (k[3] + r2 * (k[4] + r2 * k[5]))
    d = num / den
    xd = x * d + (r2 + 2 * x * x) * p2 + 2 * x * y * p1
    yd = y * d + (r2 + 2 * y * y) * p1 + 2 * x * y * p2
    return np.stack([xd, yd], axis=-1)


def brown_conrady_rays(width: int, height: int, fx: float, fy: float, cx: float, cy: float,
                       k: np.ndarray, p1: float, p2: float, max_radius: float = 0.0,
                       iterations: int = 20) -> np.ndarray:
    """Rays of a camera with Brown-Conrady distortion: the undistorted normalised coordinates
    of every pixel, by Gauss-Newton on :func:`brown_conrady_project` (numerical Jacobian).

    Parameters
    ----------
    width, height
        Image size, pixels.
    fx, fy, cx, cy
        Focal lengths and principal point, pixels (pixel centres at whole numbers).
    k, p1, p2
        The distortion of :func:`brown_conrady_project`.
    max_radius
        The model's valid radius in normalised coordinates (the calibration's
        ``MetricRadius``; 0: no limit). Pixels whose ray lies outside it, or where the
        inversion does not converge to 1e-6 px, get NaN rays (their depth is dropped).
    iterations
        Gauss-Newton steps.

    Returns
    -------
    numpy.ndarray
        ``(H, W, 2)`` float64, read-only (the same table is handed to every caller with the
        same calibration).
    """
    return _brown_conrady_rays(int(width), int(height), float(fx), float(fy), float(cx),
                               float(cy), tuple(float(c) for c in k), float(p1), float(p2),
                               float(max_radius), int(iterations))


@functools.lru_cache(maxsize=4)
def _brown_conrady_rays(width: int, height: int, fx: float, fy: float, cx: float, cy: float,
                        k: tuple[float, ...], p1: float, p2: float, max_radius: float,
                        iterations: int) -> np.ndarray:
    target = pinhole_rays(width, height, fx, fy, cx, cy).reshape(-1, 2)
    xy = target.copy()
    eps = 1e-7
    for _ in range(iterations):
        f = brown_conrady_project(xy, k, p1, p2) - target
        jx = (brown_conrady_project(xy + (eps, 0.0), k, p1, p2) - target - f) / eps
        jy = (brown_conrady_project(xy + (0.0, eps), k, p1, p2) - target - f) / eps
        det = jx[:, 0] * jy[:, 1] - jy[:, 0] * jx[:, 1]
        det = np.where(np.abs(det) < 1e-12, 1e-12, det)
        dx = (jy[:, 1] * f[:, 0] - jy[:, 0] * f[:, 1]) / det
        dy = (-jx[:, 1] * f[:, 0] + jx[:, 0] * f[:, 1]) / det
        xy[:, 0] -= dx
        xy[:, 1] -= dy
        if np.nanmax(np.abs(f)) < 1e-12:
            break
    resid = (brown_conrady_project(xy, k, p1, p2) - target) * (fx, fy)
    bad = ~np.isfinite(resid).all(axis=1) | (np.abs(resid).max(axis=1) > 1e-6)
    if max_radius > 0:
        bad |= (xy ** 2).sum(axis=1) > max_radius ** 2
    xy[bad] = np.nan
    out = xy.reshape(height, width, 2)
    out.flags.writeable = False
    return out


def depth_image_points(depth: np.ndarray, rays: np.ndarray, scale: float,
                       isolation: Isolation | None = None) -> np.ndarray:
    """Back-project one depth image through its ray table.

    Parameters
    ----------
    depth
        ``(H, W)`` depth in the camera's units (0, and NaN for float images: no depth).
    rays
        ``(H, W, 2)`` normalised rays (:func:`pinhole_rays`, :func:`brown_conrady_rays`);
        NaN rays are dropped.
    scale
        Metres per depth unit.
    isolation
        Depth range and pixel box kept (``None``: all valid pixels).

    Returns
    -------
    numpy.ndarray
        ``(N, 3)`` float64, metres, camera frame, in row-major pixel order.
    """
    z = np.nan_to_num(depth.astype(np.float64), nan=0.0, posinf=0.0, neginf=0.0) * scale
    keep = z > 0
    if isolation is not None:
        keep &= isolation.depth_mask(z) & isolation.pixel_mask(z.shape)
    keep &= np.isfinite(rays).all(axis=-1)
    v, u = np.nonzero(keep)
    zz = z[v, u]
    return np.stack([rays[v, u, 0] * zz, rays[v, u, 1] * zz, zz], axis=1)


def check_crop(isolation: Isolation | None, width: int, height: int, path: Path) -> None:
    """Refuse a pixel box outside a ``width`` x ``height`` image."""
    from ..errors import InputError

    if isolation is None or isolation.crop is None:
        return
    u0, v0, u1, v1 = isolation.crop
    if u1 > width or v1 > height:
        raise InputError(f"--crop {u0},{v0},{u1},{v1} goes past the {width} x {height} depth "
                         "image", path)
