"""Readers for single frames and whole sequences.

Every reader returns ``(N, 3)`` float64 points in metres and raises a subclass of
:class:`pointrig.errors.InputError` naming the file (and frame) and the problem.
"""

from __future__ import annotations

import json
import logging
import re
import stat
import zipfile
import zlib
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ConfigError, EmptyFrameError, FormatError, InputError
from ..jsonfile import read_json
from ..sequence import MAX_COORD, PointSequence, SpilledFrames, check_frame
from .depthcam import Isolation
from .recordings import RECORDING_FORMATS, detect_recording, isolate_points, read_recording

log = logging.getLogger(__name__)

__all__ = ["FRAME_FORMATS", "detect_format", "read_frame", "read_sequence", "natural_key",
           "read_intrinsics", "find_intrinsics", "INTRINSICS_NAMES", "depth_to_points",
           "lzf_decompress"]

#: suffix -> format name for per-frame files
FRAME_FORMATS = {".ply": "ply", ".pcd": "pcd", ".xyz": "xyz", ".txt": "xyz", ".npy": "npy",
                 ".png": "depth-png"}

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
    "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}


def natural_key(name: str) -> list:
    """Sort key that orders ``frame_2`` before ``frame_10``."""
    return [int(tok) if tok.isdigit() else tok.lower() for tok in re.split(r"(\d+)", name)]


def _ply_header_line(toks: list[str], lineno: int,
                     elements: list[tuple[str, int, list[tuple[str, str]]]], path: Path) -> None:
    """Check one ``format``/``element``/``property`` line of a PLY header (its words
    ``toks``) and add an element or property to ``elements``; :class:`FormatError` naming the
    line otherwise."""
    need = {"format": 3, "element": 3, "property": 3}.get(toks[0], 0)
    if toks[0] == "property" and len(toks) > 1 and toks[1] == "list":
        need = 5
    if len(toks) < need:
        raise FormatError(f"PLY header line {lineno} lacks a value: {' '.join(toks)!r}", path)
    if toks[0] == "element":
        try:
            count = int(toks[2])
        except ValueError:
            raise FormatError(f"PLY header line {lineno}: element count {toks[2]!r} is not a "
                              "whole number", path) from None
        if count < 0:
            raise FormatError(f"PLY header line {lineno}: negative element count {count}",
                              path)
        elements.append((toks[1], count, []))
    elif toks[0] == "property":
        if not elements:
            raise FormatError("PLY property before any element", path)
        if toks[1] == "list":
            elements[-1][2].append((toks[-1], "list:" + toks[2] + ":" + toks[3]))
        else:
            if toks[1] not in _PLY_TYPES:
                raise FormatError(f"unknown PLY property type {toks[1]!r}", path)
            elements[-1][2].append((toks[-1], _PLY_TYPES[toks[1]]))


def _read_ply(path: Path) -> np.ndarray:
    with open(path, "rb") as fh:
        first = fh.readline()
        if first.strip() != b"ply":
            raise FormatError("not a PLY file (missing 'ply' magic)", path)
        fmt = None
        elements: list[tuple[str, int, list[tuple[str, str]]]] = []
        lineno = 1
        while True:
            line = fh.readline()
            lineno += 1
            if not line:
                raise FormatError("truncated PLY header (no end_header)", path)
            toks = line.decode("ascii", "replace").split()
            if not toks or toks[0] in ("comment", "obj_info"):
                continue
            if toks[0] == "end_header":
                break
            _ply_header_line(toks, lineno, elements, path)
            if toks[0] == "format":
                fmt = toks[1]
        body = fh.read()
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise FormatError(f"unsupported PLY format {fmt!r}", path)
    vert = [e for e in elements if e[0] == "vertex"]
    if not vert:
        raise FormatError("PLY file has no vertex element", path)
    names = [p[0] for p in vert[0][2]]
    if not {"x", "y", "z"} <= set(names):
        raise FormatError(f"PLY vertex element lacks x/y/z (has {names})", path)
    # vertex must come first among elements we need; elements before it must be fixed-size
    if fmt == "ascii":
        lines = body.decode("ascii", "replace").split("\n")
        skip = 0
        for name, count, _ in elements:
            if name == "vertex":
                break
            skip += count
        n = vert[0][1]
        rows = [ln.split() for ln in lines[skip:skip + n]]
        if len(rows) < n or any(len(r) < len(names) for r in rows):
            raise FormatError(f"truncated PLY body: expected {n} vertices", path)
        try:
            arr = np.array([[float(r[names.index(c)]) for c in "xyz"] for r in rows],
                           dtype=np.float64)
        except ValueError as exc:
            raise FormatError(f"bad number in PLY body: {exc}", path) from None
        return arr.reshape(-1, 3)
    endian = "<" if fmt == "binary_little_endian" else ">"
    offset = 0
    for name, count, props in elements:
        if any(t.startswith("list:") for _, t in props):
            if name == "vertex":
                raise FormatError("list properties in the vertex element are not supported", path)
            if name != "vertex":
                break  # list elements after vertex are not needed
        dtype = np.dtype([(pn, endian + t) for pn, t in props])
        if name == "vertex":
            need = dtype.itemsize * count
            if len(body) - offset < need:
                raise FormatError(
                    f"truncated PLY body: expected {count} vertices ({need} bytes), "
                    f"found {len(body) - offset} bytes", path)
            rec = np.frombuffer(body, dtype=dtype, count=count, offset=offset)
            return np.stack([rec["x"], rec["y"], rec["z"]], axis=1).astype(np.float64)
        offset += dtype.itemsize * count
    raise FormatError("PLY vertex element not readable", path)


def _read_pcd(path: Path) -> np.ndarray:
    raw = path.read_bytes()
    header: dict[str, list[str]] = {}
    pos = 0
    while True:
        end = raw.find(b"\n", pos)
        if end < 0:
            raise FormatError("truncated PCD header (no DATA line)", path)
        line = raw[pos:end].decode("ascii", "replace").strip()
        pos = end + 1
        if not line or line.startswith("#"):
            continue
        toks = line.split()
        header[toks[0].upper()] = toks[1:]
        if toks[0].upper() == "DATA":
            break
    try:
        fields = header["FIELDS"]
        sizes = [int(s) for s in header["SIZE"]]
        types = header["TYPE"]
        counts = [int(c) for c in header.get("COUNT", ["1"] * len(fields))]
        npts = int(header["POINTS"][0])
        data = header["DATA"][0].lower()
    except (KeyError, ValueError, IndexError) as exc:
        raise FormatError(f"malformed PCD header: {exc}", path) from None
    if not {"x", "y", "z"} <= set(fields):
        raise FormatError(f"PCD lacks x/y/z fields (has {fields})", path)
    dtype = _pcd_dtype(fields, sizes, types, counts, npts, path)
    if data == "ascii":
        text = raw[pos:].decode("ascii", "replace").split("\n")
        rows = [r.split() for r in text if r.strip()]
        if len(rows) < npts:
            raise FormatError(f"truncated PCD body: expected {npts} points, found {len(rows)}",
                              path)
        try:
            cols = np.array(rows[:npts], dtype=np.float64)
        except ValueError as exc:
            raise FormatError(f"bad number in PCD body: {exc}", path) from None
        flat_idx = np.cumsum([0] + counts)[:-1]
        return cols[:, [flat_idx[fields.index(c)] for c in "xyz"]].reshape(-1, 3)
    if data == "binary":
        need = dtype.itemsize * npts
        if len(raw) - pos < need:
            raise FormatError(f"truncated PCD body: expected {need} bytes, found {len(raw) - pos}",
                              path)
        rec = np.frombuffer(raw, dtype=dtype, count=npts, offset=pos)
        return np.stack([rec["x"], rec["y"], rec["z"]], axis=1).astype(np.float64)
    if data == "binary_compressed":
        return _read_pcd_compressed(raw, pos, dtype, npts, path)
    raise FormatError(f"unsupported PCD DATA type {data!r}", path)


def _pcd_dtype(fields: list[str], sizes: list[int], types: list[str], counts: list[int],
               npts: int, path: Path) -> np.dtype:
    """The record type of a PCD header's ``FIELDS``, ``SIZE``, ``TYPE``, ``COUNT``, checked:
    one size, type and count per field, ``F`` of 4 or 8 bytes, ``I``/``U`` of 1, 2, 4 or 8,
    counts >= 1 and ``POINTS >= 0``; :class:`FormatError` naming the problem otherwise."""
    if not len(fields) == len(sizes) == len(types) == len(counts):
        raise FormatError(f"malformed PCD header: {len(fields)} FIELDS but {len(sizes)} SIZE, "
                          f"{len(types)} TYPE and {len(counts)} COUNT values", path)
    kinds = {"F": ("f", (4, 8)), "I": ("i", (1, 2, 4, 8)), "U": ("u", (1, 2, 4, 8))}
    parts = []
    for f, s, t, c in zip(fields, sizes, types, counts):
        if t.upper() not in kinds:
            raise FormatError(f"malformed PCD header: field {f!r} has TYPE {t!r} (F, I or U)",
                              path)
        kind, allowed = kinds[t.upper()]
        if s not in allowed:
            raise FormatError(f"malformed PCD header: field {f!r} of TYPE {t} has SIZE {s} "
                              f"(one of {', '.join(map(str, allowed))})", path)
        if c < 1:
            raise FormatError(f"malformed PCD header: field {f!r} has COUNT {c}", path)
        parts.append((f, "<" + kind + str(s), (c,) if c > 1 else ()))
    if npts < 0:
        raise FormatError(f"malformed PCD header: negative POINTS {npts}", path)
    return np.dtype(parts)


def _read_pcd_compressed(raw: bytes, pos: int, dtype: np.dtype, npts: int, path: Path) -> np.ndarray:
    """x, y, z of a ``binary_compressed`` PCD body (as PCL and Open3D write it).

    The body is two little-endian uint32, the compressed and the uncompressed size in bytes,
    then that many bytes of LZF data. Uncompressed, the fields are stored column by column:
    field ``f`` of all ``npts`` points contiguously (``npts * itemsize(f)`` bytes), then the
    next field.

    Returns
    -------
    numpy.ndarray
        ``(npts, 3)`` float64, in the file's units.
    """
    if len(raw) - pos < 8:
        raise FormatError("truncated binary_compressed PCD body (no sizes)", path)
    csize, usize = (int(v) for v in np.frombuffer(raw, dtype="<u4", count=2, offset=pos))
    body = raw[pos + 8:pos + 8 + csize]
    if len(body) < csize:
        raise FormatError(f"truncated binary_compressed PCD body: expected {csize} compressed "
                          f"bytes, found {len(body)}", path)
    need = dtype.itemsize * npts
    if usize < need:
        raise FormatError(f"binary_compressed PCD holds {usize} bytes, {npts} points need "
                          f"{need}", path)
    try:
        flat = lzf_decompress(body, usize)
    except ValueError as exc:
        raise FormatError(f"corrupt binary_compressed PCD data: {exc}", path) from None
    columns = {}
    offset = 0
    for name in dtype.names:
        ftype = dtype.fields[name][0]  # with its COUNT as a sub-array shape
        if name in ("x", "y", "z"):
            col = np.frombuffer(flat, dtype=ftype, count=npts, offset=offset)
            columns[name] = col.reshape(npts, -1)[:, 0]
        offset += ftype.itemsize * npts
    return np.stack([columns["x"], columns["y"], columns["z"]], axis=1).astype(np.float64)


def lzf_decompress(data: bytes, size: int) -> bytes:
    """Decompress LZF data (liblzf's format, as in PCL's ``binary_compressed`` PCD) to exactly
    ``size`` bytes.

    The data is a sequence of chunks, each opened by a control byte ``c``: ``c < 32`` copies
    the next ``c + 1`` bytes (a literal run); otherwise ``c >> 5`` is the match length minus 2
    (7 means a further byte adds to it) and ``(c & 31) << 8`` plus the next byte, plus 1, is
    how far back in the output the match starts; the match may overlap the bytes it makes.

    Raises
    ------
    ValueError
        Data that ends inside a chunk, points before the start of the output, or does not
        decompress to exactly ``size`` bytes.
    """
    out = bytearray()
    i, n = 0, len(data)
    while i < n:
        ctrl = data[i]
        i += 1
        if ctrl < 32:
            run = ctrl + 1
            if i + run > n:
                raise ValueError("a literal run goes past the end of the data")
            out += data[i:i + run]
            i += run
        else:
            length = ctrl >> 5
            if length == 7:
                if i >= n:
                    raise ValueError("the data ends inside a match")
                length += data[i]
                i += 1
            if i >= n:
                raise ValueError("the data ends inside a match")
            back = ((ctrl & 0x1F) << 8) + data[i] + 1
            i += 1
            length += 2
            start = len(out) - back
            if start < 0:
                raise ValueError("a match points before the start of the output")
            if back >= length:
                out += out[start:start + length]
            else:  # overlapping: the last `back` bytes repeat
                reps, rest = divmod(length, back)
                chunk = out[start:]
                out += chunk * reps + chunk[:rest]
        if len(out) > size:
            raise ValueError(f"more than the {size} bytes the header gives")
    if len(out) != size:
        raise ValueError(f"{len(out)} bytes, the header gives {size}")
    return bytes(out)


def _read_xyz(path: Path) -> np.ndarray:
    rows = []
    for lineno, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        toks = s.replace(",", " ").split()
        if len(toks) < 3:
            raise FormatError(f"line {lineno}: expected at least 3 numbers, got {len(toks)}", path)
        try:
            rows.append([float(t) for t in toks[:3]])
        except ValueError:
            raise FormatError(f"line {lineno}: not a number: {s[:60]!r}", path) from None
    return np.array(rows, dtype=np.float64).reshape(-1, 3)


def _check_magic(path: Path, magic: bytes, what: str) -> None:
    """:class:`FormatError` unless the file starts with ``magic``."""
    with open(path, "rb") as fh:
        head = fh.read(len(magic))
    if head != magic:
        raise FormatError(f"not {what} (the file does not start as one)", path)


def _real_coordinates(arr: np.ndarray, path: Path, frame: int | None = None,
                      what: str = "array") -> np.ndarray:
    """``arr`` as float64 when its values are real numbers (integers or floats); complex,
    boolean, text or object values are an :class:`InputError` (a cast would lose or invent
    data)."""
    if arr.dtype.kind not in "iuf":
        raise InputError(f"{what} holds {arr.dtype} values; coordinates must be real numbers "
                         "(integer or float)", path, frame=frame)
    return arr.astype(np.float64)


def _read_npy(path: Path) -> np.ndarray:
    _check_magic(path, b"\x93NUMPY", "a .npy array")
    try:
        arr = np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise FormatError(f"not a readable .npy array: {exc}", path) from None
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise InputError(f"expected an array of shape (N, 3), got {arr.shape}", path)
    return _real_coordinates(arr, path)


#: file names searched for the intrinsics of a depth-PNG folder, in this order, in the folder
#: and then in its parent: ours, then what Open3D's RealSense and Azure Kinect recorders write
#: beside their ``depth/`` folder (``intrinsic.json``) and what its reconstruction system reads
INTRINSICS_NAMES = ("intrinsics.json", "intrinsic.json", "camera_intrinsic.json")


def read_intrinsics(path: str | Path) -> dict[str, float]:
    """Read a pinhole camera intrinsics JSON.

    Two layouts are accepted:

    - pointrig's: ``fx, fy, cx, cy`` (pixels), optional ``depth_scale`` (metres per depth
      unit) and optional ``width, height`` (pixels);
    - Open3D's ``PinholeCameraIntrinsic`` (``o3d.io.write_pinhole_camera_intrinsic``, and the
      ``intrinsic.json`` of its RealSense and Azure Kinect recorders): ``width, height`` and
      ``intrinsic_matrix``, the 3 x 3 matrix ``K`` as 9 numbers in column-major order
      (``[fx, 0, 0, 0, fy, 0, cx, cy, 1]``), optional ``depth_scale``.

    ``depth_scale`` defaults to 0.001 (depth PNGs in millimetres, as both recorders write).

    Returns
    -------
    dict
        ``fx, fy, cx, cy`` (pixels), ``depth_scale`` (metres per unit) and, when the file gives
        the image size, ``width, height`` (pixels), all as floats.

    Raises
    ------
    InputError
        Missing file or key, a malformed matrix, non-positive focal lengths, size or scale.
    FormatError
        Not JSON, or not a JSON object.
    """
    p = Path(path)
    doc = read_json(p, missing="intrinsics file not found", invalid="intrinsics is not valid JSON",
                    error=FormatError)
    if not isinstance(doc, dict):
        raise FormatError("intrinsics must be a JSON object", p)
    if "intrinsic_matrix" in doc and "fx" not in doc:
        out = _open3d_pinhole(doc["intrinsic_matrix"], p)
    else:
        missing = [key for key in ("fx", "fy", "cx", "cy") if key not in doc]
        if missing:
            raise InputError(f"intrinsics lacks {missing[0]!r} (or an Open3D "
                             "'intrinsic_matrix')", p)
        out = {key: doc[key] for key in ("fx", "fy", "cx", "cy")}
    out["depth_scale"] = doc.get("depth_scale", 0.001)
    if ("width" in doc) != ("height" in doc):
        raise InputError("intrinsics give one of width and height; give both or neither", p)
    out.update({key: doc[key] for key in ("width", "height") if key in doc})
    for key, value in out.items():
        # JSON numbers only: true would read as 1 and "525" hides a typing mistake
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise InputError(f"intrinsics values must be numbers: {key!r} is "
                             f"{json.dumps(value)}", p)
    out = {key: float(value) for key, value in out.items()}
    if not all(np.isfinite(v) for v in out.values()):
        raise InputError("intrinsics values must be finite", p)
    if out["fx"] <= 0 or out["fy"] <= 0 or out["depth_scale"] <= 0:
        raise InputError("fx, fy and depth_scale must be positive", p)
    if any(key in out and (out[key] < 1 or out[key] != int(out[key]))
           for key in ("width", "height")):
        raise InputError("width and height must be positive whole numbers of pixels", p)
    return out


def _open3d_pinhole(matrix: object, path: Path) -> dict[str, float]:
    """``fx, fy, cx, cy`` of Open3D's ``intrinsic_matrix``: ``K`` as 9 numbers, column-major."""
    try:
        k = np.asarray(matrix, dtype=np.float64)
    except (TypeError, ValueError):
        k = np.zeros(0)  # ragged or not numbers: the shape test below names the problem
    if k.shape != (9,) or not np.isfinite(k).all():
        raise InputError("intrinsic_matrix must be 9 finite numbers (3 x 3, column-major as "
                         "Open3D writes it)", path)
    K = k.reshape(3, 3).T  # column-major -> K[row, col]
    if abs(K[0, 1]) > 1e-9 or abs(K[1, 0]) > 1e-9 or np.abs(K[2] - (0, 0, 1)).max() > 1e-9:
        raise InputError("intrinsic_matrix is not a pinhole K = [[fx, 0, cx], [0, fy, cy], "
                         "[0, 0, 1]] in column-major order", path)
    return {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2]}


def find_intrinsics(folder: str | Path) -> Path:
    """The intrinsics file of a depth-PNG folder: the first of :data:`INTRINSICS_NAMES` in
    ``folder``, then in its parent (Open3D's recorders put ``intrinsic.json`` beside
    ``depth/``).

    Raises
    ------
    InputError
        None of them exists; the message names every place looked at.
    """
    p = Path(folder)
    for d in (p, p.parent):
        for name in INTRINSICS_NAMES:
            if (d / name).is_file():
                return d / name
    raise InputError(f"depth PNGs need camera intrinsics: none of {', '.join(INTRINSICS_NAMES)} "
                     "in this folder or its parent; pass --intrinsics FILE", p)


def depth_to_points(depth: np.ndarray, intr: dict[str, float]) -> np.ndarray:
    """Back-project a depth image ``(H, W)`` (depth units) to ``(N, 3)`` metres, camera frame.

    Pixels with depth 0 are invalid and skipped. ``x = (u - cx) z / fx``, ``y = (v - cy) z / fy``.
    """
    v, u = np.nonzero(depth > 0)
    z = depth[v, u].astype(np.float64) * intr["depth_scale"]
    x = (u - intr["cx"]) * z / intr["fx"]
    y = (v - intr["cy"]) * z / intr["fy"]
    return np.stack([x, y, z], axis=1)


def _read_depth_png(path: Path, intr: dict[str, float]) -> np.ndarray:
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            depth = np.asarray(im)
    except (UnidentifiedImageError, OSError) as exc:
        raise FormatError(f"not a readable PNG: {exc}", path) from None
    if depth.ndim != 2:
        raise InputError(f"depth PNG must be single-channel, got shape {depth.shape}", path)
    if depth.dtype not in (np.uint16, np.int32, np.uint32, np.int16):
        raise InputError(f"depth PNG must be 16-bit, got {depth.dtype}", path)
    if "width" in intr and "height" in intr \
            and depth.shape != (int(intr["height"]), int(intr["width"])):
        raise InputError(f"depth PNG is {depth.shape[1]} x {depth.shape[0]} pixels but the "
                         f"intrinsics are for {int(intr['width'])} x {int(intr['height'])}", path)
    return depth_to_points(depth, intr)


def read_frame(path: str | Path, intrinsics: dict[str, float] | None = None) -> np.ndarray:
    """Read one frame file to ``(N, 3)`` float64 metres (no finiteness check here)."""
    p = Path(path)
    why = _not_a_frame_file(p)
    if why is not None:
        raise InputError(why, p)
    fmt = FRAME_FORMATS.get(p.suffix.lower())
    if fmt is None:
        raise FormatError(f"unknown frame format {p.suffix!r}; expected one of "
                          f"{sorted(set(FRAME_FORMATS))}", p)
    try:
        if fmt == "ply":
            return _read_ply(p)
        if fmt == "pcd":
            return _read_pcd(p)
        if fmt == "xyz":
            return _read_xyz(p)
        if fmt == "npy":
            return _read_npy(p)
        if intrinsics is None:
            raise InputError("depth PNG needs camera intrinsics (intrinsics.json)", p)
        return _read_depth_png(p, intrinsics)
    except InputError:
        raise
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise FormatError(f"unreadable file: {exc}", p) from None


def _frame_entries(folder: Path) -> list[Path]:
    """The entries of ``folder`` named like frames (a suffix of :data:`FRAME_FORMATS`), folders
    aside: regular files, links to them, and also the entries that cannot be frames (a dangling
    link, a FIFO, a device), which :func:`read_frame` refuses by name, so that they never drop
    out of the sequence unnoticed and shift the frame indices."""
    out = []
    for f in folder.iterdir():
        if f.suffix.lower() not in FRAME_FORMATS:
            continue
        try:
            if stat.S_ISDIR(f.stat().st_mode):
                continue
        except OSError:
            pass  # a dangling link: read_frame names it
        out.append(f)
    return out


def _read_frame_at(path: Path, intrinsics: dict[str, float] | None, frame: int) -> np.ndarray:
    """:func:`read_frame` whose errors also name the frame's index in the sequence."""
    try:
        return read_frame(path, intrinsics)
    except InputError as exc:
        if exc.frame is not None:
            raise
        raise type(exc)(exc.problem, exc.path, frame=frame) from None


def _not_a_frame_file(p: Path) -> str | None:
    """Why ``p`` cannot be read as a frame file (a dangling link, a FIFO, a device...), or
    ``None`` for a regular file (or a link to one)."""
    try:
        mode = p.stat().st_mode
    except FileNotFoundError:
        if p.is_symlink():
            return f"a symbolic link to {str(p.readlink())!r}, which does not exist"
        return "file not found"
    except OSError as exc:
        return f"cannot be examined: {exc.strerror or exc}"
    if stat.S_ISREG(mode):
        return None
    kinds = ((stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISCHR, "a character device"),
             (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"),
             (stat.S_ISDIR, "a folder"))
    kind = next((name for test, name in kinds if test(mode)), "not a regular file")
    return f"{kind}, not a frame file"


def detect_format(path: str | Path) -> str:
    """The sequence format of ``path``: a frame format name, or ``"npz"``.

    Raises
    ------
    InputError
        Missing path, empty folder, or a folder mixing formats.
    """
    p = Path(path)
    if not p.exists():
        raise InputError("path not found", p)
    recording = detect_recording(p)  # by content: pointrig.io.recordings
    if recording is not None:
        return recording
    if p.is_file():
        if p.suffix.lower() == ".npz":
            return "npz"
        raise FormatError("a sequence is a directory of frames or one .npz file", p)
    files = _frame_entries(p)
    kinds = sorted({FRAME_FORMATS[f.suffix.lower()] for f in files})
    if not kinds:
        raise InputError(f"no frame files found (expected {sorted(set(FRAME_FORMATS))})", p)
    if len(kinds) > 1:
        raise FormatError(f"mixed frame formats in one folder: {', '.join(kinds)}", p)
    return kinds[0]


def _read_npz(path: Path) -> tuple[list[np.ndarray], list[str]]:
    _check_magic(path, b"PK", "a .npz archive (a zip of .npy arrays)")
    try:
        with np.load(path, allow_pickle=False) as z:
            keys = list(z.files)
            if not keys:
                raise InputError("npz holds no arrays", path)
            if len(keys) == 1 and z[keys[0]].ndim == 3:
                arr = z[keys[0]]
                if arr.shape[2] != 3:
                    raise InputError(f"expected an array (F, N, 3), got {arr.shape}", path)
                arr = _real_coordinates(arr, path, what=f"array {keys[0]!r}")
                return list(arr), [f"{keys[0]}[{i}]" for i in range(len(arr))]
            keys = sorted(keys, key=natural_key)
            frames = []
            for i, k in enumerate(keys):
                a = z[k]
                if a.ndim != 2 or a.shape[1] != 3:
                    raise InputError(f"array {k!r}: expected shape (N, 3), got {a.shape}", path,
                                     frame=i)
                frames.append(_real_coordinates(a, path, i, f"array {k!r}"))
            return frames, keys
    except InputError:
        raise
    except (ValueError, OSError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
        raise FormatError(f"not a readable .npz file: {exc}", path) from None


def voxel_downsample(points: np.ndarray, voxel: float) -> np.ndarray:
    """Average the points in each cubic voxel of side ``voxel`` metres: ``(N, 3) -> (K, 3)``."""
    if voxel <= 0 or len(points) == 0:
        return points
    keys = np.floor(points / voxel).astype(np.int64)
    _, inv, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    out = np.zeros((len(counts), 3))
    np.add.at(out, inv, points)
    return out / counts[:, None]


def _corner(value: Any, name: str) -> np.ndarray:
    """A crop corner as ``(3,)`` float64 metres, or :class:`ConfigError` naming ``name``."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        arr = np.zeros(0)
    if arr.shape != (3,) or not np.isfinite(arr).all():
        raise ConfigError(f"{name} must be 3 finite numbers (x, y, z metres), got {value!r}")
    return arr


def read_sequence(
    path: str | Path,
    *,
    start: int = 0,
    stop: int | None = None,
    stride: int = 1,
    crop_min: tuple[float, float, float] | np.ndarray | None = None,
    crop_max: tuple[float, float, float] | np.ndarray | None = None,
    voxel_size: float = 0.0,
    intrinsics: str | Path | dict[str, float] | None = None,
    scale: float = 1.0,
    min_points: int = 1,
    min_frames: int = 2,
    topic: str | None = None,
    isolation: Isolation | None = None,
    skip_bad_frames: bool = False,
    spill: str | Path | None = None,
) -> PointSequence:
    """Read a point-cloud sequence.

    Parameters
    ----------
    path
        A directory of per-frame files (PLY, PCD, XYZ/TXT, NPY, or 16-bit depth PNG with an
        intrinsics JSON beside them or in the parent folder, :func:`find_intrinsics`), or one
        ``.npz`` with all frames.
    start, stop, stride
        Frame range, Python slice semantics over the naturally sorted frames.
    crop_min, crop_max
        Axis-aligned crop box, ``(3,)`` metres (after ``scale``); points outside are dropped.
    voxel_size
        Voxel downsampling size in metres (0 = off).
    intrinsics
        For depth PNGs: a path to the intrinsics JSON (either layout of
        :func:`read_intrinsics`) or the dict; default :func:`find_intrinsics` of ``path``.
    scale
        Multiplier that converts the file's units to metres (e.g. 0.001 for millimetres).
    min_points
        Frames with fewer points (after crop/downsampling) raise :class:`EmptyFrameError`.
    min_frames
        Fewer frames raise :class:`InputError` (the method needs motion).
    topic
        For ROS bags, the topic read (:func:`pointrig.io.recordings.read_recording`).
    isolation
        Depth range (``z``, metres) and pixel box of depth images kept
        (:class:`pointrig.io.depthcam.Isolation`).
    skip_bad_frames
        A frame file that cannot be read (of a folder) is left out with a warning instead of
        an error; ``meta["frame_indices"]`` then gives each frame read its index among the
        folder's frames (naturally sorted, before ``start``/``stride``), and
        ``meta["skipped_frames"]`` each one left out: ``{"frame", "file", "problem"}``.
    spill
        A folder where the frames are kept on disk (:class:`pointrig.sequence.SpilledFrames`,
        read back on demand, bit for bit) instead of in memory; ``None``: in memory.

    Each frame is reduced (scaled, checked, isolated, cropped, downsampled) as soon as it is
    read, and only what is left is kept: frames of a folder are never all in memory as read
    (a recording or an ``.npz`` is read whole first).

    Returns
    -------
    PointSequence
        ``F`` frames of ``(N_t, 3)`` float64 points in metres.
    """
    p = Path(path)
    if not (np.isfinite(scale) and scale > 0):
        raise ConfigError(f"scale must be a positive number (units to metres), got {scale:g}")
    lo = None if crop_min is None else _corner(crop_min, "crop_min")
    hi = None if crop_max is None else _corner(crop_max, "crop_max")
    fmt = detect_format(p)
    meta: dict[str, Any] = {}  # PointSequence.meta: what the reader used
    if stride < 1:
        raise InputError(f"stride must be >= 1, got {stride}", p)
    if topic is not None and fmt not in RECORDING_FORMATS:
        raise ConfigError(f"--topic is for ROS bags; {p} is a {fmt} input")
    out: list[np.ndarray] | SpilledFrames = [] if spill is None else SpilledFrames(spill)

    def keep(pts: np.ndarray, i: int, name: str) -> None:
        """Frame ``i`` (file ``name``) as read: scaled, checked, isolated, cropped and
        downsampled, then added to ``out``; what was read is not kept."""
        with np.errstate(over="ignore", invalid="ignore"):  # overflow is refused just below
            pts = np.asarray(pts, dtype=np.float64) * scale
        where = p / name if p.is_dir() else p
        bad = ~np.isfinite(pts).all(axis=1)
        if bad.any():
            raise InputError(f"{int(bad.sum())} point(s) with NaN/inf coordinates "
                             f"(first at row {int(np.argmax(bad))})", where, frame=i)
        far = np.abs(pts).max(axis=1, initial=0.0) > MAX_COORD
        if far.any():
            raise InputError(f"{int(far.sum())} point(s) farther than {MAX_COORD:g} m from the "
                             f"origin (first at row {int(np.argmax(far))}); pointrig works in "
                             "metres", where, frame=i)
        if isolation is not None and isolation.active and fmt not in RECORDING_FORMATS:
            pts = isolate_points(pts, fmt, meta, isolation, p)
        if lo is not None:
            pts = pts[(pts >= lo).all(axis=1)]
        if hi is not None:
            pts = pts[(pts <= hi).all(axis=1)]
        pts = voxel_downsample(pts, voxel_size)
        if len(pts) < max(min_points, 1):
            raise EmptyFrameError(
                f"{len(pts)} point(s) after crop/downsampling; at least {max(min_points, 1)} "
                "needed", where, frame=i)
        out.append(check_frame(pts, str(p), len(out)))

    def enough(n: int) -> None:
        if n < min_frames:
            raise InputError(f"sequence has {n} frame(s) after frame selection; "
                             f"at least {min_frames} are needed", p)

    if fmt in RECORDING_FORMATS or fmt == "npz":
        if fmt in RECORDING_FORMATS:
            rec = read_recording(p, fmt, start=start, stop=stop, stride=stride, topic=topic,
                                 isolation=isolation, intrinsics=None if intrinsics is None else
                                 (intrinsics if isinstance(intrinsics, dict)
                                  else read_intrinsics(intrinsics)))
            frames, names, meta = rec.frames, rec.names, rec.meta
        else:
            frames, names = _read_npz(p)
            idx = list(range(len(frames)))[start:stop:stride]
            frames = [frames[i] for i in idx]
            names = [names[i] for i in idx]
        if isolation is not None and isolation.active:
            meta["isolation"] = isolation.to_dict()
        enough(len(frames))
        for i, name in enumerate(names):
            keep(frames[i], i, name)
            frames[i] = None  # the frame as read is not needed any more
        return PointSequence(out, str(p), names, fmt, meta)
    # a folder of frame files: each read, reduced and kept (or spilled) before the next one,
    # so that the frames as read are never all in memory
    files = sorted((f for f in _frame_entries(p) if FRAME_FORMATS[f.suffix.lower()] == fmt),
                   key=lambda f: natural_key(f.name))
    positions = list(range(len(files)))[start:stop:stride]
    files = files[start:stop:stride]
    intr = None
    if fmt == "depth-png":
        if isinstance(intrinsics, dict):
            intr, intr_path = intrinsics, None
        else:
            intr_path = Path(intrinsics) if intrinsics is not None else find_intrinsics(p)
            intr = read_intrinsics(intr_path)
        meta["intrinsics"] = {"path": None if intr_path is None else str(intr_path),
                              **{k: float(v) for k, v in intr.items()}}
    if not skip_bad_frames:
        enough(len(files))
    names, kept, skipped = [], [], []
    for i, (f, pos) in enumerate(zip(files, positions)):
        try:
            pts = _read_frame_at(f, intr, i)
        except InputError as exc:
            if not skip_bad_frames:
                raise
            log.warning("leaving out frame %d: %s", pos, exc)
            skipped.append({"frame": pos, "file": f.name, "problem": exc.problem})
            continue
        keep(pts, len(names), f.name)
        names.append(f.name)
        kept.append(pos)
    if skip_bad_frames:
        meta.update(frame_indices=kept, skipped_frames=skipped)
        enough(len(names))
    if isolation is not None and isolation.active:
        meta["isolation"] = isolation.to_dict()
    return PointSequence(out, str(p), names, fmt, meta)
