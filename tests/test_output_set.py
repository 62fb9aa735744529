"""The output folder holds one whole set of results or none: an extract killed (SIGKILL) at
several points leaves the previous complete set, or no set declared, never a mix; a failed
write leaves the previous set; a second extract into a folder in use fails at once; the folder
is checked before step 1; temporary files of interrupted runs are removed.

The oracle is the bytes of the previous set (and the SHA-256 of every file the manifest names,
recomputed here with hashlib).
"""

from __future__ import annotations

import errno
import hashlib
import json
import logging
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
from cli_helpers import run_cli as _run

from pointrig.errors import OutputError
from pointrig.io.outdir import FAULT_ENV, MANIFEST, STAGING, OutputDir, read_manifest
from pointrig.synth import NoiseConfig, synthesize


@pytest.fixture(scope="module")
def seq_dir(tmp_path_factory) -> Path:
    """A 4-frame synthetic arm (folder of PLY frames)."""
    root = tmp_path_factory.mktemp("arm")
    seq = synthesize("arm", n_frames=4, seed=1, noise=NoiseConfig.clean())
    return seq.write(root / "arm") / "frames"


@pytest.fixture(scope="module")
def complete(seq_dir, tmp_path_factory) -> Path:
    """A folder holding a complete output set (with pictures)."""
    out = tmp_path_factory.mktemp("complete") / "out"
    code, _, err = _run(["extract", str(seq_dir), "-o", str(out), "-q"])
    assert code == 0, err
    return out


def _visible(folder: Path) -> dict[str, bytes]:
    """The files a user sees in ``folder`` (not the hidden lock and staging folder)."""
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())
            if p.is_file() and not p.name.startswith(".")}


def _check_manifest(folder: Path) -> dict[str, dict]:
    """The manifest's files, each checked against the file's size and SHA-256."""
    files = read_manifest(folder)
    for name, entry in files.items():
        data = (folder / name).read_bytes()
        assert len(data) == entry["bytes"], name
        assert hashlib.sha256(data).hexdigest() == entry["sha256"], name
    return files


def test_a_complete_set_is_named_by_its_manifest(complete):
    files = _check_manifest(complete)
    assert set(files) == set(_visible(complete)) - {MANIFEST}
    assert {"skeleton.json", "weights.npz", "registration.npz", "skeleton.bvh", "skeleton.glb",
            "skeleton.png", "skeleton.gif"} <= set(files)
    assert not (complete / STAGING).exists()


def _killed_run(seq_dir: Path, out: Path, point: str, *extra: str, stop: str | None = "3"
                ) -> subprocess.CompletedProcess:
    env = dict(os.environ, **{FAULT_ENV: point})
    # by default a frame fewer than the complete set: every output differs from it
    cmd = [sys.executable, "-m", "pointrig", "extract", str(seq_dir), "-o", str(out), "-q",
           *(["--stop", stop] if stop else []), *extra]
    return subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=600)


@pytest.mark.parametrize("point,extra", [
    ("registered", ()),                  # after step 1, its checkpoint staged
    ("pictures", ()),                    # between the PNG and the GIF
    ("commit:0", ("--stop-after", "registration")),  # the old manifest gone, nothing moved
    ("commit:3", ()),                    # three files of the new set moved in
])
def test_sigkill_leaves_the_previous_set_or_none(seq_dir, complete, tmp_path, point, extra):
    out = tmp_path / "out"
    shutil.copytree(complete, out)
    before = _visible(out)
    run = _killed_run(seq_dir, out, point, *extra)
    assert run.returncode == -9, run.stderr
    declared = _check_manifest(out)
    if point.startswith("commit:"):
        assert declared == {}, "a set is declared while its files are being moved"
    else:
        assert _visible(out) == before, "the previous set changed"
        assert set(declared) == set(before) - {MANIFEST}
    # the next run removes what the killed one left and writes one whole set
    code, stdout, err = _run(["extract", str(seq_dir), "-o", str(out), "-q", "--stop", "3",
                              "--no-pictures"])
    assert code == 0, err
    files = _check_manifest(out)
    assert set(files) == set(_visible(out)) - {MANIFEST}
    assert "skeleton.gif" not in files and not (out / "skeleton.gif").exists()
    assert not [p.name for p in out.iterdir() if p.name.startswith(".")]
    if point in ("registered", "pictures"):  # the staged step-1 checkpoint was reused
        assert "registration reused" in stdout


def test_a_failed_write_leaves_the_previous_set(seq_dir, complete, tmp_path, monkeypatch):
    out = tmp_path / "out"
    shutil.copytree(complete, out)
    before = _visible(out)

    def full_disk(*args, **kwargs):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr("pointrig.pipeline.write_gltf", full_disk)
    code, _, err = _run(["extract", str(seq_dir), "-o", str(out), "-q", "--stop", "3"])
    assert code == 1 and "Traceback" not in err
    assert err.strip() == (f"pointrig extract: error: {out / STAGING}: cannot write the "
                           f"outputs: {os.strerror(errno.ENOSPC)}")
    assert _visible(out) == before
    _check_manifest(out)


def test_a_second_extract_into_a_folder_in_use_fails_at_once(seq_dir, tmp_path):
    out = tmp_path / "out"
    with OutputDir(out):  # a first run holds the folder
        t0 = time.perf_counter()
        code, _, err = _run(["extract", str(seq_dir), "-o", str(out), "-q"])
        took = time.perf_counter() - t0
    assert code == 1
    assert err.strip() == (f"pointrig extract: error: {out}: another pointrig run is writing "
                           "into this output folder; wait for it or choose another folder")
    assert took < 2.0
    assert not (out / MANIFEST).exists()


def test_a_lock_is_released_by_a_killed_run(seq_dir, tmp_path):
    """The lock is the kernel's (flock): a run killed while holding it does not block the
    next one."""
    out = tmp_path / "out"
    run = _killed_run(seq_dir, out, "registered", "--stop-after", "registration")
    assert run.returncode == -9
    with OutputDir(out):
        pass


def _no_step1(*args, **kwargs):
    raise AssertionError("step 1 ran before the output folder was checked")


def test_output_folder_is_checked_before_step_1(seq_dir, tmp_path, monkeypatch):
    monkeypatch.setattr("pointrig.registration.register_sequence", _no_step1)
    a_file = tmp_path / "taken"
    a_file.write_text("not a folder\n")
    code, _, err = _run(["extract", str(seq_dir), "-o", str(a_file), "-q"])
    assert code == 1
    assert err.strip() == (f"pointrig extract: error: {a_file}: the output path is a file, "
                           "not a folder")
    code, _, err = _run(["extract", str(seq_dir), "-o", str(a_file / "sub"), "-q"])
    assert code == 1 and "is a file, not a folder" in err
    with pytest.raises(OutputError, match="is a file"):
        OutputDir(a_file)

    # a folder that refuses writes (simulated: the tests may run as root, who writes anyway)
    ro = tmp_path / "ro"
    ro.mkdir()
    monkeypatch.setattr("pointrig.io.outdir.os.access", lambda *a: False)
    code, _, err = _run(["extract", str(seq_dir), "-o", str(ro), "-q"])
    assert code == 1
    assert err.strip() == f"pointrig extract: error: {ro}: the output folder is not writable"
    assert list(ro.iterdir()) == []


def test_too_little_free_space_is_refused_before_step_1(seq_dir, tmp_path, monkeypatch):
    monkeypatch.setattr("pointrig.registration.register_sequence", _no_step1)
    real = shutil.disk_usage
    monkeypatch.setattr("pointrig.io.outdir.shutil.disk_usage",
                        lambda p: real(p)._replace(free=200_000))
    out = tmp_path / "out"
    code, _, err = _run(["extract", str(seq_dir), "-o", str(out), "-q"])
    assert code == 1
    assert err.startswith(f"pointrig extract: error: {out}: 0.2 MB free, the outputs need "
                          "about ")
    assert not (out / MANIFEST).exists()


def test_stale_temporary_files_are_removed(seq_dir, complete, tmp_path):
    out = tmp_path / "out"
    shutil.copytree(complete, out)
    (out / ".skeleton.gif.k3j_x9q2.gif").write_bytes(b"GIF89a half")
    (out / ".weights.npz.a1b2c3d4.npz").write_bytes(b"PK half")
    (out / STAGING).mkdir()
    (out / STAGING / "skeleton.json").write_text("{}\n")
    (out / "notes.txt").write_text("the user's own file\n")
    with OutputDir(out):
        assert not (out / ".skeleton.gif.k3j_x9q2.gif").exists()
        assert not (out / ".weights.npz.a1b2c3d4.npz").exists()
        assert not (out / STAGING / "skeleton.json").exists()
    assert (out / "notes.txt").read_text() == "the user's own file\n"
    assert json.loads((out / MANIFEST).read_text())["format"] == "pointrig.outputs/1"


def test_a_step_1_killed_midway_resumes_to_the_same_registration(tmp_path, caplog):
    """Killed right after step 1 saved its frames so far (every 10 frames), the next run
    registers only the rest and writes the registration an uninterrupted run writes."""
    import numpy as np

    from pointrig.registration import RegistrationResult

    seq = synthesize("arm", n_frames=14, seed=5, noise=NoiseConfig())
    frames = seq.write(tmp_path / "arm") / "frames"
    whole, out = tmp_path / "whole", tmp_path / "out"
    code, _, err = _run(["extract", str(frames), "-o", str(whole), "-q", "--stop-after",
                         "registration"])
    assert code == 0, err
    run = _killed_run(frames, out, "step1-saved", "--stop-after", "registration", stop=None)
    assert run.returncode == -9, run.stderr
    assert (out / STAGING / "registration.partial.npz").is_file()
    assert not (out / "registration.npz").exists()
    caplog.set_level(logging.INFO, logger="pointrig.pipeline")
    code, _, err = _run(["extract", str(frames), "-o", str(out), "-q", "--stop",
                         "3", "--stop-after", "registration"])
    assert code == 0, err
    # (another frame range: the partial state's key does not match and is not used)
    assert "resuming step 1" not in caplog.text
    shutil.rmtree(out)
    run = _killed_run(frames, out, "step1-saved", "--stop-after", "registration", stop=None)
    assert run.returncode == -9
    caplog.clear()
    code, _, err = _run(["extract", str(frames), "-o", str(out), "-q", "--stop-after",
                         "registration"])
    assert code == 0, err
    assert re.search(r"resuming step 1 from .* \((1[0-3]) frames registered\)", caplog.text)
    a = RegistrationResult.load(whole / "registration.npz")
    b = RegistrationResult.load(out / "registration.npz")
    for name in ("rest_points", "points", "sigma2", "iterations", "energy", "matched"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert set(_check_manifest(out)) == {"registration.npz"}
    assert not (out / STAGING).exists()
