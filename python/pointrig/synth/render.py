"""Vectorised z-buffer rasterisation of triangle meshes into a depth image.

Every triangle is projected with the pinhole model; each pixel centre inside its screen-space
bounding box is tested with edge functions (barycentric coordinates), and the depth is
interpolated perspective-correctly (``1/z`` is affine in screen space for a planar triangle,
so the depth of a plane is exact). The nearest surface wins per pixel. Candidate pixels of
many triangles are generated at once (``np.repeat`` over bounding-box sizes) in chunks of
bounded memory, so there is no Python loop over triangles.
"""

from __future__ import annotations

import numpy as np

from .camera import Camera

__all__ = ["rasterize", "rasterize_naive", "depth_to_points"]

#: Triangles with a vertex nearer than this (metres) are not drawn.
NEAR_PLANE = 1e-3
#: Maximum candidate pixels processed at once (bounds the memory of one chunk).
CHUNK_CANDIDATES = 1 << 20


def _screen(verts: np.ndarray, tris: np.ndarray, cam: Camera):
    u, v, z = cam.project(verts)
    tz = z[tris]
    ok = (tz > NEAR_PLANE).all(axis=1)
    tu, tv = u[tris], v[tris]
    ok &= np.isfinite(tu).all(axis=1) & np.isfinite(tv).all(axis=1)
    area = (tu[:, 1] - tu[:, 0]) * (tv[:, 2] - tv[:, 0]) - (tu[:, 2] - tu[:, 0]) * (tv[:, 1] - tv[:, 0])
    ok &= np.abs(area) > 1e-12
    x0 = np.maximum(np.ceil(tu.min(axis=1) - 1e-9), 0)
    x1 = np.minimum(np.floor(tu.max(axis=1) + 1e-9), cam.width - 1)
    y0 = np.maximum(np.ceil(tv.min(axis=1) - 1e-9), 0)
    y1 = np.minimum(np.floor(tv.max(axis=1) + 1e-9), cam.height - 1)
    ok &= (x1 >= x0) & (y1 >= y0)
    return tu, tv, tz, area, x0, x1, y0, y1, ok


def rasterize(vertices: np.ndarray, triangles: np.ndarray, cam: Camera
              ) -> tuple[np.ndarray, np.ndarray]:
    """Render a depth image of a triangle mesh given in camera coordinates.

    Parameters
    ----------
    vertices
        ``(V, 3)`` float64, camera frame, metres.
    triangles
        ``(T, 3)`` int vertex indices (either winding; no back-face culling).
    cam
        The camera (intrinsics; the extrinsic is not applied here).

    Returns
    -------
    depth
        ``(H, W)`` float64, metres along the optical axis, ``0`` where nothing is hit.
    tri_index
        ``(H, W)`` int64, the visible triangle per pixel, ``-1`` where nothing is hit.
    """
    verts = np.asarray(vertices, dtype=np.float64)
    tris = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    H, W = cam.height, cam.width
    depth = np.zeros(H * W)
    tri_index = np.full(H * W, -1, dtype=np.int64)
    if len(tris) == 0:
        return depth.reshape(H, W), tri_index.reshape(H, W)
    tu, tv, tz, area, x0, x1, y0, y1, ok = _screen(verts, tris, cam)
    idx = np.nonzero(ok)[0]
    # barycentrics b0, b1 and 1/z are affine in the pixel centre (px, py) for each triangle:
    # f(px, py) = c0 + c1 px + c2 py; one gather of 9 coefficients per candidate pixel
    u0, u1, u2 = tu[idx, 0], tu[idx, 1], tu[idx, 2]
    v0, v1, v2 = tv[idx, 0], tv[idx, 1], tv[idx, 2]
    ia = 1.0 / area[idx]
    b0c = np.stack([(u1 * v2 - u2 * v1) * ia, (v1 - v2) * ia, (u2 - u1) * ia], 1)
    b1c = np.stack([(u2 * v0 - u0 * v2) * ia, (v2 - v0) * ia, (u0 - u2) * ia], 1)
    iz0, iz1, iz2 = 1.0 / tz[idx, 0], 1.0 / tz[idx, 1], 1.0 / tz[idx, 2]
    b2c = -b0c - b1c
    b2c[:, 0] += 1.0
    izc = b0c * iz0[:, None] + b1c * iz1[:, None] + b2c * iz2[:, None]
    coef = np.concatenate([b0c, b1c, izc], axis=1)  # (n, 9)
    bx0 = x0[idx].astype(np.int64)
    by0 = y0[idx].astype(np.int64)
    bw = (x1[idx] - x0[idx] + 1).astype(np.int64)
    bh = (y1[idx] - y0[idx] + 1).astype(np.int64)
    counts = bw * bh
    best_z = np.full(H * W, np.inf)
    csum = np.cumsum(counts)
    cand_pix, cand_z, cand_t = [], [], []
    start = 0
    while start < len(idx):
        base = csum[start - 1] if start > 0 else 0
        stop = int(np.searchsorted(csum, base + CHUNK_CANDIDATES, side="right"))
        stop = max(stop, start + 1)
        cnt = counts[start:stop]
        n = int(cnt.sum())
        lt = np.repeat(np.arange(start, stop), cnt)
        offs = np.arange(n) - np.repeat(np.cumsum(cnt) - cnt, cnt)
        ww = bw[lt]
        dy, dx = np.divmod(offs, ww)
        px = (bx0[lt] + dx).astype(np.float64)
        py = (by0[lt] + dy).astype(np.float64)
        c = coef[lt]
        b0 = c[:, 0] + c[:, 1] * px + c[:, 2] * py
        b1 = c[:, 3] + c[:, 4] * px + c[:, 5] * py
        inside = (b0 >= -1e-12) & (b1 >= -1e-12) & (1.0 - b0 - b1 >= -1e-12)
        if inside.any():
            ci = c[inside]
            z = 1.0 / (ci[:, 6] + ci[:, 7] * px[inside] + ci[:, 8] * py[inside])
            pix = (py[inside] * W + px[inside]).astype(np.int64)
            np.minimum.at(best_z, pix, z)
            cand_pix.append(pix)
            cand_z.append(z)
            cand_t.append(idx[lt[inside]])
        start = stop
    if cand_pix:
        pix = np.concatenate(cand_pix)
        z = np.concatenate(cand_z)
        win = z == best_z[pix]
        tri_index[pix[win]] = np.concatenate(cand_t)[win]
    hit = np.isfinite(best_z)
    depth[hit] = best_z[hit]
    return depth.reshape(H, W), tri_index.reshape(H, W)


def rasterize_naive(vertices: np.ndarray, triangles: np.ndarray, cam: Camera
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Reference rasteriser: a Python loop over triangles (same maths), for tests/benchmarks."""
    verts = np.asarray(vertices, dtype=np.float64)
    tris = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    H, W = cam.height, cam.width
    best = np.full((H, W), np.inf)
    tri_index = np.full((H, W), -1, dtype=np.int64)
    tu, tv, tz, area, x0, x1, y0, y1, ok = _screen(verts, tris, cam)
    for t in np.nonzero(ok)[0]:
        xs = np.arange(int(x0[t]), int(x1[t]) + 1, dtype=np.float64)
        ys = np.arange(int(y0[t]), int(y1[t]) + 1, dtype=np.float64)
        px, py = np.meshgrid(xs, ys)
        u0, u1, u2 = tu[t]
        v0, v1, v2 = tv[t]
        b0 = ((u1 - px) * (v2 - py) - (u2 - px) * (v1 - py)) / area[t]
        b1 = ((u2 - px) * (v0 - py) - (u0 - px) * (v2 - py)) / area[t]
        b2 = 1.0 - b0 - b1
        inside = (b0 >= -1e-12) & (b1 >= -1e-12) & (b2 >= -1e-12)
        z = 1.0 / (b0 / tz[t, 0] + b1 / tz[t, 1] + b2 / tz[t, 2])
        iy = py[inside].astype(int)
        ix = px[inside].astype(int)
        zi = z[inside]
        closer = zi < best[iy, ix]
        best[iy[closer], ix[closer]] = zi[closer]
        tri_index[iy[closer], ix[closer]] = t
    depth = np.where(np.isfinite(best), best, 0.0)
    return depth, tri_index


def depth_to_points(depth: np.ndarray, cam: Camera, du: np.ndarray | None = None,
                    dv: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Back-project the valid pixels of ``depth (H, W)`` to ``(N, 3)`` camera points.

    ``du, dv`` are optional ``(N,)`` sub-pixel offsets (lateral jitter) of the valid pixels in
    row-major order. Returns the points and the flat pixel indices ``(N,)``.
    """
    flat = np.flatnonzero(depth > 0)
    v, u = np.divmod(flat, cam.width)
    u = u.astype(np.float64)
    v = v.astype(np.float64)
    if du is not None:
        u = u + du
    if dv is not None:
        v = v + dv
    return cam.backproject(u, v, depth.reshape(-1)[flat]), flat
