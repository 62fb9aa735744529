"""Writers for point clouds and sequences (atomic)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .atomic import atomic_path

__all__ = ["write_ply", "write_frame", "write_sequence"]


def write_ply(path: str | Path, points: np.ndarray, colors: np.ndarray | None = None,
              binary: bool = True) -> None:
    """Write points ``(N, 3)`` (metres) and optional colours ``(N, 3)`` uint8 to a PLY file.

    The file is binary little-endian float64 by default (lossless), or ascii.
    """
    pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    n = pts.shape[0]
    props = ["property double x", "property double y", "property double z"]
    if colors is not None:
        colors = np.asarray(colors, dtype=np.uint8).reshape(n, 3)
        props += ["property uchar red", "property uchar green", "property uchar blue"]
    fmt = "binary_little_endian" if binary else "ascii"
    header = "\n".join(["ply", f"format {fmt} 1.0", f"element vertex {n}", *props,
                        "end_header"]) + "\n"
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fh.write(header.encode("ascii"))
        if binary:
            if colors is None:
                fh.write(pts.astype("<f8").tobytes())
            else:
                rec = np.empty(n, dtype=[("p", "<f8", 3), ("c", "u1", 3)])
                rec["p"] = pts
                rec["c"] = colors
                fh.write(rec.tobytes())
        else:
            for i in range(n):
                row = " ".join(repr(float(v)) for v in pts[i])
                if colors is not None:
                    row += " " + " ".join(str(int(c)) for c in colors[i])
                fh.write((row + "\n").encode("ascii"))


def write_frame(path: str | Path, points: np.ndarray) -> None:
    """Write one frame; the format follows the suffix (``.ply``, ``.npy``, ``.xyz``/``.txt``)."""
    p = Path(path)
    suffix = p.suffix.lower()
    pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    if suffix == ".ply":
        write_ply(p, pts)
    elif suffix == ".npy":
        with atomic_path(p) as tmp, open(tmp, "wb") as fh:
            np.save(fh, pts)
    elif suffix in (".xyz", ".txt"):
        with atomic_path(p) as tmp:
            np.savetxt(tmp, pts, fmt="%.9g")
    elif suffix == ".pcd":
        with atomic_path(p) as tmp, open(tmp, "wb") as fh:
            header = (
                "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z\n"
                "SIZE 8 8 8\nTYPE F F F\nCOUNT 1 1 1\n"
                f"WIDTH {len(pts)}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {len(pts)}\n"
                "DATA binary\n"
            )
            fh.write(header.encode("ascii"))
            fh.write(pts.astype("<f8").tobytes())
    else:
        raise ValueError(f"{p}: unsupported frame format {suffix!r} (use .ply, .pcd, .npy, .xyz)")


def write_sequence(directory: str | Path, frames: list[np.ndarray], fmt: str = "ply",
                   prefix: str = "frame_") -> list[Path]:
    """Write frames as ``directory/frame_0000.<fmt>`` ... and return the paths."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    paths = []
    for t, pts in enumerate(frames):
        p = d / f"{prefix}{t:04d}.{fmt}"
        write_frame(p, pts)
        paths.append(p)
    return paths
