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
from cli_helpers import run_cli

from pointrig.cli import main
from pointrig.errors import InputError


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


def _npz(tmp: Path, data: bytes) -> list[str]:
    (tmp / "seq.npz").write_bytes(data)
    return ["extract", str(tmp / "seq.npz")]


def _good_npz_bytes() -> bytes:
    buf = io.BytesIO()
    np.savez_compressed(buf, **{f"f{i}": _cloud(i) for i in range(3)})
    return buf.getvalue()


def _corrupt_npz(tmp: Path) -> list[str]:
    data = bytearray(_good_npz_bytes())
    mid = len(data) // 2
    data[mid:mid + 64] = bytes(64)  # a zeroed block inside the compressed members
    return _npz(tmp, bytes(data))


def _complex_npy(tmp: Path) -> list[str]:
    frames: list[np.ndarray] = [_cloud(i) for i in range(3)]
    frames[1] = frames[1] + 0.5j
    return _seq(tmp, frames)


def _depth_pngs(tmp: Path, intrinsics: dict) -> list[str]:
    from PIL import Image

    folder = tmp / "in"
    folder.mkdir()
    for i in range(3):
        depth = np.full((48, 64), 2000 + 10 * i, np.uint16)
        Image.fromarray(depth).save(folder / f"depth_{i:03d}.png")
    (folder / "intrinsics.json").write_text(json.dumps(intrinsics))
    return ["extract", str(folder)]


def _odd_entry(tmp: Path, kind: str) -> list[str]:
    folder = _npy_frames(tmp / "in", [_cloud(i) for i in range(4)])
    bad = folder / "frame_002.npy"
    bad.unlink()
    if kind == "dangling":
        bad.symlink_to(folder / "gone.npy")
    elif kind == "fifo":
        os.mkfifo(bad)
    elif kind == "device":
        bad.symlink_to("/dev/null")
    return ["extract", str(folder)]


def _text_npy(tmp: Path) -> list[str]:
    folder = _npy_frames(tmp / "in", [_cloud(i) for i in range(3)])
    (folder / "frame_001.npy").write_text("1 2 3\n")
    return ["extract", str(folder)]


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
    Case("PLY element line without a count",
         lambda t: ["extract", str(_ply_frames(t / "in", _ascii_ply(_cloud(1), vertex_line=
                                                                       "element vertex")))],
         r"frame_001\.ply: frame 1: PLY header line 3 lacks a value: 'element vertex'"),
    Case("PLY property line without a name",
         lambda t: ["extract", str(_ply_frames(t / "in", _ascii_ply(_cloud(1)).replace(
             "property float z", "property float")))],
         r"frame_001\.ply: frame 1: PLY header line 6 lacks a value: 'property float'"),
    Case("PLY negative vertex count",
         lambda t: ["extract", str(_ply_frames(t / "in", _ascii_ply(_cloud(1), count=-5)))],
         r"frame_001\.ply: frame 1: PLY header line 3: negative element count -5"),
    Case("PLY vertex count not a number",
         lambda t: ["extract", str(_ply_frames(t / "in", _ascii_ply(_cloud(1), vertex_line=
                                                                       "element vertex 1e3")))],
         r"frame_001\.ply: frame 1: PLY header line 3: element count '1e3' is not a whole"),
    Case("PCD SIZE 1", lambda t: ["extract", str(_pcd_frames(t / "in", "1 1 1"))],
         r"frame_001\.pcd: frame 1: malformed PCD header: field 'x' of TYPE F has SIZE 1"),
    Case("PCD SIZE 3", lambda t: ["extract", str(_pcd_frames(t / "in", "3 3 3"))],
         r"frame_001\.pcd: frame 1: malformed PCD header: field 'x' of TYPE F has SIZE 3"),
    Case("PCD two sizes for three fields", lambda t: ["extract", str(_pcd_frames(t / "in",
                                                                                "4 4"))],
         r"frame_001\.pcd: frame 1: malformed PCD header: 3 FIELDS but 2 SIZE"),
    Case("corrupt .npz zip", _corrupt_npz, r"seq\.npz: not a readable \.npz file: "),
    Case("text file named .npz", lambda t: _npz(t, b"0.1 0.2 0.3\n0.4 0.5 0.6\n"),
         r"seq\.npz: not a \.npz archive \(a zip of \.npy arrays\)"),
    Case("complex NPY", _complex_npy,
         r"frame_001\.npy: frame 1: array holds complex128 values; coordinates must be real"),
    Case("text file named .npy", _text_npy, r"frame_001\.npy: frame 1: not a \.npy array"),
    Case('intrinsics "fx": true',
         lambda t: _depth_pngs(t, {"fx": True, "fy": 50.0, "cx": 32.0, "cy": 24.0}),
         r"intrinsics\.json: intrinsics values must be numbers: 'fx' is true"),
    Case('intrinsics "fy": "50"',
         lambda t: _depth_pngs(t, {"fx": 50.0, "fy": "50", "cx": 32.0, "cy": 24.0}),
         r"intrinsics\.json: intrinsics values must be numbers: 'fy' is \"50\""),
    Case("dangling symlink among the frames", lambda t: _odd_entry(t, "dangling"),
         r"frame_002\.npy: frame 2: a symbolic link to '.*gone\.npy', which does not exist"),
    Case("FIFO among the frames", lambda t: _odd_entry(t, "fifo"),
         r"frame_002\.npy: frame 2: a FIFO \(named pipe\), not a frame file"),
    Case("device link among the frames", lambda t: _odd_entry(t, "device"),
         r"frame_002\.npy: frame 2: a character device, not a frame file"),
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
    code, stdout, stderr = run_cli(argv)
    return code, stdout, stderr, _snapshot(out) == before


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


def test_a_crop_corner_of_two_numbers_is_a_config_error(tmp_path: Path) -> None:
    from pointrig.errors import ConfigError
    from pointrig.io import read_sequence

    folder = _npy_frames(tmp_path / "in", [_cloud(i) for i in range(3)])
    with pytest.raises(ConfigError, match=r"crop_min must be 3 finite numbers.*\(0, 0\)"):
        read_sequence(folder, crop_min=(0, 0))


def test_a_checkpoint_with_a_nan_is_named_and_recomputed(tmp_path: Path, caplog) -> None:
    """A registration checkpoint whose key matches the input but which holds a NaN: the run
    names the file, runs step 1 again and writes a finite checkpoint."""
    from pointrig.registration import RegistrationResult

    folder = _npy_frames(tmp_path / "in", [_cloud(0, 300) + [0.01 * i, 0, 0] for i in range(3)])
    out = tmp_path / "out"
    argv = ["extract", str(folder), "-o", str(out), "-q", "--stop-after", "registration"]
    so, se = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(so), contextlib.redirect_stderr(se):
        assert main(argv) == 0, se.getvalue()
    ckpt = out / "registration.npz"
    reg = RegistrationResult.load(ckpt)
    reg.points[1, 7, 2] = np.nan
    reg.save(ckpt)
    with pytest.raises(InputError, match=r"registration\.npz: registration checkpoint holds "
                                         r"non-finite or non-float values in 'points'"):
        RegistrationResult.load(ckpt)
    with contextlib.redirect_stdout(so), contextlib.redirect_stderr(se):
        assert main(argv) == 0, se.getvalue()
    assert any(str(ckpt) in r.getMessage() and "step 1 runs again" in r.getMessage()
               for r in caplog.records)
    assert np.isfinite(RegistrationResult.load(ckpt).points).all()


def test_skip_bad_frames_leaves_them_out_and_keeps_the_indices(tmp_path: Path, caplog) -> None:
    """``--skip-bad-frames``: a FIFO among the frames is left out with a warning; the
    skeleton records each used frame's index, and ``evaluate`` scores against exactly those
    ground-truth frames (the oracle: :func:`pointrig.evaluate.evaluate` on the GT frames
    picked by hand)."""
    from pointrig.evaluate import evaluate, evaluate_files, load_prediction
    from pointrig.synth import NoiseConfig, synthesize
    from pointrig.synth.scene import load_gt

    seq = synthesize("arm", n_frames=5, seed=3, noise=NoiseConfig.clean())
    root = seq.write(tmp_path / "arm")
    bad = root / "frames" / "frame_0002.ply"
    bad.unlink()
    os.mkfifo(bad)
    out = tmp_path / "out"
    so, se = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(so), contextlib.redirect_stderr(se):
        assert main(["extract", str(root / "frames"), "-o", str(out), "-q", "--no-pictures",
                     "--stop-after", "structure"]) == 1
        assert "frame_0002.ply: frame 2: a FIFO" in se.getvalue()
        assert main(["extract", str(root / "frames"), "-o", str(out), "-q", "--no-pictures",
                     "--stop-after", "structure", "--skip-bad-frames"]) == 0, se.getvalue()
    assert any("leaving out frame 2" in r.getMessage() for r in caplog.records)
    src = json.loads((out / "skeleton.json").read_text())["source"]
    assert src["frame_indices"] == [0, 1, 3, 4] and src["frames"] == 4
    assert [(s["frame"], s["file"]) for s in src["skipped_frames"]] == [(2, "frame_0002.ply")]
    gt = load_gt(root / "gt.npz")
    pred, names = load_prediction(out)
    ref = evaluate(pred, gt["joints"][[0, 1, 3, 4]], gt["parents"], gt_names=gt["names"],
                   pred_names=names, surface=gt["surface"][[0, 1, 3, 4]],
                   surface_labels=gt.get("surface_labels"), skinned=gt.get("skinned"),
                   bone_rotations=gt["bone_rotations"][[0, 1, 3, 4]],
                   bone_translations=gt["bone_translations"][[0, 1, 3, 4]],
                   rest_surface=gt.get("rest_surface"))
    got = evaluate_files(out, root / "gt.npz")
    assert got.to_dict() == ref.to_dict()
