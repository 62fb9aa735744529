"""A corpus of bad inputs, generated here, each run through the ``pointrig`` command line: every
case exits with code 1 and one ``pointrig <command>: error: ...`` line naming the file (and the
frame) and the problem, with no traceback, and leaves the output folder as it was.

``python tests/test_bad_input.py`` prints the table of cases, exit codes and messages.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from pointrig.cli import main


def _cloud(seed: int, n: int = 400) -> np.ndarray:
    """A small ``(n, 3)`` cloud, metres, 2 m in front of the camera."""
    rng = np.random.default_rng(seed)
    return rng.normal(scale=0.2, size=(n, 3)) + [0.0, 0.0, 2.0]


def _npy_frames(folder: Path, frames: list[np.ndarray]) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for i, f in enumerate(frames):
        np.save(folder / f"frame_{i:03d}.npy", f)
    return folder


def _ascii_ply(points: np.ndarray, count: int | None = None, vertex_line: str | None = None
               ) -> str:
    n = len(points) if count is None else count
    head = ["ply", "format ascii 1.0", vertex_line or f"element vertex {n}",
            "property float x", "property float y", "property float z", "end_header"]
    return "\n".join(head + [" ".join(f"{v:.5f}" for v in p) for p in points]) + "\n"


def _ply_frames(folder: Path, bad: str, n_frames: int = 3) -> Path:
    """Good PLY frames with frame 1 replaced by the text ``bad``."""
    folder.mkdir(parents=True, exist_ok=True)
    for i in range(n_frames):
        text = bad if i == 1 else _ascii_ply(_cloud(i))
        (folder / f"frame_{i:03d}.ply").write_text(text)
    return folder


def _pcd(points: np.ndarray, size: str) -> str:
    head = ["VERSION .7", "FIELDS x y z", f"SIZE {size}", "TYPE F F F", "COUNT 1 1 1",
            f"WIDTH {len(points)}", "HEIGHT 1", f"POINTS {len(points)}", "DATA ascii"]
    return "\n".join(head + [" ".join(f"{v:.5f}" for v in p) for p in points]) + "\n"


def _pcd_frames(folder: Path, size: str) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for i in range(3):
        (folder / f"frame_{i:03d}.pcd").write_text(_pcd(_cloud(i), "4 4 4" if i != 1 else size))
    return folder


@dataclass
class Case:
    """One bad input: ``build(tmp)`` makes it and returns the command's arguments (the output
    folder is added); ``message`` is a regex the error line must match."""

    name: str
    build: Callable[[Path], list[str]]
    message: str


def _seq(tmp: Path, frames: list[np.ndarray]) -> list[str]:
    return ["extract", str(_npy_frames(tmp / "in", frames))]


def _far_points(tmp: Path, value: float) -> list[str]:
    frames = [_cloud(i) for i in range(3)]
    frames[2][:5] = value
    return _seq(tmp, frames)


CASES = [
    Case("points at 1e18 m", lambda t: _far_points(t, 1e18),
         r"frame_002\.npy: frame 2: 5 point\(s\) farther than 1e\+12 m"),
    Case("points at 1e300 m", lambda t: _far_points(t, 1e300),
         r"frame_002\.npy: frame 2: 5 point\(s\) farther than 1e\+12 m"),
    Case("all points identical",
         lambda t: _seq(t, [_cloud(0), np.full((400, 3), 0.5), _cloud(2)]),
         r"frame_001\.npy: frame 1: the frame's points coincide"),
    Case("--scale 0", lambda t: _seq(t, [_cloud(i) for i in range(3)]) + ["--scale", "0"],
         r"scale must be a positive number .* got 0"),
    Case("--scale -1", lambda t: _seq(t, [_cloud(i) for i in range(3)]) + ["--scale", "-1"],
         r"scale must be a positive number .* got -1"),
]


def _snapshot(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` (relative name -> bytes)."""
    if not folder.exists():
        return {}
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file()}


def run_case(case: Case, tmp: Path) -> tuple[int, str, str, bool]:
    """Run ``case`` into an output folder holding an earlier result; returns the exit code,
    stdout, stderr and whether the output folder is unchanged."""
    out = tmp / "out"
    out.mkdir()
    (out / "skeleton.json").write_text(json.dumps({"earlier": True}) + "\n")
    before = _snapshot(out)
    argv = case.build(tmp)
    argv = argv[:2] + ["-o", str(out), "-q", "--no-pictures"] + argv[2:] \
        if argv[0] == "extract" else argv
    so, se = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(so), contextlib.redirect_stderr(se):
        code = main(argv)
    return code, so.getvalue(), se.getvalue(), _snapshot(out) == before


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_bad_input_is_one_typed_error_line(case: Case, tmp_path: Path) -> None:
    code, _, err, unchanged = run_case(case, tmp_path)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 1, err
    assert len(lines) == 1 and lines[0].startswith("pointrig "), err
    assert "Traceback" not in err
    assert re.search(case.message, lines[0]), lines[0]
    assert unchanged, "the output folder changed"


if __name__ == "__main__":  # the table of the corpus: case | exit code | message
    import tempfile

    print("| case | exit | message |\n|---|---|---|")
    for c in CASES:
        with tempfile.TemporaryDirectory() as d:
            code, _, err, _ = run_case(c, Path(d))
        msg = err.strip().replace(d + os.sep, "").replace("|", "\\|")
        print(f"| {c.name} | {code} | {msg} |")
    sys.exit(0)
