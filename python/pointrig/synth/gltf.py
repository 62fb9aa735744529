"""Rigged, animated glTF 2.0 / GLB models, read with ``json`` + ``numpy`` only.

Supported: GLB and ``.gltf`` (embedded ``data:`` URIs or external ``.bin`` files), accessors
of every component type (normalized integers included) with byte strides and sparse
substitution, the node hierarchy (``matrix`` or TRS), skins with inverse bind matrices, and
animation channels on translation / rotation / scale with ``STEP``, ``LINEAR`` (quaternion
slerp) and ``CUBICSPLINE`` (Hermite) interpolation. Morph targets are ignored.

Skinning is linear blend skinning (Eq. 13): a vertex ``v`` of a skinned mesh goes to
``sum_j w_j G_j(t) IBM_j v`` where ``G_j(t)`` is joint ``j``'s global node matrix at time ``t``
and ``IBM_j`` its inverse bind matrix (the mesh node's own transform is ignored, as the glTF
specification requires). Ground-truth joints are the skin joints' global positions
``G_j(t)[:3, 3]``; joint parents follow the node hierarchy restricted to the skin's joints.

One armature is often exported as several skinned meshes with a skin each, and machines carry
rigid parts as plain mesh nodes under a joint node. The joints are the union of the skins that
mesh nodes use (the most used skin's first), each vertex taken to that union's bind space; a
mesh node without a skin under a joint node is rigidly bound to its nearest joint ancestor
(its rest-pose placement relative to that joint kept).
"""

from __future__ import annotations

import base64
import json
import stat
import struct
import urllib.parse
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import FormatError, InputError

__all__ = ["GltfModel", "load_gltf", "pose_gltf", "quat_to_matrix", "slerp"]

_COMPONENT = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32,
              5126: np.float32}
_NCOMP = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
#: Samples used to rank animation clips by joint motion when no clip is named.
CLIP_RANK_SAMPLES = 24


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Unit quaternions ``(..., 4)`` in glTF order ``(x, y, z, w)`` -> ``(..., 3, 3)``."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.maximum(np.linalg.norm(q, axis=-1, keepdims=True), 1e-300)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def slerp(q0: np.ndarray, q1: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Spherical linear interpolation of quaternions ``(N, 4)`` by ``u (N,)`` in [0, 1]
    (shortest arc)."""
    q0 = q0 / np.linalg.norm(q0, axis=-1, keepdims=True)
    q1 = q1 / np.linalg.norm(q1, axis=-1, keepdims=True)
    dot = np.sum(q0 * q1, axis=-1)
    q1 = np.where(dot[:, None] < 0, -q1, q1)
    dot = np.abs(dot)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    small = theta < 1e-6
    s = np.sin(theta)
    with np.errstate(invalid="ignore", divide="ignore"):
        a = np.where(small, 1 - u, np.sin((1 - u) * theta) / s)
        b = np.where(small, u, np.sin(u * theta) / s)
    out = a[:, None] * q0 + b[:, None] * q1
    return out / np.linalg.norm(out, axis=-1, keepdims=True)


@dataclass
class _Channel:
    node: int
    path: str
    times: np.ndarray  # (K,)
    values: np.ndarray  # (K, C) or (K, 3, C) for CUBICSPLINE (in-tangent, value, out-tangent)
    interp: str


@dataclass
class GltfModel:
    """A parsed rigged glTF model (internal representation, world metres, ``y`` up)."""

    path: Path
    node_names: list[str]
    node_parent: np.ndarray  # (N,)
    node_trs: list[tuple[np.ndarray, np.ndarray, np.ndarray] | np.ndarray]  # TRS or a matrix
    joints: np.ndarray  # (J,) node index of each skin joint
    inverse_bind: np.ndarray  # (J, 4, 4)
    vertices: np.ndarray  # (V, 3) bind space
    triangles: np.ndarray  # (T, 3)
    weights: np.ndarray  # (V, J)
    animations: list[tuple[str, list[_Channel]]]

    @property
    def joint_names(self) -> list[str]:
        """Names of the skin joints."""
        return [self.node_names[n] for n in self.joints]

    @property
    def joint_parents(self) -> np.ndarray:
        """``(J,)`` parent of each skin joint among the skin joints (``-1``: none)."""
        pos = {int(n): i for i, n in enumerate(self.joints)}
        out = np.full(len(self.joints), -1, dtype=np.int64)
        for i, n in enumerate(self.joints):
            p = int(self.node_parent[n])
            while p >= 0 and p not in pos:
                p = int(self.node_parent[p])
            out[i] = pos.get(p, -1)
        return out

    def clip_names(self) -> list[str]:
        """Animation names (``clip<i>`` when unnamed)."""
        return [a[0] for a in self.animations]

    def clip_duration(self, clip: int) -> float:
        """Duration of animation ``clip`` in seconds (0 if static)."""
        chans = self.animations[clip][1] if self.animations else []
        return max((float(c.times[-1]) for c in chans if len(c.times)), default=0.0)

    def globals_at(self, clip: int | None, times: np.ndarray) -> np.ndarray:
        """Global node matrices ``(F, N, 4, 4)`` at ``times (F,)`` seconds of ``clip``."""
        F = len(times)
        N = len(self.node_names)
        T = np.zeros((F, N, 3))
        Rq = np.zeros((F, N, 4))
        S = np.ones((F, N, 3))
        fixed: dict[int, np.ndarray] = {}
        for n, trs in enumerate(self.node_trs):
            if isinstance(trs, np.ndarray):
                fixed[n] = trs
            else:
                T[:, n], Rq[:, n], S[:, n] = trs
        if clip is not None and self.animations:
            for ch in self.animations[clip][1]:
                if ch.node in fixed or ch.path not in ("translation", "rotation", "scale"):
                    continue
                val = _sample_channel(ch, times)
                if ch.path == "translation":
                    T[:, ch.node] = val
                elif ch.path == "rotation":
                    Rq[:, ch.node] = val
                else:
                    S[:, ch.node] = val
        local = np.zeros((F, N, 4, 4))
        local[..., :3, :3] = quat_to_matrix(Rq) * S[..., None, :]
        local[..., :3, 3] = T
        local[..., 3, 3] = 1.0
        for n, m in fixed.items():
            local[:, n] = m
        G = np.zeros_like(local)
        done = np.zeros(N, dtype=bool)

        def visit(n: int) -> None:
            if done[n]:
                return
            p = int(self.node_parent[n])
            if p >= 0:
                visit(p)
                G[:, n] = G[:, p] @ local[:, n]
            else:
                G[:, n] = local[:, n]
            done[n] = True

        for n in range(N):
            visit(n)
        return G


def _sample_channel(ch: _Channel, times: np.ndarray) -> np.ndarray:
    t = ch.times
    K = len(t)
    vals = ch.values
    cubic = ch.interp == "CUBICSPLINE"
    key = vals[:, 1] if cubic else vals
    if K == 1:
        return np.repeat(key[:1], len(times), axis=0)
    tc = np.clip(times, t[0], t[-1])
    i = np.clip(np.searchsorted(t, tc, side="right") - 1, 0, K - 2)
    dt = t[i + 1] - t[i]
    u = np.where(dt > 0, (tc - t[i]) / np.where(dt > 0, dt, 1), 0.0)
    if ch.interp == "STEP":
        out = np.where((u >= 1)[:, None], key[i + 1], key[i])
    elif cubic:
        u2, u3 = u * u, u * u * u
        p0, p1 = vals[i, 1], vals[i + 1, 1]
        m0, m1 = vals[i, 2] * dt[:, None], vals[i + 1, 0] * dt[:, None]
        out = ((2 * u3 - 3 * u2 + 1)[:, None] * p0 + (u3 - 2 * u2 + u)[:, None] * m0
               + (-2 * u3 + 3 * u2)[:, None] * p1 + (u3 - u2)[:, None] * m1)
    elif ch.path == "rotation":
        out = slerp(key[i], key[i + 1], u)
    else:
        out = (1 - u)[:, None] * key[i] + u[:, None] * key[i + 1]
    if ch.path == "rotation":
        out = out / np.linalg.norm(out, axis=-1, keepdims=True)
    return out


#: Largest glTF/GLB file, and largest buffer, that :func:`load_gltf` reads (bytes).
MAX_GLTF_BYTES = 1 << 30


def _regular_size(p: Path, what: str, model: Path) -> int:
    """The size of regular file ``p`` (bytes); :class:`InputError` naming ``what`` when it is
    not one (a FIFO, a device) or exceeds :data:`MAX_GLTF_BYTES`."""
    try:
        st = p.stat()
    except OSError:
        raise InputError(f"{what} not found", model) from None
    if not stat.S_ISREG(st.st_mode):
        raise InputError(f"{what} is not a regular file", model)
    if st.st_size > MAX_GLTF_BYTES:
        raise InputError(f"{what} holds {st.st_size} bytes, more than the {MAX_GLTF_BYTES} "
                         "read", model)
    return st.st_size


def _external_buffer(model: Path, uri: str, i: int, byte_length: object) -> bytes:
    """The bytes of buffer ``i`` stored in the file ``uri`` (relative, percent-encoded): only
    a regular file inside the model's folder (no absolute path, ``..`` out of it, scheme or
    link to elsewhere), at most :data:`MAX_GLTF_BYTES`, and only the ``byteLength`` the
    buffer declares."""
    rel = urllib.parse.unquote(uri)
    if "://" in uri or uri.startswith("file:") or Path(rel).is_absolute():
        raise InputError(f"glTF buffer {i} uri {uri!r} is not a relative file name; only "
                         "files in the model's folder are read", model)
    folder = model.parent.resolve()
    target = (folder / rel).resolve()
    if not target.is_relative_to(folder):
        raise InputError(f"glTF buffer {i} uri {uri!r} points outside the model's folder; "
                         "only files in it are read", model)
    size = _regular_size(target, f"glTF buffer {i} file {uri!r}", model)
    if not isinstance(byte_length, int) or isinstance(byte_length, bool) or byte_length < 0:
        raise FormatError(f"glTF buffer {i} has no valid byteLength", model)
    if byte_length > size:
        raise FormatError(f"glTF buffer {i} file {uri!r} holds {size} bytes, the buffer "
                          f"declares {byte_length}", model)
    with open(target, "rb") as fh:
        return fh.read(byte_length)


def _read_container(path: Path) -> tuple[dict, list[bytes]]:
    _regular_size(path, "the glTF file", path)
    raw = path.read_bytes()
    if raw[:4] == b"glTF":
        if len(raw) < 20:
            raise FormatError("truncated GLB header", path)
        version, length = struct.unpack_from("<II", raw, 4)
        if version != 2:
            raise FormatError(f"GLB version {version} not supported (need 2)", path)
        pos, doc, bin_chunk = 12, None, None
        while pos + 8 <= min(length, len(raw)):
            clen, ctype = struct.unpack_from("<II", raw, pos)
            data = raw[pos + 8: pos + 8 + clen]
            if len(data) < clen:
                raise FormatError("truncated GLB chunk", path)
            if ctype == 0x4E4F534A:
                doc = json.loads(data.decode("utf-8"))
            elif ctype == 0x004E4942:
                bin_chunk = data
            pos += 8 + clen
        if doc is None:
            raise FormatError("GLB without a JSON chunk", path)
    else:
        try:
            doc = json.loads(raw.decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise FormatError(f"not a glTF/GLB file: {exc}", path) from None
        bin_chunk = None
    buffers = []
    for i, b in enumerate(doc.get("buffers", [])):
        uri = b.get("uri")
        if uri is None:
            if bin_chunk is None:
                raise FormatError(f"buffer {i} has no uri and there is no GLB BIN chunk", path)
            buffers.append(bin_chunk)
        elif uri.startswith("data:"):
            buffers.append(base64.b64decode(uri.split(",", 1)[1]))
        else:
            buffers.append(_external_buffer(path, uri, i, b.get("byteLength")))
    return doc, buffers


def _accessor(doc: dict, buffers: list[bytes], idx: int, path: Path) -> np.ndarray:
    acc = doc["accessors"][idx]
    dtype = np.dtype(_COMPONENT[acc["componentType"]]).newbyteorder("<")
    nc = _NCOMP[acc["type"]]
    count = int(acc["count"])
    if "bufferView" in acc:
        bv = doc["bufferViews"][acc["bufferView"]]
        buf = buffers[bv.get("buffer", 0)]
        start = bv.get("byteOffset", 0) + acc.get("byteOffset", 0)
        elem = dtype.itemsize * nc
        stride = bv.get("byteStride", elem) or elem
        need = start + stride * (count - 1) + elem if count else start
        if need > len(buf):
            raise FormatError(f"accessor {idx} runs past the end of its buffer", path)
        if stride == elem:
            arr = np.frombuffer(buf, dtype=dtype, count=count * nc, offset=start).reshape(count,
                                                                                          nc)
        else:
            arr = np.lib.stride_tricks.as_strided(
                np.frombuffer(buf, dtype=np.uint8, count=need - start, offset=start),
                shape=(count, elem), strides=(stride, 1)).copy().view(dtype).reshape(count, nc)
        arr = arr.copy()
    else:
        arr = np.zeros((count, nc), dtype=dtype)
    if "sparse" in acc:
        sp = acc["sparse"]
        n = int(sp["count"])
        ibv = doc["bufferViews"][sp["indices"]["bufferView"]]
        idt = np.dtype(_COMPONENT[sp["indices"]["componentType"]]).newbyteorder("<")
        ind = np.frombuffer(buffers[ibv.get("buffer", 0)], dtype=idt, count=n,
                            offset=ibv.get("byteOffset", 0) + sp["indices"].get("byteOffset", 0))
        vbv = doc["bufferViews"][sp["values"]["bufferView"]]
        vals = np.frombuffer(buffers[vbv.get("buffer", 0)], dtype=dtype, count=n * nc,
                             offset=vbv.get("byteOffset", 0) + sp["values"].get("byteOffset", 0))
        arr[ind.astype(np.int64)] = vals.reshape(n, nc)
    out = arr.astype(np.float64)
    if acc.get("normalized", False) and dtype.kind in "iu":
        info = np.iinfo(dtype)
        out = np.maximum(out / info.max, -1.0)
    return out


def _node_trs(node: dict):
    if "matrix" in node:
        return np.asarray(node["matrix"], dtype=np.float64).reshape(4, 4).T  # column-major
    return (np.asarray(node.get("translation", [0, 0, 0]), dtype=np.float64),
            np.asarray(node.get("rotation", [0, 0, 0, 1]), dtype=np.float64),
            np.asarray(node.get("scale", [1, 1, 1]), dtype=np.float64))


def load_gltf(path: str | Path) -> GltfModel:
    """Parse a rigged glTF/GLB file.

    Raises
    ------
    InputError
        Missing file, unreadable container, no skinned triangle mesh.
    """
    p = Path(path)
    if not p.exists():
        raise InputError("file not found", p)
    try:
        doc, buffers = _read_container(p)
        return _build_model(p, doc, buffers)
    except InputError:
        raise
    except (KeyError, IndexError, TypeError, ValueError, struct.error) as exc:
        raise FormatError(f"malformed glTF: {exc!r}", p) from None


def _rest_globals(parent: np.ndarray, trs: list) -> np.ndarray:
    """Global node matrices ``(N, 4, 4)`` of the nodes' own (unanimated) transforms."""
    N = len(trs)
    local = np.zeros((N, 4, 4))
    for n, t in enumerate(trs):
        if isinstance(t, np.ndarray):
            local[n] = t
        else:
            local[n, :3, :3] = quat_to_matrix(t[1]) * t[2][None, :]
            local[n, :3, 3] = t[0]
            local[n, 3, 3] = 1.0
    G = np.zeros_like(local)
    done = np.zeros(N, dtype=bool)
    for n0 in range(N):
        chain = []
        n = n0
        while n >= 0 and not done[n]:
            chain.append(n)
            n = int(parent[n])
        for n in reversed(chain):
            p = int(parent[n])
            G[n] = G[p] @ local[n] if p >= 0 else local[n]
            done[n] = True
    return G


def _build_model(p: Path, doc: dict, buffers: list[bytes]) -> GltfModel:
    nodes = doc.get("nodes", [])
    N = len(nodes)
    parent = np.full(N, -1, dtype=np.int64)
    for i, n in enumerate(nodes):
        for c in n.get("children", []):
            parent[c] = i
    names = [n.get("name", f"node{i}") for i, n in enumerate(nodes)]
    skins = doc.get("skins", [])
    mesh_nodes = [i for i, n in enumerate(nodes) if "mesh" in n]
    skinned_nodes = [i for i in mesh_nodes if "skin" in nodes[i]]
    if not skins or not skinned_nodes:
        raise InputError("glTF has no skinned mesh (need a rigged model)", p)
    # the ground-truth joints: the skin used by most mesh nodes, then the joints of the other
    # skins that mesh nodes use (one armature exported as several skinned meshes)
    used = sorted({nodes[i]["skin"] for i in skinned_nodes},
                  key=lambda s: (-sum(nodes[i]["skin"] == s for i in skinned_nodes), s))
    skin_ibm: dict[int, np.ndarray] = {}
    order: list[int] = []
    ibm_of: dict[int, np.ndarray] = {}
    for sid in used:
        sk = skins[sid]
        sj = [int(n) for n in sk["joints"]]
        if "inverseBindMatrices" in sk:
            m = _accessor(doc, buffers, sk["inverseBindMatrices"], p).reshape(len(sj), 4, 4)
            m = np.transpose(m, (0, 2, 1))  # column-major storage
        else:
            m = np.broadcast_to(np.eye(4), (len(sj), 4, 4)).copy()
        skin_ibm[sid] = m
        for k, n in enumerate(sj):
            if n not in ibm_of:
                ibm_of[n] = m[k]
                order.append(n)
    joints = np.asarray(order, dtype=np.int64)
    J = len(joints)
    ibm = np.stack([ibm_of[n] for n in order])
    col = {n: k for k, n in enumerate(order)}
    rest_globals = None
    verts, tris, wts = [], [], []
    nv = 0
    for ni in mesh_nodes:
        sid = nodes[ni].get("skin")
        if sid is None:
            # a rigid part: a mesh node under a joint node moves with its nearest joint
            a = int(parent[ni])
            while a >= 0 and a not in col:
                a = int(parent[a])
            if a < 0:
                continue
            if rest_globals is None:
                rest_globals = _rest_globals(parent, [_node_trs(n) for n in nodes])
            # bind-space position of a vertex v of the node: IBM_a^-1 G_a^-1 G_node v
            to_bind = np.linalg.inv(ibm[col[a]]) @ np.linalg.solve(rest_globals[a],
                                                                    rest_globals[ni])
            jmap = None
        else:
            sj = [int(n) for n in skins[sid]["joints"]]
            jmap = np.array([col[n] for n in sj], dtype=np.int64)
            # a vertex bound by this skin's IBM_s goes to the union's bind space through
            # IBM_u^-1 IBM_s of its dominant joint (the identity when the skins agree)
            fix = np.stack([np.linalg.solve(ibm[col[n]], skin_ibm[sid][k])
                            for k, n in enumerate(sj)])
        mesh = doc["meshes"][nodes[ni]["mesh"]]
        for prim in mesh["primitives"]:
            mode = prim.get("mode", 4)
            if mode not in (4, 5, 6):
                continue
            attr = prim["attributes"]
            if "POSITION" not in attr:
                continue
            pos = _accessor(doc, buffers, attr["POSITION"], p)
            V = len(pos)
            W = np.zeros((V, J))
            if jmap is None:
                W[:, col[a]] = 1.0
                pos = pos @ to_bind[:3, :3].T + to_bind[:3, 3]
            else:
                if "JOINTS_0" not in attr or "WEIGHTS_0" not in attr:
                    continue
                k = 0
                while f"JOINTS_{k}" in attr and f"WEIGHTS_{k}" in attr:
                    jj = _accessor(doc, buffers, attr[f"JOINTS_{k}"], p).astype(np.int64)
                    ww = _accessor(doc, buffers, attr[f"WEIGHTS_{k}"], p)
                    if (jj >= len(jmap)).any() or (jj < 0).any():
                        raise FormatError(f"JOINTS_{k} refers to a joint outside the skin", p)
                    np.add.at(W, (np.repeat(np.arange(V), jj.shape[1]), jmap[jj].reshape(-1)),
                              ww.reshape(-1))
                    k += 1
                s = W.sum(axis=1, keepdims=True)
                W = np.where(s > 0, W / np.where(s > 0, s, 1), 0.0)
                inv_col = np.full(J, -1, dtype=np.int64)
                inv_col[jmap] = np.arange(len(jmap))
                dom = inv_col[np.argmax(W, axis=1)]
                if not np.allclose(fix, np.eye(4), atol=1e-9):
                    f = fix[np.maximum(dom, 0)]
                    pos = np.einsum("vij,vj->vi", f[:, :3, :3], pos) + f[:, :3, 3]
            if "indices" in prim:
                idx = _accessor(doc, buffers, prim["indices"], p).astype(np.int64).reshape(-1)
            else:
                idx = np.arange(V)
            if mode == 4:
                t = idx[: len(idx) // 3 * 3].reshape(-1, 3)
            elif mode == 5:
                t = np.stack([idx[:-2], idx[1:-1], idx[2:]], axis=1)
            else:
                t = np.stack([np.full(len(idx) - 2, idx[0]), idx[1:-1], idx[2:]], axis=1)
            verts.append(pos)
            tris.append(t + nv)
            wts.append(W)
            nv += V
    if not verts:
        raise InputError("glTF skinned mesh has no triangle primitive with POSITION, JOINTS_0 "
                         "and WEIGHTS_0", p)
    vall, tall, wall = np.concatenate(verts), np.concatenate(tris), np.concatenate(wts)
    # drop unweighted vertices (they would collapse to the origin) and triangles using them
    ok_v = wall.sum(axis=1) > 0
    tall = tall[ok_v[tall].all(axis=1)]
    remap = np.cumsum(ok_v) - 1
    vall, wall, tall = vall[ok_v], wall[ok_v], remap[tall]
    if len(tall) == 0:
        raise InputError("glTF skinned mesh has no weighted triangles", p)
    animations = []
    for ai, anim in enumerate(doc.get("animations", [])):
        chans = []
        for ch in anim.get("channels", []):
            tgt = ch.get("target", {})
            if "node" not in tgt:
                continue
            smp = anim["samplers"][ch["sampler"]]
            times = _accessor(doc, buffers, smp["input"], p).reshape(-1)
            vals = _accessor(doc, buffers, smp["output"], p)
            interp = smp.get("interpolation", "LINEAR")
            if tgt["path"] == "weights":
                continue
            if interp == "CUBICSPLINE":
                vals = vals.reshape(len(times), 3, -1)
            else:
                vals = vals.reshape(len(times), -1)
            chans.append(_Channel(int(tgt["node"]), tgt["path"], times, vals, interp))
        animations.append((anim.get("name") or f"clip{ai}", chans))
    return GltfModel(p, names, parent, [_node_trs(n) for n in nodes], joints, ibm, vall, tall,
                     wall, animations)


def _pick_clip(model: GltfModel, clip: str | int | None) -> int | None:
    if not model.animations:
        if clip is not None:
            raise InputError(f"glTF has no animations (asked for clip {clip!r})", model.path)
        return None
    names = model.clip_names()
    if isinstance(clip, str):
        if clip.isdigit():
            clip = int(clip)
        else:
            low = [n.lower() for n in names]
            hits = [i for i, n in enumerate(low) if n == clip.lower()] or \
                [i for i, n in enumerate(low) if clip.lower() in n]
            if not hits:
                raise InputError(f"no animation named {clip!r}; clips: {', '.join(names)}",
                                 model.path)
            return hits[0]
    if isinstance(clip, int):
        if not 0 <= clip < len(names):
            raise InputError(f"animation index {clip} out of range (0..{len(names) - 1})",
                             model.path)
        return clip
    best, best_score = 0, -1.0
    for c in range(len(names)):
        dur = model.clip_duration(c)
        G = model.globals_at(c, np.linspace(0, dur, CLIP_RANK_SAMPLES))
        pos = G[:, model.joints][..., :3, 3]
        score = float(np.mean(np.linalg.norm(pos - pos.mean(axis=0), axis=-1)))
        if score > best_score:
            best, best_score = c, score
    return best


def pose_gltf(path: str | Path, n_frames: int, fps: float = 30.0, speed: float = 1.0,
              walk: float = 0.0, yaw: float = 0.0, clip: str | int | None = None,
              start: float = 0.0, seed: int = 0, surface_points: int = 3000):
    """Pose a rigged glTF over ``n_frames`` (world frame) -> :class:`pointrig.synth.scene.Posed`.

    Frame ``k`` shows time ``start + k * speed / fps`` of the clip, looping.
    """
    from .scene import Posed, _placement

    model = load_gltf(path)
    c = _pick_clip(model, clip)
    dur = model.clip_duration(c) if c is not None else 0.0
    times = start + np.arange(n_frames) * speed / fps
    if dur > 0:
        times = np.where(times > dur, np.mod(times, dur), times)  # loop past the end
    G = model.globals_at(c, times)
    M = G[:, model.joints] @ model.inverse_bind  # (F, J, 4, 4) skinning matrices
    Rp, tp = _placement(n_frames, walk, yaw)
    R = np.einsum("fij,fbjk->fbik", Rp, M[..., :3, :3])
    T = np.einsum("fij,fbj->fbi", Rp, M[..., :3, 3]) + tp[:, None]
    joints = np.einsum("fij,fbj->fbi", Rp, G[:, model.joints][..., :3, 3]) + tp[:, None]
    from ..kinematics import skin

    verts = skin(model.vertices, model.weights, R, T)
    # surface samples, area-uniform on the bind-pose mesh
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 11]))
    tv = model.vertices[model.triangles]
    area = 0.5 * np.linalg.norm(np.cross(tv[:, 1] - tv[:, 0], tv[:, 2] - tv[:, 0]), axis=1)
    tri = rng.choice(len(area), size=surface_points, p=area / area.sum())
    r1, r2 = rng.random(surface_points), rng.random(surface_points)
    s = np.sqrt(r1)
    bary = np.stack([1 - s, s * (1 - r2), s * r2], axis=1)
    info = {"clip": model.clip_names()[c] if c is not None else None,
            "clip_duration": dur, "triangles": int(len(model.triangles))}
    return Posed(Path(path).stem, verts, model.triangles, model.weights, joints,
                 model.joint_names, model.joint_parents, R, T, model.vertices, tri, bary,
                 np.array([0.0, 0.0, 1.0]), info)
