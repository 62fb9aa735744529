"""Pictures (numpy + Pillow): PNG previews of frames with joints and bones overlaid, skeleton
sheets over registered points coloured by bone, and animated GIFs.

Points are projected with a pinhole camera (the sequence's own intrinsics when known, else
Kinect v1 at 640x480) and coloured by depth (near = warm, far = cool); joints are white discs,
bones are lines from each joint to its parent.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .io.atomic import atomic_path

__all__ = ["depth_colors", "render_preview", "preview_sequence", "palette", "render_frame",
           "render_mesh", "save_rig_png", "save_skeleton_png", "save_sequence_gif"]

# a compact "turbo"-like colour ramp: (position, r, g, b)
_RAMP = np.array([
    [0.00, 48, 18, 59], [0.15, 70, 107, 227], [0.30, 40, 187, 236], [0.45, 49, 242, 153],
    [0.60, 162, 252, 60], [0.75, 237, 208, 58], [0.88, 251, 128, 34], [1.00, 122, 4, 3],
])


def depth_colors(z: np.ndarray, lo: float | None = None, hi: float | None = None) -> np.ndarray:
    """``(N,)`` depths -> ``(N, 3)`` uint8 colours (near warm, far cool)."""
    z = np.asarray(z, dtype=np.float64)
    if len(z) == 0:
        return np.zeros((0, 3), dtype=np.uint8)
    lo = float(np.percentile(z, 2)) if lo is None else lo
    hi = float(np.percentile(z, 98)) if hi is None else hi
    s = 1.0 - np.clip((z - lo) / max(hi - lo, 1e-9), 0, 1)
    cols = np.stack([np.interp(s, _RAMP[:, 0], _RAMP[:, k]) for k in (1, 2, 3)], axis=1)
    return cols.astype(np.uint8)


def render_preview(points: np.ndarray, joints: np.ndarray | None = None,
                   parents: np.ndarray | None = None, intrinsics: tuple | None = None,
                   scale: int = 0, pred_joints: np.ndarray | None = None,
                   pred_parents: np.ndarray | None = None, title: str | None = None):
    """A :class:`PIL.Image.Image` of ``points (N, 3)`` (camera frame) coloured by depth, with
    ``joints (J, 3)`` and bones (``parents (J,)``) overlaid, optionally a second (predicted)
    skeleton in magenta.

    ``intrinsics = (fx, fy, cx, cy, width, height)``; ``scale`` enlarges the image (0 = auto:
    to at least 640 pixels wide).
    """
    from PIL import Image, ImageDraw

    if intrinsics is None:
        intrinsics = (525.0, 525.0, 319.5, 239.5, 640, 480)
    fx, fy, cx, cy, W, H = (float(v) for v in intrinsics)
    W, H = int(W), int(H)
    k = scale if scale > 0 else max(1, int(np.ceil(640 / W)))
    img = np.full((H * k, W * k, 3), 24, dtype=np.uint8)
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    pts = pts[pts[:, 2] > 1e-6]
    if len(pts):
        u = np.round((fx * pts[:, 0] / pts[:, 2] + cx) * k).astype(np.int64)
        v = np.round((fy * pts[:, 1] / pts[:, 2] + cy) * k).astype(np.int64)
        cols = depth_colors(pts[:, 2])
        order = np.argsort(-pts[:, 2])  # far first, near drawn last
        for du in range(k):
            for dv in range(k):
                uu, vv = u[order] + du - k // 2, v[order] + dv - k // 2
                ok = (uu >= 0) & (uu < W * k) & (vv >= 0) & (vv < H * k)
                img[vv[ok], uu[ok]] = cols[order][ok]
    im = Image.fromarray(img)
    draw = ImageDraw.Draw(im)

    def skel(j, par, colour, rad):
        if j is None:
            return
        j = np.asarray(j, dtype=np.float64).reshape(-1, 3)
        z = np.maximum(j[:, 2], 1e-6)
        ju = (fx * j[:, 0] / z + cx) * k
        jv = (fy * j[:, 1] / z + cy) * k
        if par is not None:
            for a, p in enumerate(np.asarray(par).reshape(-1)):
                if p >= 0:
                    draw.line([(ju[a], jv[a]), (ju[p], jv[p])], fill=colour, width=max(2, k))
        for a in range(len(j)):
            r = rad * k
            draw.ellipse([ju[a] - r, jv[a] - r, ju[a] + r, jv[a] + r], fill=(255, 255, 255),
                         outline=colour)

    skel(joints, parents, (255, 255, 255), 3)
    skel(pred_joints, pred_parents, (255, 0, 255), 2)
    if title:
        draw.text((6, 4), title, fill=(230, 230, 230))
    return im


def preview_sequence(seq_dir: str | Path, out_png: str | Path, frame: int = 0,
                     skeleton_json: str | Path | None = None, isolation=None,
                     topic: str | None = None) -> Path:
    """Write a PNG preview of frame ``frame`` of a sequence folder (``frames/`` + optional
    ``gt.npz``), with GT joints and, optionally, a predicted ``skeleton.json`` overlaid; the
    points as read with ``isolation`` (:class:`pointrig.io.depthcam.Isolation`) and, for a
    bag, ``topic``."""
    from .errors import InputError
    from .io import read_sequence

    d = Path(seq_dir)
    frames_dir = d / "frames" if (d / "frames").is_dir() else d
    seq = read_sequence(frames_dir, start=frame, stop=frame + 1, min_frames=1,
                        isolation=isolation, topic=topic)
    joints = parents = None
    intr = None
    gt_path = d / "gt.npz"
    if gt_path.exists():
        from .synth.scene import load_gt

        gt = load_gt(gt_path)
        if not 0 <= frame < gt["joints"].shape[0]:
            raise InputError(f"frame {frame} out of range (0..{gt['joints'].shape[0] - 1})",
                             gt_path)
        joints, parents = gt["joints"][frame], gt["parents"]
        if "intrinsics" in gt:
            intr = tuple(gt["intrinsics"])
    pj = pp = None
    if skeleton_json is not None:
        from .skeleton import load_skeleton_json

        sk = load_skeleton_json(skeleton_json)
        if frame < sk.n_frames:
            pj, pp = sk.joint_positions[frame], sk.parents
    im = render_preview(seq.frames[0], joints, parents, intr, pred_joints=pj, pred_parents=pp,
                        title=f"{d.name} frame {frame}")
    out = Path(out_png)
    out.parent.mkdir(parents=True, exist_ok=True)
    im.save(out)
    return out


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
            cols = depth_colors(points[order, 2])
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


def _depth_image(path: Path, fmt: str, frame: int, intrinsics: str | Path | None,
                 topic: str | None) -> tuple[np.ndarray, str] | None:
    """Frame ``frame`` of a depth-image input as ``(H, W)`` metres (0: no depth) and its name,
    or ``None`` when the input holds points, not depth images."""
    from .errors import InputError
    from .io.readers import (
        FRAME_FORMATS,
        find_intrinsics,
        natural_key,
        read_intrinsics,
    )
    from .io.recordings import RECORDING_FORMATS, read_recording

    if frame < 0:
        raise InputError(f"frame {frame} is negative", path)
    if fmt in RECORDING_FORMATS:
        given = None if intrinsics is None else read_intrinsics(intrinsics)
        rec = read_recording(path, fmt, start=frame, stop=frame + 1, intrinsics=given,
                             topic=topic, keep_depth=True)
        if not rec.frames:
            raise InputError(f"frame {frame} out of range (the recording has "
                             f"{rec.meta.get('frames_in_file', 0)} frames)", path)
        return (rec.depth[0], rec.names[0]) if rec.depth else None
    if fmt != "depth-png":
        return None
    from PIL import Image

    files = sorted((f for f in path.iterdir() if f.is_file()
                    and FRAME_FORMATS.get(f.suffix.lower()) == fmt),
                   key=lambda f: natural_key(f.name))
    if not 0 <= frame < len(files):
        raise InputError(f"frame {frame} out of range (0..{len(files) - 1})", path)
    intr = read_intrinsics(intrinsics if intrinsics is not None else find_intrinsics(path))
    with Image.open(files[frame]) as im:
        depth = np.asarray(im).astype(np.float64) * intr["depth_scale"]
    return depth.astype(np.float32), files[frame].name


def render_depth_isolation(depth: np.ndarray, isolation=None, title: str | None = None):
    """A :class:`PIL.Image.Image` of a depth image ``(H, W)`` (metres, 0: no depth) showing
    what subject isolation keeps: kept pixels coloured by depth, pixels cut by ``--near/--far``
    or ``--crop`` in grey, no depth black; the ``--crop`` box outlined, and pixel coordinates
    every 50 px along the edges (to pick a box)."""
    from PIL import Image, ImageDraw

    from .io.depthcam import Isolation

    iso = isolation if isolation is not None else Isolation()
    z = np.nan_to_num(np.asarray(depth, dtype=np.float64), nan=0.0)
    valid = z > 0
    kept = valid & iso.depth_mask(z) & iso.pixel_mask(z.shape)
    H, W = z.shape
    pad = 28
    img = np.full((H + 2 * pad, W + 2 * pad, 3), 16, dtype=np.uint8)
    view = img[pad:pad + H, pad:pad + W]
    view[:] = 0
    if valid.any():
        zs = z[valid]
        lo, hi = float(np.percentile(zs, 2)), float(np.percentile(zs, 98))
        g = (200 - 140 * np.clip((z - lo) / max(hi - lo, 1e-9), 0, 1)).astype(np.uint8)
        cut = valid & ~kept
        view[cut] = np.stack([g[cut]] * 3, axis=1) // 2 + 20
        if kept.any():
            view[kept] = depth_colors(z[kept], lo, hi)
    im = Image.fromarray(img)
    draw = ImageDraw.Draw(im)
    for u in range(0, W + 1, 50):
        draw.line([(pad + u, pad - 5), (pad + u, pad - 1)], fill=(200, 200, 200))
        draw.line([(pad + u, pad + H), (pad + u, pad + H + 4)], fill=(200, 200, 200))
        if u % 100 == 0:
            draw.text((pad + u - 6, pad + H + 6), str(u), fill=(200, 200, 200))
    for v in range(0, H + 1, 50):
        draw.line([(pad - 5, pad + v), (pad - 1, pad + v)], fill=(200, 200, 200))
        draw.line([(pad + W, pad + v), (pad + W + 4, pad + v)], fill=(200, 200, 200))
        if v % 100 == 0:
            draw.text((2, pad + v - 5), str(v), fill=(200, 200, 200))
    if iso.crop is not None:
        u0, v0, u1, v1 = iso.crop
        draw.rectangle([pad + u0, pad + v0, pad + u1 - 1, pad + v1 - 1], outline=(255, 255, 255))
    text = f"kept {int(kept.sum())} of {int(valid.sum())} depth pixels"
    if kept.any():
        text += f", z {z[kept].min():.3f}..{z[kept].max():.3f} m"
    draw.text((pad, 4), (title + ": " if title else "") + text, fill=(230, 230, 230))
    return im


def preview_input(path: str | Path, out_png: str | Path, frame: int = 0, isolation=None,
                  intrinsics: str | Path | None = None, topic: str | None = None) -> Path | None:
    """Write a PNG of what subject isolation keeps of frame ``frame`` of a depth-image input
    (a recording, or a folder of depth PNGs): :func:`render_depth_isolation`.

    Returns
    -------
    pathlib.Path or None
        The PNG, or ``None`` when the input holds points rather than depth images (nothing
        written; :func:`preview_sequence` draws those).
    """
    from .io import detect_format

    p = Path(path)
    got = _depth_image(p, detect_format(p), frame, intrinsics, topic)
    if got is None:
        return None
    depth, name = got
    im = render_depth_isolation(depth, isolation, title=f"{p.name} frame {frame} ({name})")
    out = Path(out_png)
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(out) as tmp:
        im.save(tmp, format="PNG")
    return out


def render_mesh(vertices: np.ndarray, faces: np.ndarray, face_colors: np.ndarray,
                joints: np.ndarray | None, parents: np.ndarray | None, view: _View,
                title: str = ""):
    """Draw a triangle mesh seen from the camera to a Pillow image: faces far to near
    (painter's order by mean depth), each shaded by how much it faces the camera (Lambert,
    light at the camera), the skeleton on top.

    Parameters
    ----------
    vertices
        ``(V, 3)`` metres, camera frame (y down, z forward; orthographic along z).
    faces
        ``(K, 3)`` int, counter-clockwise seen from outside.
    face_colors
        ``(K, 3)`` uint8 base colours.
    joints, parents
        ``(J, 3)`` metres and ``(J,)`` parent indices, or ``None``.
    """
    from PIL import Image, ImageDraw

    size = view.size
    img = Image.new("RGB", (size, size), (24, 24, 28))
    draw = ImageDraw.Draw(img)
    tri = vertices[faces]  # (K, 3, 3)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    # facing the camera: the outward normal points back along -z; back faces are hidden
    lit = -n[:, 2]
    front = lit > 0
    order = np.flatnonzero(front)[np.argsort(-tri[front, :, 2].mean(axis=1), kind="stable")]
    uv = view.project(tri.reshape(-1, 3)).reshape(-1, 3, 2)
    shade = (0.25 + 0.75 * np.clip(lit, 0, 1))[:, None] * face_colors
    cols = np.clip(shade, 0, 255).astype(np.uint8)
    for k in order:
        draw.polygon([tuple(p) for p in uv[k]], fill=tuple(int(c) for c in cols[k]))
    if joints is not None and len(joints):
        juv = view.project(joints)
        if parents is not None:
            for j, p in enumerate(parents):
                if p >= 0:
                    draw.line([tuple(juv[p]), tuple(juv[j])], fill=(255, 255, 255), width=2)
        for u, v in juv:
            draw.ellipse([u - 3, v - 3, u + 3, v + 3], fill=(255, 230, 40), outline=(0, 0, 0))
    if title:
        draw.text((6, 4), title, fill=(230, 230, 230))
    return img


def _distinct_poses(joints: np.ndarray, n: int = 3) -> list[int]:
    """``n`` frames of ``joints (F, J, 3)`` whose poses differ most: frame 0, then each time
    the frame farthest (mean joint distance, root placed at the origin) from those chosen."""
    rel = joints - joints[:, :1]
    chosen = [0]
    while len(chosen) < min(n, len(joints)):
        d = np.min([np.linalg.norm(rel - rel[c], axis=2).mean(axis=1) for c in chosen], axis=0)
        chosen.append(int(np.argmax(d)))
    return sorted(set(chosen))


def save_rig_png(path: str | Path, vertices: np.ndarray, faces: np.ndarray,
                 weights: np.ndarray, R: np.ndarray, T: np.ndarray, joints: np.ndarray,
                 parents: np.ndarray, size: int = 360) -> None:
    """Write ``rig.png``: the skinned surface posed in three frames of the sequence (the
    most different poses), coloured by each face's main bone, with the skeleton.

    Parameters
    ----------
    vertices, faces
        ``(V, 3)`` rest-pose vertices (metres, camera frame) and ``(K, 3)`` faces.
    weights
        ``(V, J)`` skinning weights.
    R, T
        ``(F, J, 3, 3)``, ``(F, J, 3)`` the joint frames' ``T_frame_rest``
        (:func:`pointrig.export.joint_transforms`).
    joints
        ``(F, J, 3)`` joint positions, metres; ``parents (J,)``.
    """
    from PIL import Image

    from .kinematics import skin

    which = _distinct_poses(np.asarray(joints))
    posed = skin(vertices, weights, R[which], T[which])  # (3, V, 3)
    view = _View(np.concatenate(list(posed)), size)
    main = np.argmax(weights[faces].sum(axis=1), axis=1)
    base = palette(max(weights.shape[1], 1))[main].astype(float)
    panels = [render_mesh(posed[i], faces, base, joints[t], parents, view, f"frame {t}")
              for i, t in enumerate(which)]
    sheet = Image.new("RGB", (size * len(panels), size))
    for i, p in enumerate(panels):
        sheet.paste(p, (i * size, 0))
    with atomic_path(path) as tmp:
        sheet.save(tmp, format="PNG")
