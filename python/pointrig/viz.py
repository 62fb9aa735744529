"""Pictures: skeletons over point clouds (PNG) and animated sequences (GIF).

Points are drawn with a virtual pinhole camera looking down the input's +z axis (the depth
camera's optical axis for camera-frame input), so pictures look like the sensor's view. Only
numpy and Pillow are used.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .io.atomic import atomic_path

__all__ = ["palette", "render_frame", "save_skeleton_png", "save_sequence_gif"]


def palette(n: int) -> np.ndarray:
    """``(n, 3)`` uint8 distinct colours (golden-ratio hues, fixed saturation and value)."""
    h = (np.arange(n) * 0.618033988749895) % 1.0
    rgb = np.clip(np.abs((h[:, None] * 6 + np.array([0.0, 4.0, 2.0])) % 6 - 3) - 1, 0, 1)
    return ((0.25 + 0.7 * rgb) * 255).astype(np.uint8)


class _View:
    """A shared projection for all frames so the subject does not jump between panels."""

    def __init__(self, all_points: np.ndarray, size: int):
        lo = np.percentile(all_points, 1, axis=0)
        hi = np.percentile(all_points, 99, axis=0)
        self.center = (lo + hi) / 2
        extent = max(hi[0] - lo[0], hi[1] - lo[1], 1e-6)
        self.scale = 0.85 * size / extent
        self.size = size

    def project(self, pts: np.ndarray) -> np.ndarray:
        uv = (pts[:, :2] - self.center[:2]) * self.scale + self.size / 2
        return uv


def render_frame(points: np.ndarray, colors: np.ndarray | None, joints: np.ndarray | None,
                 parents: np.ndarray | None, view: _View, title: str = ""):
    """Draw one frame to a Pillow image.

    Parameters
    ----------
    points
        ``(N, 3)`` metres. Drawn far-to-near so near points cover far ones.
    colors
        ``(N, 3)`` uint8, or ``None`` to colour by depth.
    joints
        ``(J, 3)`` metres or ``None``; ``parents (J,)`` gives the bones to draw.
    """
    from PIL import Image, ImageDraw

    size = view.size
    img = Image.new("RGB", (size, size), (24, 24, 28))
    draw = ImageDraw.Draw(img)
    if len(points):
        order = np.argsort(-points[:, 2])
        uv = view.project(points[order])
        if colors is None:
            z = points[order, 2]
            zn = (z - z.min()) / max(np.ptp(z), 1e-9)
            cols = np.stack([255 * (1 - zn), 80 + 100 * zn, 255 * zn], 1).astype(np.uint8)
        else:
            cols = colors[order]
        arr = np.asarray(img).copy()
        u = np.clip(uv[:, 0].astype(int), 0, size - 2)
        v = np.clip(uv[:, 1].astype(int), 0, size - 2)
        for du in (0, 1):
            for dv in (0, 1):
                arr[v + dv, u + du] = cols
        img = Image.fromarray(arr)
        draw = ImageDraw.Draw(img)
    if joints is not None and len(joints):
        juv = view.project(joints)
        if parents is not None:
            for j, p in enumerate(parents):
                if p >= 0:
                    draw.line([tuple(juv[p]), tuple(juv[j])], fill=(255, 255, 255), width=3)
        for j, (u, v) in enumerate(juv):
            r = 5 if parents is not None and parents[j] < 0 else 4
            draw.ellipse([u - r, v - r, u + r, v + r], fill=(255, 230, 40), outline=(0, 0, 0))
    if title:
        draw.text((6, 4), title, fill=(230, 230, 230))
    return img


def save_skeleton_png(path: str | Path, frames: list[np.ndarray], joints: np.ndarray,
                      parents: np.ndarray, which: list[int] | None = None,
                      point_colors: list[np.ndarray | None] | None = None,
                      size: int = 360) -> None:
    """Write a PNG with panels of the skeleton over the points for a few frames.

    Parameters
    ----------
    frames
        Per-frame points, each ``(N_t, 3)`` metres.
    joints
        ``(F, J, 3)`` joint positions per frame, metres.
    parents
        ``(J,)`` parent joint index (``-1`` root).
    which
        Frame indices to show (default: 4 spread over the sequence).
    point_colors
        Optional per-frame ``(N_t, 3)`` uint8 colours (e.g. by bone).
    """
    from PIL import Image

    F = len(frames)
    if which is None:
        which = sorted(set(np.linspace(0, F - 1, min(4, F)).round().astype(int).tolist()))
    view = _View(np.concatenate([frames[t] for t in which]), size)
    panels = [render_frame(frames[t], None if point_colors is None else point_colors[t],
                           joints[t], parents, view, f"frame {t}") for t in which]
    sheet = Image.new("RGB", (size * len(panels), size))
    for i, p in enumerate(panels):
        sheet.paste(p, (i * size, 0))
    with atomic_path(path) as tmp:
        sheet.save(tmp, format="PNG")


def save_sequence_gif(path: str | Path, frames: list[np.ndarray], joints: np.ndarray,
                      parents: np.ndarray, point_colors: list[np.ndarray | None] | None = None,
                      size: int = 320, fps: float = 10.0, max_frames: int = 60) -> None:
    """Write an animated GIF of the skeleton over the points (at most ``max_frames`` frames)."""
    F = len(frames)
    idx = np.linspace(0, F - 1, min(F, max_frames)).round().astype(int)
    view = _View(np.concatenate([frames[t] for t in idx[:: max(1, len(idx) // 8)]]), size)
    imgs = [render_frame(frames[t], None if point_colors is None else point_colors[t],
                         joints[t], parents, view, f"frame {t}") for t in idx]
    with atomic_path(path) as tmp:
        imgs[0].save(tmp, format="GIF", save_all=True, append_images=imgs[1:],
                     duration=int(1000 / fps), loop=0)
