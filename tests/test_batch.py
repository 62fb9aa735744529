"""pointrig batch: one output set per recording, a summary, failures that stop nothing, and
the same results serially, in N processes and on a Dask cluster.

Oracles: the output files of a serial run (bit for bit: skeleton.json joint positions,
weights.npz weights and bone transforms), the synthetic inputs' frame counts, the joints each
skeleton.json lists, and the error a bad frame file gives on its own (pointrig.read_sequence).
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import os
import sys
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import run_cli as _run

from pointrig import PointrigError, read_sequence
from pointrig.batch import THREAD_ENV, _thread_env, run_batch
from pointrig.cli import main
from pointrig.io import write_sequence
from pointrig.io.outdir import MANIFEST, read_manifest
from pointrig.synth import Camera, NoiseConfig, synthesize

#: a small, quick configuration: few rest points, one ensemble seed, no surface
FAST = """
[registration]
n_rest_points = 600
rest_frame = 0
refine_rounds = 0
[structure]
ensemble_seeds = 1
[rig]
mesh = "off"
usd = "off"
"""
FRAMES = 6
GOOD = ("take_a", "take_b")


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> dict:
    """Two short synthetic arm recordings (folders of PLY frames), a recording whose second
    frame file is damaged, and the fast config."""
    root = tmp_path_factory.mktemp("batch-in")
    paths = []
    for name, seed in zip(GOOD, (2, 3)):
        seq = synthesize("arm", n_frames=FRAMES, seed=seed, speed=3.0,
                         camera=Camera.kinect(320), noise=NoiseConfig(seed=seed))
        write_sequence(root / name, seq.frames)
        paths.append(root / name)
    bad = root / "broken"
    write_sequence(bad, synthesize("arm", n_frames=3, seed=4, camera=Camera.kinect(320)).frames)
    (bad / "frame_0001.ply").write_bytes(b"ply\nformat ascii 1.0\nelement vertex 5\nend")
    cfg = root / "fast.toml"
    cfg.write_text(FAST)
    return {"good": paths, "bad": bad, "config": cfg}


def _argv(inputs: dict, out: Path, *extra: str) -> list[str]:
    a, b = inputs["good"]
    return ["batch", str(a), str(inputs["bad"]), str(b), "-o", str(out),
            "--config", str(inputs["config"]), "--no-pictures", "-q", *extra]


@pytest.fixture(scope="module")
def serial(inputs, tmp_path_factory) -> dict:
    """The serial run (in this process), with reports."""
    out = tmp_path_factory.mktemp("serial") / "out"
    code, stdout, stderr = _run(_argv(inputs, out))
    return {"out": out, "code": code, "stdout": stdout, "stderr": stderr}


def _results(folder: Path) -> dict[str, np.ndarray]:
    """The arrays a user reads from one recording's outputs."""
    doc = json.loads((folder / "skeleton.json").read_text())
    arrays = {"joint_positions": np.array(doc["joint_positions"]),
              "parents": np.array([j["parent"] for j in doc["joints"]])}
    with np.load(folder / "weights.npz") as z:
        for key in ("weights", "labels", "rest_points", "bone_rotations", "bone_translations"):
            arrays[key] = z[key]
    return arrays


def _assert_same(run: Path, ref: Path) -> None:
    for name in GOOD:
        got, want = _results(run / name), _results(ref / name)
        assert got.keys() == want.keys()
        for key in want:
            assert got[key].dtype == want[key].dtype, (name, key)
            assert np.array_equal(got[key], want[key]), f"{name}: {key} differs"


def _summary(out: Path) -> dict[str, dict]:
    with open(out / "summary.csv", newline="") as fh:
        return {row["recording"]: row for row in csv.DictReader(fh)}


def test_a_failed_recording_is_recorded_and_the_others_complete(serial, inputs):
    out = serial["out"]
    assert serial["code"] == 1, serial["stderr"]
    # the failure is the error the bad frame file gives on its own
    with pytest.raises(PointrigError) as bad:
        read_sequence(inputs["bad"])
    rows = _summary(out)
    assert list(rows) == ["take_a", "broken", "take_b"]  # the inputs' order
    assert rows["broken"]["failure"] == str(bad.value)
    assert rows["broken"]["frames"] == rows["broken"]["joints"] == ""
    assert not (out / "broken").exists()
    for name in GOOD:
        doc = json.loads((out / name / "skeleton.json").read_text())
        assert rows[name]["failure"] == ""
        assert int(rows[name]["frames"]) == FRAMES == len(doc["joint_positions"])
        assert int(rows[name]["joints"]) == len(doc["joints"]) >= 2
        assert int(rows[name]["warnings"]) == len(doc["source"]["warnings"])
        assert float(rows[name]["time_s"]) > 0
        assert set(read_manifest(out / name)) >= {"skeleton.json", "weights.npz"}
        assert (out / name / MANIFEST).is_file()
    # the printed table and the closing line
    table = serial["stdout"].splitlines()
    assert table[0].split() == ["recording", "frames", "joints", "time", "s", "warnings",
                                "failure"]
    assert any(line.startswith("broken") and str(bad.value) in line for line in table)
    assert "1 of 3 recordings failed (broken)" in serial["stderr"]


def test_the_index_links_each_report(serial):
    out = serial["out"]
    page = (out / "index.html").read_text()
    for name in GOOD:
        assert f'href="{name}/report.html"' in page
        assert "report.html" in read_manifest(out / name)  # staged and committed with the set
    assert 'href="broken/report.html"' not in page and "broken" in page


def test_jobs_2_gives_the_serial_results(serial, inputs, tmp_path):
    out = tmp_path / "jobs"
    code, _, stderr = _run(_argv(inputs, out, "--jobs", "2", "--report", "off"))
    assert code == 1, stderr
    _assert_same(out, serial["out"])
    assert _summary(out)["broken"]["failure"] == _summary(serial["out"])["broken"]["failure"]
    # each recording ran with its thread pools capped: N x threads = cores
    threads = max(1, (os.cpu_count() or 1) // 2)
    for name in GOOD:
        params = json.loads((out / name / "skeleton.json").read_text())["params"]
        assert [params[s]["workers"] for s in ("registration", "structure", "joints")] \
            == [threads] * 3
        assert not (out / name / "report.html").exists()
    env = _thread_env(threads)
    assert all(env[k] == str(threads) for k in THREAD_ENV)


def test_reading_options_apply_to_every_recording_as_for_extract(inputs, tmp_path):
    """``--far``, ``--crop`` and ``--skip-bad-frames`` reach each recording: a depth capture
    (a wall behind an arm) with a damaged frame gives, through batch, the outputs extract
    gives with the same options, bit for bit; without ``--skip-bad-frames`` it fails."""
    from benchmarks.bench_memory import FAR_M, write_depth_sequence

    folder = write_depth_sequence(tmp_path / "capture", 5)
    (folder / "frame_00002.png").write_bytes(b"not a png")
    opts = ["--far", str(FAR_M), "--crop", "40,0,600,480", "--skip-bad-frames",
            "--config", str(inputs["config"]), "--no-pictures", "-q"]
    code, _, stderr = _run(["extract", str(folder), "-o", str(tmp_path / "ref"), *opts])
    assert code == 0, stderr
    code, _, stderr = _run(["batch", str(folder), "-o", str(tmp_path / "out"), *opts,
                            "--report", "off"])
    assert code == 0, stderr
    got, want = _results(tmp_path / "out" / "capture"), _results(tmp_path / "ref")
    for key in want:
        assert np.array_equal(got[key], want[key]), key
    doc = json.loads((tmp_path / "out" / "capture" / "skeleton.json").read_text())
    src = doc["source"]
    assert src["frame_indices"] == [0, 1, 3, 4] and src["frames"] == 4
    assert [(k["frame"], k["file"]) for k in src["skipped_frames"]] == [(2, "frame_00002.png")]
    assert int(_summary(tmp_path / "out")["capture"]["frames"]) == 4
    # every kept point lies nearer than --far
    with np.load(tmp_path / "out" / "capture" / "weights.npz") as z:
        assert z["rest_points"][:, 2].max() < FAR_M
    code, _, _ = _run(["batch", str(folder), "-o", str(tmp_path / "strict"),
                       *[o for o in opts if o != "--skip-bad-frames"]])
    assert code == 1
    assert "frame_00002.png" in _summary(tmp_path / "strict")["capture"]["failure"]


def test_a_dask_cluster_gives_the_serial_results(serial, inputs, tmp_path):
    from distributed import LocalCluster

    out = tmp_path / "dask"
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster:
        code, _, stderr = _run(_argv(inputs, out, "--scheduler", cluster.scheduler_address,
                                     "--report", "off"))
    assert code == 1, stderr
    _assert_same(out, serial["out"])
    rows = _summary(out)
    assert rows["broken"]["failure"] == _summary(serial["out"])["broken"]["failure"]
    assert [rows[n]["failure"] for n in GOOD] == ["", ""]


def test_scheduler_without_the_batch_extra_is_one_line(inputs, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)  # import fails
    with pytest.raises(PointrigError, match=r"pip install 'pointrig\[batch\]'"):
        run_batch(inputs["good"], tmp_path / "x", scheduler="tcp://127.0.0.1:1")
    code, stdout, stderr = _run(_argv(inputs, tmp_path / "y", "--scheduler",
                                      "tcp://127.0.0.1:1"))
    assert code == 1 and stdout == ""
    assert not (tmp_path / "x").exists() and not (tmp_path / "y").exists()
    assert stderr.strip().splitlines() == [
        "pointrig batch: error: pointrig batch --scheduler needs the batch extra (dask "
        "distributed): pip install 'pointrig[batch]'"]


def test_batch_help_describes_usage():
    so = io.StringIO()
    with contextlib.redirect_stdout(so), pytest.raises(SystemExit):
        main(["batch", "--help"])
    text = " ".join(so.getvalue().split())
    for words in ("INPUT [INPUT ...]", "-o OUTPUT", "--jobs N", "--scheduler ADDRESS",
                  "summary.csv", "index.html", "exit code is 1"):
        assert words in text, words


def test_a_worker_process_that_dies_is_a_failed_row(inputs, tmp_path, monkeypatch):
    """A recording whose process is killed (SIGKILL after step 1, as the fault tests stop a
    run) is recorded as failed; the batch still finishes and writes its summary."""
    from pointrig.io.outdir import FAULT_ENV

    monkeypatch.setenv(FAULT_ENV, "registered")
    out = tmp_path / "killed"
    a, _ = inputs["good"]
    code, _, stderr = _run(["batch", str(a), str(inputs["bad"]), "-o", str(out), "--config",
                            str(inputs["config"]), "--no-pictures", "-q", "--jobs", "2"])
    assert code == 1, stderr
    rows = _summary(out)
    assert rows["take_a"]["failure"].startswith("the worker process ended with signal 9")
    assert rows["broken"]["failure"] and "signal" not in rows["broken"]["failure"]
    assert not (out / "take_a" / MANIFEST).exists()


@pytest.mark.parametrize("extra, problem", [
    (["--jobs", "0"], "--jobs must be at least 1, got 0"),
    (["--threads", "-1"], "--threads must be 0 or more, got -1"),
    (["--jobs", "2", "--scheduler", "tcp://127.0.0.1:1"], "--jobs and --scheduler exclude"),
])
def test_bad_batch_options_are_one_line(inputs, tmp_path, extra, problem):
    code, stdout, stderr = _run(["batch", str(inputs["bad"]), "-o", str(tmp_path / "o"),
                                 *extra])
    assert code == 1 and stdout == "" and len(stderr.strip().splitlines()) == 1
    assert stderr.startswith("pointrig batch: error: ") and problem in stderr
    assert not (tmp_path / "o").exists()
