"""Procedural articulated figures: a bone tree dressed with tapered capsules and ellipsoids,
skinned by linear blend skinning (Eq. 13 of the paper) with smooth weights near the joints,
and animated by smooth joint-angle trajectories within joint limits.

World frame: metres, ``y`` up, subjects stand on (or float above) ``y = 0`` and face ``+z``
(quadrupeds and snakes face ``+x`` so that the camera on ``+z`` sees them side-on).

Each bone owns one joint, its *head* (the pointrig convention, see
:mod:`pointrig.kinematics`); joint names are those of the anatomical joints (``elbow_l`` is
the head of the forearm). Bone transforms are ``T_frame_rest``: ``x = R[t, b] @ q + T[t, b]``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import ConfigError

__all__ = ["FIGURES", "Dof", "Figure", "make_figure", "rodrigues"]

FIGURES: tuple[str, ...] = ("human", "upper_body", "arm", "hand", "quadruped", "snake",
                            "robot_arm")

#: Mesh resolution: vertices around each primitive, rings per hemispherical cap, and the
#: target spacing of rings along a bone (metres, relative to the figure's size).
N_AROUND = 16
N_CAP = 4
RING_SPACING = 0.018  # fraction of the figure height between rings along a bone
#: Joint-angle trajectories: 0.65 sin(2 pi f1 t + p1) + 0.35 sin(2 pi f2 t + p2), with f1, f2
#: drawn (seeded) from these ranges in Hz (scaled by ``speed``).
FREQ1 = (0.15, 0.4)
FREQ2 = (0.4, 0.8)


def rodrigues(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` about unit ``axis (3,)`` by ``angle (...)`` radians."""
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    th = np.asarray(angle, dtype=np.float64)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    s = np.sin(th)[..., None, None]
    c = np.cos(th)[..., None, None]
    return np.eye(3) + s * K + (1 - c) * (K @ K)


@dataclass(frozen=True)
class Dof:
    """One rotational degree of freedom of a bone about its head.

    ``axis`` is a direction in the rest-pose world frame (it moves with the parent), or
    ``None`` for a twist about the bone's own axis. ``lo, hi`` are limits in degrees.
    ``wave = (frequency_hz, phase_rad)`` makes a single travelling-wave sinusoid instead of the
    seeded random mixture (used for snake undulation).
    """

    axis: tuple[float, float, float] | None
    lo: float
    hi: float
    wave: tuple[float, float] | None = None


@dataclass
class _BoneSpec:
    name: str
    parent: int
    head: np.ndarray
    tail: np.ndarray
    shape: str  # "capsule" (radii at head, tail) or "ellipsoid" (radii across x_l, z_l)
    radii: tuple[float, float]
    ext: float = 1.0  # ellipsoid: semi-axis along the bone = ext * length / 2
    dofs: list[Dof] = field(default_factory=list)


def _bone_frame(head: np.ndarray, tail: np.ndarray) -> np.ndarray:
    """Columns: local x, y (= bone direction), z, in world coordinates."""
    y = tail - head
    y = y / np.linalg.norm(y)
    ref = np.array([1.0, 0.0, 0.0]) if abs(y[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    x = ref - (ref @ y) * y
    x /= np.linalg.norm(x)
    z = np.cross(x, y)
    return np.stack([x, y, z], axis=1)


def area_samples(vertices: np.ndarray, triangles: np.ndarray, n: int, seed: int
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``n`` points uniform in area on the mesh ``vertices (V, 3)``, ``triangles (T, 3)``:
    triangle indices ``(n,)``, barycentric coordinates ``(n, 3)`` and positions ``(n, 3)``
    (metres), from the stream ``SeedSequence([seed, 11])``."""
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 11]))
    v = vertices[triangles]
    area = 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1)
    tri = rng.choice(len(area), size=n, p=area / area.sum())
    r1, r2 = rng.random(len(tri)), rng.random(len(tri))
    s = np.sqrt(r1)
    bary = np.stack([1 - s, s * (1 - r2), s * r2], axis=1)
    return tri, bary, np.einsum("sk,ski->si", bary, v[tri])


def _smoothstep(s: np.ndarray) -> np.ndarray:
    s = np.clip(s, 0.0, 1.0)
    return s * s * (3 - 2 * s)


@dataclass
class Figure:
    """An articulated figure: bone tree, skinned triangle mesh and joint limits.

    Attributes
    ----------
    name
        Figure name.
    joint_names
        ``B`` names; joint ``b`` is the head of bone ``b``.
    parents
        ``(B,)`` int, parent bone, ``-1`` for the root; ``parents[b] < b``.
    heads, tails
        ``(B, 3)`` rest-pose joint positions and bone ends, world metres.
    dofs
        Per bone, the list of :class:`Dof` applied in order (``R_local = R_1 R_2 ...``).
    vertices
        ``(V, 3)`` rest-pose mesh vertices, world metres.
    triangles
        ``(T, 3)`` int.
    weights
        ``(V, B)`` LBS weights (rows sum to 1, at most 2 non-zeros).
    vertex_bone
        ``(V,)`` the bone whose primitive made each vertex.
    facing
        World direction from the subject towards the default camera position.
    rigid
        True for machines: each vertex follows one bone only.
    """

    name: str
    joint_names: list[str]
    parents: np.ndarray
    heads: np.ndarray
    tails: np.ndarray
    dofs: list[list[Dof]]
    vertices: np.ndarray
    triangles: np.ndarray
    weights: np.ndarray
    vertex_bone: np.ndarray
    specs: list[_BoneSpec]
    facing: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    rigid: bool = False

    @property
    def n_bones(self) -> int:
        """Number of bones (= joints) ``B``."""
        return len(self.joint_names)

    @property
    def size(self) -> float:
        """Diagonal of the rest-pose bounding box, metres."""
        return float(np.linalg.norm(self.vertices.max(0) - self.vertices.min(0)))

    def angles(self, n_frames: int, fps: float = 30.0, speed: float = 1.0,
               amplitude: float = 1.0, seed: int = 0) -> list[np.ndarray]:
        """Smooth joint-angle trajectories, per bone ``(F, n_dof)`` radians.

        Each angle is ``mid + half * amplitude * (0.65 sin(2 pi f1 s t + p1) + 0.35 sin(2 pi f2
        s t + p2))`` with ``mid, half`` from the joint limits, ``s = speed``, frequencies and
        phases drawn from ``seed``; so angles stay within the limits for ``amplitude <= 1``.
        """
        rng = np.random.default_rng(np.random.SeedSequence([int(seed), 7]))
        t = np.arange(n_frames) / float(fps)
        glob = rng.uniform(0, 2 * np.pi)
        out = []
        for dofs in self.dofs:
            a = np.zeros((n_frames, len(dofs)))
            for k, d in enumerate(dofs):
                f1, f2 = rng.uniform(*FREQ1), rng.uniform(*FREQ2)
                p1, p2 = rng.uniform(0, 2 * np.pi, size=2)
                mid = np.radians(d.lo + d.hi) / 2
                half = np.radians(d.hi - d.lo) / 2
                if d.wave is not None:
                    f, ph = d.wave
                    s = np.sin(2 * np.pi * f * speed * t - ph + glob)
                else:
                    s = (0.65 * np.sin(2 * np.pi * f1 * speed * t + p1)
                         + 0.35 * np.sin(2 * np.pi * f2 * speed * t + p2))
                a[:, k] = mid + half * amplitude * s
            out.append(a)
        return out

    def rest_angles(self, n_frames: int = 1) -> list[np.ndarray]:
        """All-zero angles (the rest pose), per bone ``(F, n_dof)``."""
        return [np.zeros((n_frames, len(d))) for d in self.dofs]

    def forward(self, angles: list[np.ndarray], placement_R: np.ndarray | None = None,
                placement_t: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Forward kinematics.

        Parameters
        ----------
        angles
            Per bone ``(F, n_dof)`` radians.
        placement_R, placement_t
            Optional world placement of the whole figure per frame, ``(F, 3, 3)`` and
            ``(F, 3)`` (e.g. walking): ``x_world = P_R x + P_t``.

        Returns
        -------
        R, T
            ``(F, B, 3, 3)``, ``(F, B, 3)``: ``T_frame_rest`` of every bone, world frame.
        """
        F = angles[0].shape[0]
        B = self.n_bones
        R = np.zeros((F, B, 3, 3))
        T = np.zeros((F, B, 3))
        for b in range(B):
            Rl = np.broadcast_to(np.eye(3), (F, 3, 3)).copy()
            axis_bone = self.tails[b] - self.heads[b]
            for k, d in enumerate(self.dofs[b]):
                ax = axis_bone if d.axis is None else np.asarray(d.axis, dtype=np.float64)
                Rl = Rl @ rodrigues(ax, angles[b][:, k])
            h = self.heads[b]
            p = self.parents[b]
            if p < 0:
                R[:, b] = Rl
                T[:, b] = h - Rl @ h
            else:
                R[:, b] = R[:, p] @ Rl
                joint = R[:, p] @ h + T[:, p]
                T[:, b] = joint - R[:, b] @ h
        if placement_R is not None:
            R = np.einsum("fij,fbjk->fbik", placement_R, R)
            T = np.einsum("fij,fbj->fbi", placement_R, T)
        if placement_t is not None:
            T = T + placement_t[:, None, :]
        return R, T

    def joints(self, R: np.ndarray, T: np.ndarray) -> np.ndarray:
        """Joint positions ``(F, B, 3)`` from bone transforms."""
        return np.einsum("fbij,bj->fbi", R, self.heads) + T

    def skin_points(self, points: np.ndarray, weights: np.ndarray, R: np.ndarray,
                    T: np.ndarray) -> np.ndarray:
        """LBS (Eq. 13) of rest points ``(M, 3)`` with weights ``(M, B)`` -> ``(F, M, 3)``."""
        from ..kinematics import skin

        return skin(points, weights, R, T)

    def skin(self, R: np.ndarray, T: np.ndarray) -> np.ndarray:
        """Posed mesh vertices ``(F, V, 3)``."""
        return self.skin_points(self.vertices, self.weights, R, T)

    def inside(self, points: np.ndarray, exclude: int = -1, margin: float = 1e-3) -> np.ndarray:
        """Whether rest-pose points ``(N, 3)`` lie strictly inside any bone's primitive other
        than ``exclude`` (by more than ``margin`` metres)."""
        out = np.zeros(len(points), dtype=bool)
        for b, sp in enumerate(self.specs):
            if b == exclude:
                continue
            fr = _bone_frame(sp.head, sp.tail)
            L = float(np.linalg.norm(sp.tail - sp.head))
            loc = (points - sp.head) @ fr  # columns: x_l, axial, z_l
            if sp.shape == "capsule":
                a = np.clip(loc[:, 1], 0, L)
                r = sp.radii[0] + (sp.radii[1] - sp.radii[0]) * a / L
                d = np.sqrt(loc[:, 0] ** 2 + (loc[:, 1] - a) ** 2 + loc[:, 2] ** 2)
                out |= d < r - margin
            else:
                ay = sp.ext * L / 2
                q = ((loc[:, 0] / sp.radii[0]) ** 2 + ((loc[:, 1] - L / 2) / ay) ** 2
                     + (loc[:, 2] / sp.radii[1]) ** 2)
                scale = margin / max(min(sp.radii[0], sp.radii[1], ay), 1e-9)
                out |= q < (1 - scale) ** 2
        return out

    def sample_surface(self, n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Area-uniform samples on the outer rest-pose surface.

        Returns ``tri (S,)`` triangle indices, ``bary (S, 3)`` barycentric coordinates, and the
        rest positions ``(S, 3)``. Samples buried inside another primitive are dropped, so
        ``S <= n``.
        """
        tri, bary, pts = area_samples(self.vertices, self.triangles, int(n * 1.6) + 16, seed)
        owner = self.vertex_bone[self.triangles[tri, 0]]
        keep = np.ones(len(tri), dtype=bool)
        for b in range(self.n_bones):
            m = owner == b
            if m.any():
                keep[m] = ~self.inside(pts[m], exclude=b)
        idx = np.nonzero(keep)[0][:n]
        return tri[idx], bary[idx], pts[idx]


def _primitive_mesh(sp: _BoneSpec, ring_spacing: float) -> tuple[np.ndarray, np.ndarray,
                                                                  np.ndarray]:
    """Vertices ``(V, 3)``, triangles ``(T, 3)`` and axial coordinates ``(V,)`` (metres from the
    head along the bone) of one bone's primitive."""
    fr = _bone_frame(sp.head, sp.tail)
    L = float(np.linalg.norm(sp.tail - sp.head))
    rings = []  # (axial, rx, rz)
    if sp.shape == "capsule":
        r0, r1 = sp.radii
        for phi in np.linspace(0, np.pi / 2, N_CAP + 1):
            rings.append((-r0 * np.cos(phi), r0 * np.sin(phi), r0 * np.sin(phi)))
        n_len = max(1, int(np.ceil(L / ring_spacing)))
        for a in np.linspace(0, L, n_len + 1)[1:-1]:
            r = r0 + (r1 - r0) * a / L
            rings.append((a, r, r))
        for phi in np.linspace(np.pi / 2, np.pi, N_CAP + 1):
            rings.append((L - r1 * np.cos(phi), r1 * np.sin(phi), r1 * np.sin(phi)))
    elif sp.shape == "ellipsoid":
        ay = sp.ext * L / 2
        n_lat = max(2 * N_CAP, int(np.ceil(2 * ay / ring_spacing)))
        for phi in np.linspace(0, np.pi, n_lat + 1):
            rings.append((L / 2 - ay * np.cos(phi), sp.radii[0] * np.sin(phi),
                          sp.radii[1] * np.sin(phi)))
    else:
        raise ValueError(f"unknown primitive shape {sp.shape!r}")
    rings_a = np.array(rings)
    th = np.linspace(0, 2 * np.pi, N_AROUND, endpoint=False)
    nr = len(rings_a)
    loc = np.zeros((nr, N_AROUND, 3))
    loc[..., 0] = rings_a[:, 1:2] * np.cos(th)
    loc[..., 1] = rings_a[:, 0:1]
    loc[..., 2] = rings_a[:, 2:3] * np.sin(th)
    verts = sp.head + loc.reshape(-1, 3) @ fr.T
    axial = np.repeat(rings_a[:, 0], N_AROUND)
    i = np.arange(nr - 1)[:, None] * N_AROUND
    j = np.arange(N_AROUND)[None, :]
    jn = (j + 1) % N_AROUND
    a0, a1, b0, b1 = i + j, i + jn, i + N_AROUND + j, i + N_AROUND + jn
    tris = np.concatenate([np.stack([a0, b0, a1], -1).reshape(-1, 3),
                           np.stack([a1, b0, b1], -1).reshape(-1, 3)])
    # drop the degenerate triangles at the poles
    ring_r = rings_a[:, 1]
    ring_of = tris // N_AROUND
    degenerate = (ring_r[ring_of] < 1e-12).sum(axis=1) >= 2
    return verts, tris[~degenerate], axial


def _build(name: str, specs: list[_BoneSpec], rigid: bool = False,
           facing: tuple[float, float, float] = (0.0, 0.0, 1.0)) -> Figure:
    B = len(specs)
    for b, sp in enumerate(specs):
        if sp.parent >= b:
            raise ValueError(f"bone {sp.name}: parent must come before the child")
    heads = np.array([sp.head for sp in specs], dtype=np.float64)
    tails = np.array([sp.tail for sp in specs], dtype=np.float64)
    all_pts = np.concatenate([heads, tails])
    height = float(np.linalg.norm(all_pts.max(0) - all_pts.min(0)))
    spacing = RING_SPACING * height
    children: list[list[int]] = [[] for _ in range(B)]
    for b, sp in enumerate(specs):
        if sp.parent >= 0:
            children[sp.parent].append(b)
    verts, tris, W, owner = [], [], [], []
    nv = 0
    for b, sp in enumerate(specs):
        v, t, axial = _primitive_mesh(sp, spacing)
        L = float(np.linalg.norm(sp.tail - sp.head))
        w = np.zeros((len(v), B))
        if rigid:
            w[:, b] = 1.0
        else:
            w_par = np.zeros(len(v))
            w_chd = np.zeros(len(v))
            if sp.parent >= 0:
                blend = min(0.45 * L, max(sp.radii))
                w_par = 0.5 * (1 - _smoothstep(axial / blend))
                w[:, sp.parent] += w_par
            # blend into the one child that continues this bone at its tail
            cont = [c for c in children[b]
                    if np.linalg.norm(specs[c].head - sp.tail) < 0.5 * max(sp.radii)]
            if len(children[b]) == 1 and cont:
                c = cont[0]
                blend = min(0.45 * L, max(sp.radii))
                w_chd = 0.5 * (1 - _smoothstep((L - axial) / blend))
                w[:, c] += w_chd
            w[:, b] += 1.0 - w_par - w_chd
        verts.append(v)
        tris.append(t + nv)
        W.append(w)
        owner.append(np.full(len(v), b))
        nv += len(v)
    return Figure(
        name=name,
        joint_names=[sp.name for sp in specs],
        parents=np.array([sp.parent for sp in specs], dtype=np.int64),
        heads=heads,
        tails=tails,
        dofs=[list(sp.dofs) for sp in specs],
        vertices=np.concatenate(verts),
        triangles=np.concatenate(tris).astype(np.int64),
        weights=np.concatenate(W),
        vertex_bone=np.concatenate(owner).astype(np.int64),
        specs=specs,
        facing=np.asarray(facing, dtype=np.float64),
        rigid=rigid,
    )


X, Y, Z = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)


class _Builder:
    def __init__(self) -> None:
        self.specs: list[_BoneSpec] = []
        self.index: dict[str, int] = {}

    def add(self, name: str, parent: str | None, head, tail, shape: str = "capsule",
            radii: tuple[float, float] = (0.05, 0.04), ext: float = 1.0,
            dofs: list[Dof] | None = None) -> None:
        p = -1 if parent is None else self.index[parent]
        self.index[name] = len(self.specs)
        self.specs.append(_BoneSpec(name, p, np.asarray(head, float), np.asarray(tail, float),
                                    shape, radii, ext, list(dofs or [])))

    def mirror(self, names: list[str], normal, suffix: tuple[str, str]) -> None:
        """Add mirror images (through the plane through the origin with ``normal``) of the
        named bones, renaming ``suffix[0]`` to ``suffix[1]``."""
        n = np.asarray(normal, dtype=np.float64)
        M = np.eye(3) - 2 * np.outer(n, n)
        for nm in names:
            sp = self.specs[self.index[nm]]
            parent = None if sp.parent < 0 else self.specs[sp.parent].name
            if parent is not None and parent.endswith(suffix[0]):
                parent = parent[: -len(suffix[0])] + suffix[1]
            dofs = [Dof(None if d.axis is None else tuple(M @ np.asarray(d.axis)), -d.hi, -d.lo,
                        d.wave) for d in sp.dofs]
            self.add(nm[: -len(suffix[0])] + suffix[1], parent, M @ sp.head, M @ sp.tail,
                     sp.shape, sp.radii, sp.ext, dofs)


def _torso_head(b: _Builder, full: bool) -> None:
    root_dofs = ([Dof(Y, -25, 25), Dof(X, -8, 8), Dof(Z, -6, 6)] if full
                 else [Dof(Y, -15, 15), Dof(X, -5, 10)])
    b.add("pelvis", None, (0, 0.95, 0), (0, 1.05, 0), "ellipsoid", (0.16, 0.11), 1.7, root_dofs)
    b.add("spine", "pelvis", (0, 1.05, 0), (0, 1.28, 0), "ellipsoid", (0.145, 0.10), 1.25,
          [Dof(X, -10, 30), Dof(Z, -12, 12), Dof(None, -25, 25)])
    b.add("chest", "spine", (0, 1.28, 0), (0, 1.48, 0), "ellipsoid", (0.175, 0.11), 1.25,
          [Dof(X, -8, 15), Dof(None, -20, 20)])
    b.add("neck", "chest", (0, 1.48, 0), (0, 1.57, 0), "capsule", (0.055, 0.05), 1.0,
          [Dof(X, -20, 25), Dof(None, -35, 35)])
    b.add("head", "neck", (0, 1.57, 0), (0, 1.79, 0), "ellipsoid", (0.08, 0.095), 1.0,
          [Dof(X, -20, 20), Dof(Z, -15, 15)])


def _arm(b: _Builder, parent: str | None, y: float = 1.42, x0: float = 0.19,
         root_dofs: list[Dof] | None = None) -> None:
    b.add("shoulder_l", parent, (x0, y, 0), (x0 + 0.28, y, 0), "capsule", (0.052, 0.042), 1.0,
          root_dofs or [Dof(Z, -75, 35), Dof(Y, -80, 30), Dof(None, -40, 40)])
    b.add("elbow_l", "shoulder_l", (x0 + 0.28, y, 0), (x0 + 0.54, y, 0), "capsule",
          (0.04, 0.031), 1.0, [Dof(Y, -125, 0), Dof(None, -50, 30)])
    b.add("wrist_l", "elbow_l", (x0 + 0.54, y, 0), (x0 + 0.71, y, 0), "ellipsoid",
          (0.045, 0.02), 1.15, [Dof(Z, -35, 35), Dof(Y, -50, 50)])


def _figure_human() -> Figure:
    b = _Builder()
    _torso_head(b, full=True)
    _arm(b, "chest")
    b.mirror(["shoulder_l", "elbow_l", "wrist_l"], X, ("_l", "_r"))
    b.add("hip_l", "pelvis", (0.09, 0.93, 0), (0.09, 0.50, 0), "capsule", (0.075, 0.052), 1.0,
          [Dof(X, -70, 25), Dof(Z, -5, 35), Dof(None, -25, 25)])
    b.add("knee_l", "hip_l", (0.09, 0.50, 0), (0.09, 0.08, 0), "capsule", (0.05, 0.038), 1.0,
          [Dof(X, 0, 110)])
    b.add("ankle_l", "knee_l", (0.09, 0.08, 0), (0.09, 0.03, 0.17), "ellipsoid", (0.045, 0.032),
          1.35, [Dof(X, -25, 30)])
    b.mirror(["hip_l", "knee_l", "ankle_l"], X, ("_l", "_r"))
    return _build("human", b.specs)


def _figure_upper_body() -> Figure:
    b = _Builder()
    _torso_head(b, full=False)
    _arm(b, "chest")
    b.mirror(["shoulder_l", "elbow_l", "wrist_l"], X, ("_l", "_r"))
    return _build("upper_body", b.specs)


def _figure_arm() -> Figure:
    b = _Builder()
    _arm(b, None, y=1.4, x0=0.0)
    return _build("arm", b.specs)


def _figure_hand() -> Figure:
    b = _Builder()
    b.add("wrist", None, (0, 0, 0), (0, 0.09, 0), "ellipsoid", (0.043, 0.015), 1.15,
          [Dof(X, -50, 50), Dof(Z, -25, 25), Dof(None, -40, 40)])
    fingers = {"index": (0.026, 0.92), "middle": (0.008, 1.0), "ring": (-0.010, 0.95),
               "pinky": (-0.027, 0.78)}
    for fname, (x, s) in fingers.items():
        y0 = 0.085 - (1 - s) * 0.05
        l1, l2, l3 = 0.046 * s, 0.028 * s, 0.022 * s
        r = 0.0085 * (0.85 + 0.15 * s)
        b.add(f"{fname}_mcp", "wrist", (x, y0, 0), (x, y0 + l1, 0), "capsule", (r, r * 0.9), 1.0,
              [Dof(X, 0, 80), Dof(Z, -12, 12)])
        b.add(f"{fname}_pip", f"{fname}_mcp", (x, y0 + l1, 0), (x, y0 + l1 + l2, 0), "capsule",
              (r * 0.9, r * 0.8), 1.0, [Dof(X, 0, 95)])
        b.add(f"{fname}_dip", f"{fname}_pip", (x, y0 + l1 + l2, 0), (x, y0 + l1 + l2 + l3, 0),
              "capsule", (r * 0.8, r * 0.7), 1.0, [Dof(X, 0, 70)])
    p0, p1, p2, p3 = (0.024, 0.012, 0.004), (0.05, 0.042, 0.01), (0.066, 0.068, 0.012), \
        (0.076, 0.09, 0.012)
    b.add("thumb_cmc", "wrist", p0, p1, "capsule", (0.013, 0.011), 1.0,
          [Dof(Z, -15, 25), Dof(X, 0, 40)])
    b.add("thumb_mcp", "thumb_cmc", p1, p2, "capsule", (0.0105, 0.0095), 1.0,
          [Dof(Z, 0, 40), Dof(X, 0, 30)])
    b.add("thumb_ip", "thumb_mcp", p2, p3, "capsule", (0.0095, 0.008), 1.0, [Dof(Z, 0, 60)])
    return _build("hand", b.specs)


def _figure_quadruped() -> Figure:
    b = _Builder()
    b.add("hips", None, (-0.32, 0.55, 0), (-0.02, 0.57, 0), "ellipsoid", (0.12, 0.13), 1.4,
          [Dof(Z, -8, 8), Dof(Y, -15, 15), Dof(None, -6, 6)])
    b.add("chest", "hips", (-0.02, 0.57, 0), (0.28, 0.6, 0), "ellipsoid", (0.13, 0.15), 1.3,
          [Dof(Z, -10, 10), Dof(Y, -15, 15), Dof(None, -8, 8)])
    b.add("neck", "chest", (0.28, 0.62, 0), (0.40, 0.78, 0), "capsule", (0.06, 0.05), 1.0,
          [Dof(Z, -25, 25), Dof(Y, -30, 30)])
    b.add("head", "neck", (0.40, 0.78, 0), (0.60, 0.74, 0), "ellipsoid", (0.07, 0.075), 1.1,
          [Dof(Z, -20, 20), Dof(Y, -25, 25)])
    b.add("tail", "hips", (-0.40, 0.58, 0), (-0.56, 0.64, 0), "capsule", (0.03, 0.022), 1.0,
          [Dof(Z, -30, 40), Dof(Y, -40, 40)])
    b.add("tail_tip", "tail", (-0.56, 0.64, 0), (-0.74, 0.64, 0), "capsule", (0.022, 0.012), 1.0,
          [Dof(Z, -30, 30), Dof(Y, -40, 40)])
    for leg, parent, x, knee in (("front", "chest", 0.22, (-70, 5)),
                                 ("rear", "hips", -0.28, (-5, 70))):
        z = 0.09
        b.add(f"{leg}_shoulder_l" if leg == "front" else "rear_hip_l", parent, (x, 0.50, z),
              (x, 0.30, z), "capsule", (0.05, 0.035), 1.0, [Dof(Z, -35, 35), Dof(X, -8, 8)])
        up = f"{leg}_shoulder_l" if leg == "front" else "rear_hip_l"
        b.add(f"{leg}_knee_l", up, (x, 0.30, z), (x, 0.07, z), "capsule", (0.032, 0.025), 1.0,
              [Dof(Z, *knee)])
        b.add(f"{leg}_paw_l", f"{leg}_knee_l", (x, 0.07, z), (x + 0.06, 0.02, z), "capsule",
              (0.028, 0.022), 1.0, [Dof(Z, -30, 30)])
    b.mirror(["front_shoulder_l", "front_knee_l", "front_paw_l", "rear_hip_l", "rear_knee_l",
              "rear_paw_l"], Z, ("_l", "_r"))
    return _build("quadruped", b.specs)


def _figure_snake() -> Figure:
    b = _Builder()
    n = 10
    length = 1.4
    seg = length / n
    y = 0.25
    r = np.linspace(0.05, 0.014, n + 1)
    b.add("head", None, (0.7, y, 0), (0.7 - seg, y, 0), "capsule", (r[0], r[1]), 1.0,
          [Dof(Y, -20, 20), Dof(Z, -10, 10)])
    prev = "head"
    for i in range(1, n):
        nm = f"seg{i}"
        b.add(nm, prev, (0.7 - i * seg, y, 0), (0.7 - (i + 1) * seg, y, 0), "capsule",
              (r[i], r[i + 1]), 1.0,
              [Dof(Y, -28, 28, wave=(0.8, 0.7 * i)), Dof(Z, -15, 15, wave=(0.8, 0.7 * i + 1.2))])
        prev = nm
    return _build("snake", b.specs)


def _figure_robot_arm() -> Figure:
    b = _Builder()
    b.add("base", None, (0, 0, 0), (0, 0.12, 0), "capsule", (0.11, 0.11))
    b.add("turret", "base", (0, 0.12, 0), (0, 0.28, 0), "capsule", (0.075, 0.075), 1.0,
          [Dof(None, -90, 90)])
    b.add("shoulder", "turret", (0, 0.28, 0), (0, 0.72, 0), "capsule", (0.055, 0.05), 1.0,
          [Dof(Z, -70, 25)])
    b.add("elbow", "shoulder", (0, 0.72, 0), (0, 1.08, 0), "capsule", (0.045, 0.04), 1.0,
          [Dof(Z, -10, 130)])
    b.add("wrist", "elbow", (0, 1.08, 0), (0, 1.18, 0), "capsule", (0.035, 0.035), 1.0,
          [Dof(Z, -90, 90), Dof(None, -90, 90)])
    b.add("finger_a", "wrist", (0.025, 1.2, 0), (0.025, 1.3, 0), "capsule", (0.013, 0.01), 1.0,
          [Dof(Z, 0, 35)])
    b.add("finger_b", "wrist", (-0.025, 1.2, 0), (-0.025, 1.3, 0), "capsule", (0.013, 0.01), 1.0,
          [Dof(Z, -35, 0)])
    return _build("robot_arm", b.specs, rigid=True)


_MAKERS = {
    "human": _figure_human,
    "upper_body": _figure_upper_body,
    "arm": _figure_arm,
    "hand": _figure_hand,
    "quadruped": _figure_quadruped,
    "snake": _figure_snake,
    "robot_arm": _figure_robot_arm,
}


def make_figure(name: str, seed: int = 0) -> Figure:
    """Build the procedural figure ``name`` (one of :data:`FIGURES`).

    ``seed = 0`` gives the canonical proportions; any other seed varies the overall size
    (+-12 %), each bone's length (+-10 %) and thickness (+-15 %), i.e. another individual.
    Motion is seeded separately in :meth:`Figure.angles`.

    Raises
    ------
    ValueError
        Unknown figure name.
    """
    try:
        maker = _MAKERS[name]
    except KeyError:
        raise ConfigError(f"unknown figure {name!r}; choose one of {', '.join(FIGURES)}") \
            from None
    fig = maker()
    if seed == 0:
        return fig
    return _build(fig.name, _vary(fig.specs, seed), rigid=fig.rigid,
                  facing=tuple(fig.facing))


#: Proportion variation of ``make_figure(name, seed != 0)``: overall size, per-bone length and
#: per-bone thickness factors are drawn uniformly within +- these fractions.
VARY_SIZE, VARY_LENGTH, VARY_RADIUS = 0.12, 0.10, 0.15


def _vary(specs: list[_BoneSpec], seed: int) -> list[_BoneSpec]:
    """Copies of ``specs`` with seeded proportions: each bone's length and radii are scaled,
    children keep their attachment point relative to the (scaled) parent."""
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 5]))
    g = 1 + rng.uniform(-VARY_SIZE, VARY_SIZE)
    ls = 1 + rng.uniform(-VARY_LENGTH, VARY_LENGTH, len(specs))
    rs = 1 + rng.uniform(-VARY_RADIUS, VARY_RADIUS, len(specs))
    out: list[_BoneSpec] = []
    for b, sp in enumerate(specs):
        if sp.parent < 0:
            head = sp.head * g
        else:
            par, new_par = specs[sp.parent], out[sp.parent]
            head = new_par.head + (sp.head - par.head) * g * ls[sp.parent]
        tail = head + (sp.tail - sp.head) * g * ls[b]
        out.append(_BoneSpec(sp.name, sp.parent, head, tail, sp.shape,
                             (sp.radii[0] * g * rs[b], sp.radii[1] * g * rs[b]), sp.ext,
                             list(sp.dofs)))
    return out
