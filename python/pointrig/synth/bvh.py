"""Motion-capture BVH clips: parse the hierarchy and motion, and dress the skeleton in a capsule
body that the depth renderer rasterises like any skinned mesh.

BVH conventions followed: each ``JOINT`` has an ``OFFSET`` from its parent (in the parent's
frame) and a list of ``CHANNELS``; its local transform is the translation ``OFFSET`` plus any
position channels, then the rotation channels composed in the order they are listed
(``Zrotation Xrotation Yrotation`` gives ``R = R_z R_x R_y``), angles in degrees. ``End Site``
blocks carry an offset only: they are where the last segment of a chain ends, not joints.
The rest pose is every channel at zero. Lengths are taken in the file's units (the clips shipped
with the models are in metres) and ``y`` is up.

The capsule body (:func:`capsule_body`): every segment from a joint to a child joint or end site
becomes a capsule owned by that joint; the trunk (the chain from the root towards the highest
point) is thick, limb capsules get radii proportional to their length, and the top of the trunk
(the head) is a sphere. Vertices near a joint blend into the parent bone as in
:mod:`pointrig.synth.figures`. The ground-truth joints are the BVH joints (end sites excluded);
joints whose segments have no length carry no skin and are not scored, and joints that never
turn against their parent are dropped by the scorer's articulation test.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import FormatError, InputError
from .figures import _BoneSpec, _primitive_mesh, _smoothstep, area_samples, rodrigues

__all__ = ["Bvh", "CapsuleBody", "capsule_body", "load_bvh", "parse_bvh", "pose_bvh"]

_AXES = {"X": np.array([1.0, 0.0, 0.0]), "Y": np.array([0.0, 1.0, 0.0]),
         "Z": np.array([0.0, 0.0, 1.0])}
_CHANNELS = ("Xposition", "Yposition", "Zposition", "Xrotation", "Yrotation", "Zrotation")

#: Capsule body proportions, as fractions of the rest skeleton's height ``H``: the trunk's
#: radius, the head sphere's radius, and the bounds of a limb capsule's radius.
TRUNK_RADIUS = 0.075
HEAD_RADIUS = 0.06
LIMB_RADIUS_MIN, LIMB_RADIUS_MAX = 0.012, 0.045
#: A limb capsule's radius as a fraction of its length (before the bounds).
LIMB_RADIUS_PER_LENGTH = 0.2
#: The trunk stops at a joint named ``head`` or at the first joint whose remaining subtree
#: spans less than this fraction of ``H`` (a head with eye joints); that joint is the head, and the trunk segment into it (the
#: neck) is half as thick as the rest of the trunk.
HEAD_SUBTREE = 0.08


@dataclass
class Bvh:
    """A parsed BVH file.

    Attributes
    ----------
    names
        ``J`` joint names (end sites excluded), parents before children.
    parents
        ``(J,)`` int, ``-1`` for the root.
    offsets
        ``(J, 3)`` offset of each joint from its parent, file units.
    channels
        Per joint, its channel names in file order.
    end_sites
        ``(joint, offset (3,))`` for each ``End Site``.
    motion
        ``(F, C)`` channel values, degrees and file units, in hierarchy order.
    frame_time
        Seconds between frames.
    """

    names: list[str]
    parents: np.ndarray
    offsets: np.ndarray
    channels: list[list[str]]
    end_sites: list[tuple[int, np.ndarray]]
    motion: np.ndarray
    frame_time: float

    @property
    def n_frames(self) -> int:
        """Number of motion frames ``F``."""
        return int(self.motion.shape[0])

    @property
    def fps(self) -> float:
        """Frame rate, Hz."""
        return 1.0 / self.frame_time

    def rest_positions(self) -> tuple[np.ndarray, np.ndarray]:
        """Rest-pose (all channels zero) joint positions ``(J, 3)`` and end-site positions
        ``(E, 3)``."""
        J = len(self.names)
        pos = np.zeros((J, 3))
        for j in range(J):
            p = int(self.parents[j])
            pos[j] = self.offsets[j] + (pos[p] if p >= 0 else 0.0)
        ends = np.array([pos[j] + off for j, off in self.end_sites]).reshape(-1, 3)
        return pos, ends

    def forward(self, frames: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Forward kinematics of motion frames ``frames`` (default all).

        Returns
        -------
        R
            ``(F, J, 3, 3)`` global rotation of each joint's frame.
        P
            ``(F, J, 3)`` global joint positions, file units.
        """
        idx = np.arange(self.n_frames) if frames is None else np.asarray(frames, dtype=np.int64)
        m = self.motion[idx]
        F, J = len(idx), len(self.names)
        R = np.zeros((F, J, 3, 3))
        P = np.zeros((F, J, 3))
        col = 0
        for j in range(J):
            t = np.broadcast_to(self.offsets[j], (F, 3)).copy()
            Rl = np.broadcast_to(np.eye(3), (F, 3, 3)).copy()
            for ch in self.channels[j]:
                v = m[:, col]
                col += 1
                if ch.endswith("position"):
                    t[:, "XYZ".index(ch[0])] += v
                else:
                    Rl = Rl @ rodrigues(_AXES[ch[0]], np.radians(v))
            p = int(self.parents[j])
            if p < 0:
                R[:, j] = Rl
                P[:, j] = t
            else:
                R[:, j] = R[:, p] @ Rl
                P[:, j] = P[:, p] + np.einsum("fij,fj->fi", R[:, p], t)
        return R, P


def parse_bvh(text: str, path: str | Path | None = None) -> Bvh:
    """Parse BVH text (hierarchy and motion).

    Raises
    ------
    FormatError
        Not a BVH file, unknown channel, unbalanced braces, or a motion block whose frame
        count or row width does not match the hierarchy.
    """
    tok = text.split()
    pos = 0

    def take() -> str:
        nonlocal pos
        if pos >= len(tok):
            raise FormatError("unexpected end of BVH file", path)
        pos += 1
        return tok[pos - 1]

    def floats(n: int) -> np.ndarray:
        try:
            return np.array([float(take()) for _ in range(n)])
        except ValueError:
            raise FormatError(f"expected {n} numbers near token {pos}", path) from None

    if take().upper() != "HIERARCHY":
        raise FormatError("not a BVH file (no HIERARCHY)", path)
    names: list[str] = []
    parents: list[int] = []
    offsets: list[np.ndarray] = []
    channels: list[list[str]] = []
    ends: list[tuple[int, np.ndarray]] = []
    stack: list[int] = []  # joint index per open brace, -2 for an end site
    kw = take()
    if kw.upper() != "ROOT":
        raise FormatError(f"expected ROOT, got {kw!r}", path)
    while True:
        if kw.upper() in ("ROOT", "JOINT"):
            name = take()
            if take() != "{":
                raise FormatError(f"expected '{{' after joint {name!r}", path)
            parent = next((s for s in reversed(stack) if s >= 0), -1)
            if kw.upper() == "JOINT" and parent < 0:
                raise FormatError(f"JOINT {name!r} outside the root", path)
            if kw.upper() == "ROOT" and stack:
                raise FormatError("a second ROOT inside the hierarchy", path)
            names.append(name)
            parents.append(parent)
            stack.append(len(names) - 1)
            if take().upper() != "OFFSET":
                raise FormatError(f"joint {name!r} has no OFFSET", path)
            offsets.append(floats(3))
            if take().upper() != "CHANNELS":
                raise FormatError(f"joint {name!r} has no CHANNELS", path)
            try:
                n = int(take())
            except ValueError:
                raise FormatError(f"joint {name!r}: bad channel count", path) from None
            chans = [take() for _ in range(n)]
            bad = [c for c in chans if c not in _CHANNELS]
            if bad:
                raise FormatError(f"joint {name!r}: unknown channel {bad[0]!r}", path)
            channels.append(chans)
        elif kw.upper() == "END":
            if take().upper() != "SITE" or take() != "{" or take().upper() != "OFFSET":
                raise FormatError("malformed End Site block", path)
            if not stack or stack[-1] < 0:
                raise FormatError("End Site outside a joint", path)
            ends.append((stack[-1], floats(3)))
            if take() != "}":
                raise FormatError("End Site block not closed", path)
        elif kw == "}":
            if not stack:
                raise FormatError("unbalanced '}'", path)
            stack.pop()
            if not stack:
                break
        else:
            raise FormatError(f"unexpected token {kw!r} in the hierarchy", path)
        kw = take()
    if take().upper() != "MOTION":
        raise FormatError("no MOTION block after the hierarchy", path)
    try:
        if take().rstrip(":").upper() != "FRAMES":
            raise ValueError
        n_frames = int(take())
        if take().upper() != "FRAME" or take().rstrip(":").upper() != "TIME":
            raise ValueError
        frame_time = float(take())
    except ValueError:
        raise FormatError("malformed MOTION header (need 'Frames: N' and 'Frame Time: dt')",
                          path) from None
    if n_frames < 1 or not frame_time > 0:
        raise FormatError(f"MOTION needs >= 1 frame and a positive frame time, got {n_frames} "
                          f"and {frame_time}", path)
    n_ch = sum(len(c) for c in channels)
    rest = tok[pos:]
    if len(rest) != n_frames * n_ch:
        raise FormatError(f"MOTION holds {len(rest)} values, expected {n_frames} frames x "
                          f"{n_ch} channels", path)
    try:
        motion = np.array(rest, dtype=np.float64).reshape(n_frames, n_ch)
    except ValueError:
        raise FormatError("MOTION holds a non-numeric value", path) from None
    if not np.isfinite(motion).all():
        raise FormatError("MOTION holds NaN/inf", path)
    return Bvh(names, np.array(parents, dtype=np.int64), np.array(offsets).reshape(-1, 3),
               channels, ends, motion, frame_time)


def load_bvh(path: str | Path) -> Bvh:
    """Read and parse a ``.bvh`` file.

    Raises
    ------
    InputError
        Missing or unreadable file; :class:`FormatError` for malformed contents.
    """
    p = Path(path)
    if not p.exists():
        raise InputError("file not found", p)
    try:
        text = p.read_text(encoding="utf-8", errors="strict")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"unreadable BVH file: {exc}", p) from None
    return parse_bvh(text, p)


@dataclass
class CapsuleBody:
    """A skinned capsule mesh over a BVH skeleton's rest pose.

    Attributes
    ----------
    vertices
        ``(V, 3)`` rest-pose vertices, file units.
    triangles
        ``(T, 3)`` int.
    weights
        ``(V, J)`` LBS weights over the BVH joints (rows sum to 1).
    segments
        ``(K, 2, 3)`` head and tail of each capsule, rest pose.
    radii
        ``(K,)`` capsule radius.
    owner
        ``(K,)`` the joint owning each capsule.
    vertex_segment
        ``(V,)`` the capsule each vertex belongs to.
    """

    vertices: np.ndarray
    triangles: np.ndarray
    weights: np.ndarray
    segments: np.ndarray
    radii: np.ndarray
    owner: np.ndarray
    vertex_segment: np.ndarray

    def inside(self, points: np.ndarray, exclude: np.ndarray, margin: float) -> np.ndarray:
        """Whether rest points ``(N, 3)`` lie inside a capsule other than ``exclude (N,)`` by
        more than ``margin``."""
        a, b = self.segments[:, 0], self.segments[:, 1]
        ab = b - a
        L2 = np.maximum((ab * ab).sum(axis=1), 1e-300)
        d = points[:, None, :] - a[None]
        s = np.clip((d * ab[None]).sum(axis=2) / L2, 0.0, 1.0)
        dist = np.linalg.norm(d - s[..., None] * ab[None], axis=2)
        inside = dist < self.radii[None] - margin
        inside[np.arange(len(points)), exclude] = False
        return inside.any(axis=1)


def _subtree_extent(bvh: Bvh, rest: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """``(J,)`` bounding-box diagonal of each joint's subtree (joints and end sites)."""
    J = len(bvh.names)
    pts: list[list[np.ndarray]] = [[rest[j]] for j in range(J)]
    for (j, _), e in zip(bvh.end_sites, ends):
        pts[j].append(e)
    for j in range(J - 1, 0, -1):
        pts[int(bvh.parents[j])].extend(pts[j])
    return np.array([float(np.linalg.norm(np.ptp(np.array(p), axis=0))) for p in pts])


def capsule_body(bvh: Bvh, radius_scale: float = 1.0) -> CapsuleBody:
    """Dress ``bvh``'s rest pose in capsules (module docstring), ``radius_scale`` times the
    default thickness."""
    rest, ends = bvh.rest_positions()
    J = len(bvh.names)
    allp = np.concatenate([rest, ends])
    H = float(np.ptp(allp[:, 1])) or float(np.linalg.norm(np.ptp(allp, axis=0)))
    if not H > 0:
        raise InputError("BVH rest pose has no extent")
    children: list[list[int]] = [[] for _ in range(J)]
    for j in range(1, J):
        children[int(bvh.parents[j])].append(j)
    ext = _subtree_extent(bvh, rest, ends)
    # trunk: from the root towards the highest point; its top joint is the head
    top_of = np.array([max([rest[j, 1]] + [e[1] for (k, _), e in zip(bvh.end_sites, ends)
                                           if k == j]) for j in range(J)])
    for j in range(J - 1, 0, -1):
        p = int(bvh.parents[j])
        top_of[p] = max(top_of[p], top_of[j])
    trunk = [0]
    while children[trunk[-1]]:
        nxt = max(children[trunk[-1]], key=lambda c: top_of[c])
        trunk.append(nxt)
        if bvh.names[nxt].lower() == "head" or ext[nxt] < HEAD_SUBTREE * H:
            break
    head = trunk[-1]
    segs: list[tuple[int, np.ndarray, np.ndarray, float, int]] = []  # owner, a, b, r, child
    for j in range(J):
        tails = [(rest[c], c) for c in children[j]] + \
            [(rest[j] + off, -1) for k, off in bvh.end_sites if k == j]
        if j == head:
            up = np.array([0.0, 1.0, 0.0]) * (HEAD_RADIUS * H)
            segs.append((j, rest[j] + 0.5 * up, rest[j] + 1.5 * up,
                         HEAD_RADIUS * H * radius_scale, -1))
            continue
        for tail, c in tails:
            L = float(np.linalg.norm(tail - rest[j]))
            if L < 1e-9 * H:
                continue
            if j in trunk:
                r = TRUNK_RADIUS * H * (0.5 if c == head else 1.0)
            else:
                r = float(np.clip(LIMB_RADIUS_PER_LENGTH * L, LIMB_RADIUS_MIN * H,
                                  LIMB_RADIUS_MAX * H))
            segs.append((j, rest[j], tail, r * radius_scale, c))
    verts, tris, W, vseg = [], [], [], []
    nv = 0
    spacing = 0.018 * H
    for k, (j, a, b, r, c) in enumerate(segs):
        sp = _BoneSpec(bvh.names[j], -1, a, b, "capsule", (r, r))
        v, t, axial = _primitive_mesh(sp, spacing)
        L = float(np.linalg.norm(b - a))
        w = np.zeros((len(v), J))
        p = int(bvh.parents[j])
        w_par = np.zeros(len(v))
        w_chd = np.zeros(len(v))
        blend = min(0.45 * L, r)
        if p >= 0 and j != head:
            w_par = 0.5 * (1 - _smoothstep(axial / blend))
            w[:, p] += w_par
        if c >= 0 and len(children[j]) == 1:
            w_chd = 0.5 * (1 - _smoothstep((L - axial) / blend))
            w[:, c] += w_chd
        w[:, j] += 1.0 - w_par - w_chd
        verts.append(v)
        tris.append(t + nv)
        W.append(w)
        vseg.append(np.full(len(v), k))
        nv += len(v)
    return CapsuleBody(np.concatenate(verts), np.concatenate(tris).astype(np.int64),
                       np.concatenate(W), np.array([[a, b] for _, a, b, _, _ in segs]),
                       np.array([r for _, _, _, r, _ in segs]),
                       np.array([j for j, *_ in segs], dtype=np.int64),
                       np.concatenate(vseg).astype(np.int64))


def pose_bvh(path: str | Path, n_frames: int, fps: float = 30.0, speed: float = 1.0,
             walk: float = 0.0, yaw: float = 0.0, start: float = 0.0, seed: int = 0,
             surface_points: int = 3000, radius_scale: float = 1.0):
    """Pose a BVH clip's capsule body over ``n_frames`` (world frame) ->
    :class:`pointrig.synth.scene.Posed`.

    Frame ``k`` shows the clip's motion frame nearest to time ``start + k * speed / fps``
    seconds, looping past the end. The body's bone transforms are ``T_frame_rest = (R_j(t),
    P_j(t) - R_j(t) P_j^rest)`` from the BVH's global joint frames.

    Raises
    ------
    InputError
        Missing or malformed file.
    """
    from ..kinematics import skin
    from .scene import Posed, _placement

    bvh = load_bvh(path)
    body = capsule_body(bvh, radius_scale)
    times = start + np.arange(n_frames) * speed / fps
    idx = np.rint(times / bvh.frame_time).astype(np.int64) % bvh.n_frames
    Rg, Pg = bvh.forward(idx)
    rest, _ = bvh.rest_positions()
    Rp, tp = _placement(n_frames, walk, yaw)
    R = np.einsum("fij,fbjk->fbik", Rp, Rg)
    Tl = Pg - np.einsum("fbij,bj->fbi", Rg, rest)
    T = np.einsum("fij,fbj->fbi", Rp, Tl) + tp[:, None]
    joints = np.einsum("fij,fbj->fbi", Rp, Pg) + tp[:, None]
    verts = skin(body.vertices, body.weights, R, T)
    # area-uniform surface samples on the rest body, those buried in another capsule dropped
    tri, bary, pts = area_samples(body.vertices, body.triangles, int(surface_points * 1.6) + 16,
                                  seed)
    seg = body.vertex_segment[body.triangles[tri, 0]]
    H = float(np.ptp(body.vertices[:, 1]))
    keep = np.nonzero(~body.inside(pts, seg, 1e-3 * H))[0][:surface_points]
    info = {"bvh_frames": bvh.n_frames, "bvh_fps": bvh.fps, "triangles": len(body.triangles)}
    return Posed(Path(path).stem, verts, body.triangles, body.weights, joints, list(bvh.names),
                 bvh.parents.copy(), R, T, body.vertices, tri[keep], bary[keep],
                 np.array([0.0, 0.0, 1.0]), info)
