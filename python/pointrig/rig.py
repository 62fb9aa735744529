"""The animator's rig: a skinned triangle surface of the subject in the rest pose (``rig.glb``).

:func:`build_surface` reconstructs the surface from the rest points and, to fill what the rest
frame's one view missed or sampled sparsely, the observed points of a few frames moved back
to the rest pose by the inverse of the registration's motion (each observed point ``x`` near
registered point ``y_m^t`` goes to ``q_m + (R_b^t)^T (x - y_m^t)``, ``b`` the point's main
bone). All points are splatted into a voxel grid; the surface is the level set at ``radius``
of their smoothed distance field (marching cubes, scikit-image) with its enclosed hollows
filled, so it is closed and lies about ``radius`` outside the points: a thin shell around a
surface seen from one side, the body's outside around one seen from all sides. Small islands (outliers) are dropped, the mesh is
decimated to the face budget (fast-simplification, quadric error) and given area-weighted
vertex normals.

Skinning weights: each vertex averages the weights of its nearest rest points (Gaussian in
distance, so a vertex takes the bones of the part it lies on), then the weights are smoothed
over the mesh's edges and cut to the 4 largest, renormalised. The mesh moves with the joint
frames of :func:`pointrig.export.joint_transforms` (LBS, ``kinematics.skin``), so it follows
``skeleton.json``'s joints exactly.

Needs the ``rig`` extra (``pip install 'pointrig[rig]'``: scikit-image, fast-simplification).
"""

from __future__ import annotations

import importlib
import logging
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .config import RigConfig
from .errors import PointrigError
from .export import SurfaceMesh, top_weights
from .skeleton import Skeleton

__all__ = ["SurfaceStats", "build_surface", "rig_available", "surface_distances"]

log = logging.getLogger(__name__)

_EXTRA = "the rig surface (rig.glb) needs the rig extra: pip install 'pointrig[rig]'"


def rig_available(mode: str) -> bool:
    """Whether the ``rig`` extra is importable; ``mode`` ``"on"`` makes its absence an error.

    Raises
    ------
    PointrigError
        With ``mode == "on"`` and scikit-image or fast-simplification missing.
    """
    return extra_available(mode, ("fast_simplification", "skimage.measure"), _EXTRA,
                           "rig.glb not written")


def extra_available(mode: str, modules: tuple[str, ...], message: str,
                    skipped: str | None = None) -> bool:
    """Whether the optional ``modules`` import: ``mode`` ``"off"`` answers ``False``, ``"on"``
    makes their absence a :class:`PointrigError` with ``message``, ``"auto"`` answers
    ``False`` (logging ``message`` and ``skipped`` when given)."""
    if mode == "off":
        return False
    try:
        for name in modules:
            importlib.import_module(name)
    except ImportError:
        if mode == "on":
            raise PointrigError(message) from None
        if skipped:
            log.info("%s (%s)", message, skipped)
        return False
    return True


@dataclass
class SurfaceStats:
    """Figures of a reconstructed surface."""

    faces: int  #: triangles after decimation
    voxel: float  #: grid spacing, metres
    radius: float  #: level of the distance field, metres
    n_points: int  #: points the surface was built from (rest + filled)


def _fill_points(skel: Skeleton, frames: list[np.ndarray], registered: np.ndarray,
                 n_frames: int, rest_frame: int, spacing: float) -> np.ndarray:
    """Observed points of ``n_frames`` frames (evenly spread, the rest frame first) moved
    back to the rest pose: ``(K, 3)`` metres, camera frame. A point farther than
    ``3 spacing`` from every registered point is left out (background, outliers)."""
    F = len(frames)
    if n_frames <= 0 or F == 0:
        return np.zeros((0, 3))
    picks = [rest_frame] if 0 <= rest_frame < F else []
    for t in np.linspace(0, F - 1, n_frames).round().astype(int):
        if int(t) not in picks and len(picks) < n_frames:
            picks.append(int(t))
    q = np.asarray(skel.rest_points, dtype=float)
    W = np.asarray(skel.weights, dtype=float)
    main = np.argmax(W, axis=1)
    R = np.asarray(skel.bone_rotations, dtype=float)
    out = []
    for t in picks:
        x = np.asarray(frames[t], dtype=float)
        y = registered[t]
        d, m = cKDTree(y).query(x)
        ok = d < 3.0 * spacing
        x, m = x[ok], m[ok]
        Rb = R[t, main[m]]  # (K, 3, 3)
        out.append(q[m] + np.einsum("kba,kb->ka", Rb, x - y[m]))
    return np.concatenate(out) if out else np.zeros((0, 3))


def _vertex_normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """``(V, 3)`` unit area-weighted vertex normals of a mesh whose faces are CCW outside."""
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    n = np.zeros_like(v)
    for k in range(3):
        np.add.at(n, f[:, k], fn)
    ln = np.linalg.norm(n, axis=1)
    bad = ln < 1e-12 * max(float(ln.max()), 1e-300)
    if bad.any():  # faces that cancel (a fold): the normal of one of them
        own = np.full(len(v), -1)
        for k in range(3):
            own[f[:, k]] = np.arange(len(f))
        n[bad] = fn[own[bad]]
        ln = np.linalg.norm(n, axis=1)
    return n / np.where(ln > 0, ln, 1.0)[:, None]


def _clean(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The mesh without zero-area faces and without vertices no face uses."""
    area = np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)
    f = f[area > 1e-14]
    used = np.unique(f)
    remap = np.full(len(v), -1)
    remap[used] = np.arange(len(used))
    return v[used], remap[f]


def _signed_volume(v: np.ndarray, f: np.ndarray) -> float:
    return float(np.einsum("ki,ki->k", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum() / 6)


def _drop_islands(v: np.ndarray, f: np.ndarray, keep_fraction: float = 0.02
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The mesh without connected pieces of fewer than ``keep_fraction`` of the faces."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    V = len(v)
    rows = np.concatenate([f[:, 0], f[:, 1], f[:, 2]])
    cols = np.concatenate([f[:, 1], f[:, 2], f[:, 0]])
    n, lab = connected_components(coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(V, V)),
                                  directed=False)
    if n == 1:
        return v, f
    flab = lab[f[:, 0]]
    count = np.bincount(flab, minlength=n)
    keep_f = count[flab] >= keep_fraction * len(f)
    f = f[keep_f]
    used = np.unique(f)
    remap = np.full(V, -1)
    remap[used] = np.arange(len(used))
    return v[used], remap[f]


def build_surface(skel: Skeleton, cfg: RigConfig, frames: list[np.ndarray] | None = None,
                  registered: np.ndarray | None = None, rest_frame: int = -1
                  ) -> tuple[SurfaceMesh, SurfaceStats]:
    """The skinned rest-pose surface of the subject (see the module).

    Parameters
    ----------
    skel
        The skeleton with ``rest_points (M, 3)``, ``weights (M, J)`` and
        ``bone_rotations (F, J, 3, 3)`` (camera frame, metres).
    cfg
        ``faces`` (budget), ``voxel`` (0 = auto) and ``fill_frames``.
    frames
        The ``F`` observed clouds ``(N_t, 3)``, metres, or ``None`` (rest points only).
    registered
        ``(F, M, 3)`` the rest points registered to each frame (metres), with ``frames``.
    rest_frame
        Index of the rest frame among ``frames`` (filled first), ``-1`` if unknown.

    Returns
    -------
    mesh, stats

    Raises
    ------
    PointrigError
        Without the ``rig`` extra, or when the points give no surface.
    """
    import fast_simplification
    from scipy import ndimage
    from skimage.measure import marching_cubes

    if skel.rest_points is None or skel.weights is None or skel.bone_rotations is None:
        raise PointrigError("the rig surface needs rest points, weights and bone rotations")
    q = np.asarray(skel.rest_points, dtype=float)
    nn = cKDTree(q).query(q, k=2)[0][:, 1]
    spacing = float(np.median(nn))
    pts = q
    if frames is not None and registered is not None and cfg.fill_frames > 0:
        filled = _fill_points(skel, frames, registered, cfg.fill_frames, rest_frame, spacing)
        pts = np.concatenate([q, filled])
    sub = pts[:: max(1, len(pts) // 20000)]
    nn_sub = cKDTree(pts).query(sub, k=2)[0][:, 1]
    dense = float(np.median(nn_sub))
    if cfg.voxel > 0:
        h = float(cfg.voxel)
    else:
        # half the spacing of the points the surface is built from, and at least 1/160 of the
        # subject's size (finer is not seen at the face budget and costs cubically), 3-30 mm
        size = float(np.max(np.percentile(pts, 99, axis=0) - np.percentile(pts, 1, axis=0)))
        h = float(np.clip(max(0.5 * dense, spacing / 8, size / 160), 0.003, 0.03))
    # the level: two voxels, and more than the gaps between the points so that the shell has
    # no holes; if a 1.5 x larger level closes a body (encloses a hollow), that one
    radius = max(2.0 * h, 1.5 * float(np.percentile(nn_sub, 99)))
    pad = 1.5 * radius + 3 * h
    lo = pts.min(axis=0) - pad
    shape = np.ceil((pts.max(axis=0) + pad - lo) / h).astype(int) + 1
    occ = np.zeros(shape, dtype=bool)
    idx = np.clip(np.round((pts - lo) / h).astype(int), 0, shape - 1)
    occ[idx[:, 0], idx[:, 1], idx[:, 2]] = True
    dist = ndimage.distance_transform_edt(~occ, sampling=h)
    dist = ndimage.gaussian_filter(dist, sigma=1.0)
    # a body seen from all sides would have a second, inner sheet around its hollow inside:
    # fill the hollows so that only the outer surface is left
    for r in (radius, 1.5 * radius):
        solid = dist < r
        hollow = ndimage.binary_fill_holes(solid) & ~solid
        if hollow.any():
            radius = r
            dist[hollow] = 0.0
            break
    if not (dist.min() < radius < dist.max()):
        raise PointrigError("the rest points give no surface (too few points)")
    v, f, _, _ = marching_cubes(dist, level=radius, spacing=(h, h, h))
    v = v + lo
    f = f.astype(np.int64)
    v, f = _drop_islands(v, f)
    if len(f) > cfg.faces:
        v, f = fast_simplification.simplify(v, f.astype(np.int32), target_count=cfg.faces)
        f = np.asarray(f, dtype=np.int64)
        v = np.asarray(v, dtype=float)
    v, f = _clean(v, f)
    if _signed_volume(v, f) < 0:
        f = f[:, ::-1].copy()
    normals = _vertex_normals(v, f)
    weights = _vertex_weights(v, f, q, np.asarray(skel.weights, dtype=float), spacing)
    stats = SurfaceStats(faces=len(f), voxel=h, radius=radius, n_points=len(pts))
    return SurfaceMesh(v, f, normals, weights), stats


def _vertex_weights(v: np.ndarray, f: np.ndarray, q: np.ndarray, W: np.ndarray,
                    spacing: float, k: int = 8, iterations: int = 10) -> np.ndarray:
    """``(V, J)`` weights: Gaussian average of the ``k`` nearest rest points' rows, smoothed
    ``iterations`` times over the mesh edges (half own, half the neighbours' mean), cut to the
    4 largest and renormalised."""
    from scipy.sparse import coo_matrix

    d, m = cKDTree(q).query(v, k=min(k, len(q)))
    d, m = d.reshape(len(v), -1), m.reshape(len(v), -1)
    s = max(spacing, float(np.median(d[:, 0])))
    g = np.exp(-0.5 * ((d - d[:, :1]) / s) ** 2)
    g /= g.sum(axis=1, keepdims=True)
    out = np.einsum("vk,vkj->vj", g, W[m])
    V = len(v)
    rows = np.concatenate([f[:, 0], f[:, 1], f[:, 2], f[:, 1], f[:, 2], f[:, 0]])
    cols = np.concatenate([f[:, 1], f[:, 2], f[:, 0], f[:, 0], f[:, 1], f[:, 2]])
    A = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(V, V)).tocsr()
    A.data[:] = 1.0
    deg = np.asarray(A.sum(axis=1)).ravel()
    for _ in range(iterations):
        out = 0.5 * out + 0.5 * (A @ out) / np.maximum(deg, 1)[:, None]
    idx, w = top_weights(out)
    # a padded slot (fewer than 4 bones) points at joint 0 with weight 0: add, not assign
    dense = np.zeros_like(out)
    for c in range(idx.shape[1]):
        np.add.at(dense, (np.arange(V), idx[:, c].astype(np.int64)), w[:, c])
    return dense


def _closest_on_triangles(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray
                          ) -> np.ndarray:
    """Closest points ``(N, 3)`` of triangles ``(a, b, c)`` (each ``(N, 3)``) to ``p (N, 3)``
    (Ericson, Real-Time Collision Detection, 5.1.5)."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = np.einsum("ij,ij->i", ab, ap), np.einsum("ij,ij->i", ac, ap)
    bp = p - b
    d3, d4 = np.einsum("ij,ij->i", ab, bp), np.einsum("ij,ij->i", ac, bp)
    cp = p - c
    d5, d6 = np.einsum("ij,ij->i", ab, cp), np.einsum("ij,ij->i", ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        v = np.where(denom != 0, vb / denom, 0.0)
        w = np.where(denom != 0, vc / denom, 0.0)
        out = a + ab * v[:, None] + ac * w[:, None]  # inside the face
        # edges
        t_ab = np.clip(np.where(d1 - d3 != 0, d1 / (d1 - d3), 0.0), 0, 1)
        t_ac = np.clip(np.where(d2 - d6 != 0, d2 / (d2 - d6), 0.0), 0, 1)
        t_bc = np.clip(np.where((d4 - d3) + (d5 - d6) != 0,
                                (d4 - d3) / ((d4 - d3) + (d5 - d6)), 0.0), 0, 1)
    e_ab = a + ab * t_ab[:, None]
    e_ac = a + ac * t_ac[:, None]
    e_bc = b + (c - b) * t_bc[:, None]
    out = np.where(((vc <= 0) & (d1 >= 0) & (d3 <= 0))[:, None], e_ab, out)
    out = np.where(((vb <= 0) & (d2 >= 0) & (d6 <= 0))[:, None], e_ac, out)
    out = np.where(((va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0))[:, None], e_bc, out)
    out = np.where(((d6 >= 0) & (d5 <= d6))[:, None], c, out)
    out = np.where(((d3 >= 0) & (d4 <= d3))[:, None], b, out)
    out = np.where(((d1 <= 0) & (d2 <= 0))[:, None], a, out)
    return out


def surface_distances(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
                      candidates: int = 24) -> np.ndarray:
    """Distance of each point to a triangle mesh, ``(N,)`` metres: the exact point-triangle
    distance over the ``candidates`` triangles whose centroids are nearest the point."""
    tri = vertices[faces]
    cen = tri.mean(axis=1)
    _, cand = cKDTree(cen).query(points, k=min(candidates, len(faces)))
    cand = cand.reshape(len(points), -1)
    P = np.repeat(points, cand.shape[1], axis=0)
    t = tri[cand.ravel()]
    cl = _closest_on_triangles(P, t[:, 0], t[:, 1], t[:, 2])
    d = np.linalg.norm(cl - P, axis=1).reshape(len(points), -1)
    return d.min(axis=1)
