"""A pinhole depth camera (Kinect v1 defaults) and its placement in the world.

Conventions
-----------
- World frame: metres, ``y`` up; procedural subjects stand on ``y = 0`` and face ``+z``.
- Camera frame (OpenCV): ``x`` right, ``y`` down, ``z`` forward (depth), metres.
  ``X_cam = rotation @ X_world + translation``.
- Pixel ``(u, v)`` has its centre at integer coordinates; ``u = fx x / z + cx``,
  ``v = fy y / z + cy``. Back-projection is ``x = (u - cx) z / fx``, ``y = (v - cy) z / fy``,
  the same as :func:`pointrig.io.readers.depth_to_points`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError

__all__ = ["Camera", "look_at"]

#: Kinect v1 depth intrinsics at 640x480 (fx = fy = 525 px, principal point at the centre).
KINECT_FX = 525.0
KINECT_WIDTH = 640
KINECT_HEIGHT = 480
#: Nearest distance a Kinect v1 measures (metres); auto-placement never puts the subject nearer.
KINECT_MIN_RANGE = 0.6
#: Fraction of the image the subject's bounding box may fill when the camera is auto-placed.
FRAME_FILL = 0.8


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray | None = None
            ) -> tuple[np.ndarray, np.ndarray]:
    """World-to-camera ``(rotation (3,3), translation (3,))`` of a camera at ``eye`` looking at
    ``target`` with world ``up`` (default ``+y``) pointing up in the image."""
    eye = np.asarray(eye, dtype=np.float64)
    target = np.asarray(target, dtype=np.float64)
    up = np.array([0.0, 1.0, 0.0]) if up is None else np.asarray(up, dtype=np.float64)
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(-up, z)  # image x: right; image y: down = -up
    if np.linalg.norm(x) < 1e-9:
        x = np.cross(np.array([0.0, 0.0, -1.0]), z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    rot = np.stack([x, y, z])  # rows: camera axes in world coordinates
    return rot, -rot @ eye


@dataclass(frozen=True)
class Camera:
    """A pinhole depth camera.

    Attributes
    ----------
    fx, fy, cx, cy
        Intrinsics in pixels.
    width, height
        Image size in pixels.
    rotation, translation
        World-to-camera extrinsic, ``(3, 3)`` and ``(3,)`` metres, or ``None`` to let
        :func:`pointrig.synth.synthesize` place the camera in front of the subject
        (0.6-3 m away, looking along world ``-z``, framing the whole motion).
    """

    fx: float = KINECT_FX
    fy: float = KINECT_FX
    cx: float = (KINECT_WIDTH - 1) / 2
    cy: float = (KINECT_HEIGHT - 1) / 2
    width: int = KINECT_WIDTH
    height: int = KINECT_HEIGHT
    rotation: np.ndarray | None = None
    translation: np.ndarray | None = None

    @classmethod
    def kinect(cls, width: int = 640) -> Camera:
        """Kinect v1 intrinsics at 640x480 (``width=640``) or 320x240 (``width=320``, focal
        length halved). Extrinsic unset (auto-placed)."""
        if width not in (320, 640):
            raise ConfigError(f"Kinect resolution is 640x480 or 320x240, got width {width}")
        return cls.kinect_fov(width)

    @classmethod
    def kinect_fov(cls, width: int) -> Camera:
        """A pinhole camera of Kinect v1's field of view ``width`` pixels wide (``width >= 16``):
        height 3/4 of it, focal length ``525 * width / 640`` pixels, principal point at the
        centre. 1280 gives 4x the points of 640 on the same scene (a closer subject or a newer
        camera). Extrinsic unset (auto-placed)."""
        if isinstance(width, bool) or not isinstance(width, int) or width < 16:
            raise ConfigError(f"camera width must be an integer of at least 16 pixels, got "
                              f"{width!r}")
        s = width / KINECT_WIDTH
        h = int(round(KINECT_HEIGHT * s))
        return cls(KINECT_FX * s, KINECT_FX * s, (width - 1) / 2, (h - 1) / 2, width, h)

    @property
    def placed(self) -> bool:
        """Whether the extrinsic is set."""
        return self.rotation is not None and self.translation is not None

    def with_pose(self, rotation: np.ndarray, translation: np.ndarray) -> Camera:
        """A copy with the given world-to-camera extrinsic."""
        return dataclasses.replace(self, rotation=np.asarray(rotation, dtype=np.float64),
                                   translation=np.asarray(translation, dtype=np.float64))

    def world_to_camera(self, points: np.ndarray) -> np.ndarray:
        """``(..., 3)`` world points to camera coordinates (identity if not placed)."""
        pts = np.asarray(points, dtype=np.float64)
        if not self.placed:
            return pts.copy()
        return pts @ np.asarray(self.rotation).T + np.asarray(self.translation)

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Camera-frame points ``(N, 3)`` -> pixel ``u (N,)``, ``v (N,)``, depth ``z (N,)``."""
        z = points[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = self.fx * points[:, 0] / z + self.cx
            v = self.fy * points[:, 1] / z + self.cy
        return u, v, z

    def backproject(self, u: np.ndarray, v: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Pixels ``u, v`` (any float) with depth ``z`` (metres) -> ``(N, 3)`` camera points."""
        return np.stack([(u - self.cx) * z / self.fx, (v - self.cy) * z / self.fy, z], axis=1)

    def placed_for(self, lo: np.ndarray, hi: np.ndarray,
                   direction: np.ndarray | None = None,
                   distance: float | None = None) -> Camera:
        """A copy placed to see the world box ``[lo, hi]`` whole, from ``direction`` (world,
        from the subject towards the camera; default ``+z``), at least
        :data:`KINECT_MIN_RANGE` from the box's front face; or, with ``distance``, exactly
        ``distance`` metres from the box's centre (what does not fit in the image is cut).

        Raises
        ------
        ConfigError
            ``distance`` not a positive number.
        """
        if distance is not None and not (np.isfinite(distance) and distance > 0):
            raise ConfigError(f"camera distance must be a positive number of metres, got "
                              f"{distance!r}")
        lo = np.asarray(lo, dtype=np.float64)
        hi = np.asarray(hi, dtype=np.float64)
        d = np.array([0.0, 0.0, 1.0]) if direction is None else np.asarray(direction, float)
        d = d / np.linalg.norm(d)
        centre = (lo + hi) / 2
        half = (hi - lo) / 2
        rot, _ = look_at(centre + d, centre)
        # extent of the box in camera axes
        corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
        local = (corners * half) @ rot.T
        ext = np.abs(local).max(axis=0)
        tan_x = (self.width / 2) / self.fx * FRAME_FILL
        tan_y = (self.height / 2) / self.fy * FRAME_FILL
        dist = max(ext[0] / tan_x, ext[1] / tan_y) + ext[2]
        dist = max(dist, KINECT_MIN_RANGE + ext[2])
        if distance is not None:
            dist = float(distance)
        eye = centre + d * dist
        rot, trans = look_at(eye, centre)
        return self.with_pose(rot, trans)

    def intrinsics_dict(self) -> dict[str, float]:
        """``fx, fy, cx, cy, width, height`` as a dict (JSON-ready)."""
        return {"fx": float(self.fx), "fy": float(self.fy), "cx": float(self.cx),
                "cy": float(self.cy), "width": int(self.width), "height": int(self.height)}
