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
    bw = (x1[idx] - x0[idx] + 1).astype(np.int64)
    bh = (y1[idx] - y0[idx] + 1).astype(np.int64)
    counts = bw * bh
    best_z = np.full(H * W, np.inf)
    # chunk boundaries by cumulative candidate count
    csum = np.cumsum(counts)
    start = 0
    while start < len(idx):
        base = csum[start - 1] if start > 0 else 0
        stop = int(np.searchsorted(csum, base + CHUNK_CANDIDATES, side="right"))
        stop = max(stop, start + 1)
        sel = idx[start:stop]
        cnt = counts[start:stop]
        w_ = bw[start:stop]
        n = int(cnt.sum())
        local_tri = np.repeat(np.arange(len(sel)), cnt)
        offs = np.arange(n) - np.repeat(np.cumsum(cnt) - cnt, cnt)
        ww = w_[local_tri]
        px = x0[sel][local_tri] + (offs % ww)
        py = y0[sel][local_tri] + (offs // ww)
        t = sel[local_tri]
        u0, u1, u2 = tu[t, 0], tu[t, 1], tu[t, 2]
        v0, v1, v2 = tv[t, 0], tv[t, 1], tv[t, 2]
        inv_a = 1.0 / area[t]
        b0 = ((u1 - px) * (v2 - py) - (u2 - px) * (v1 - py)) * inv_a
        b1 = ((u2 - px) * (v0 - py) - (u0 - px) * (v2 - py)) * inv_a
        b2 = 1.0 - b0 - b1
        inside = (b0 >= -1e-12) & (b1 >= -1e-12) & (b2 >= -1e-12)
        if inside.any():
            b0, b1, b2, t = b0[inside], b1[inside], b2[inside], t[inside]
            iz = b0 / tz[t, 0] + b1 / tz[t, 1] + b2 / tz[t, 2]
            z = 1.0 / iz
            pix = (py[inside] * W + px[inside]).astype(np.int64)
            # nearest candidate per pixel: sort by (pixel, z), keep the first of each pixel
            order = np.lexsort((z, pix))
            pix_s = pix[order]
            first = np.ones(len(order), dtype=bool)
            first[1:] = pix_s[1:] != pix_s[:-1]
            keep = order[first]
            pk, zk = pix[keep], z[keep]
            closer = zk < best_z[pk]
            best_z[pk[closer]] = zk[closer]
            tri_index[pk[closer]] = t[keep][closer]
        start = stop
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
