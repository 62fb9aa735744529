"""The command line: info on a sequence, clear one-line errors and exit codes."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from pointrig.cli import main
from pointrig.io import write_sequence


def test_info_prints_summary(tmp_path, rng, capsys):
    frames = [rng.normal(size=(n, 3)) for n in (100, 120, 140)]
    write_sequence(tmp_path / "seq", frames, fmt="ply")
    assert main(["info", str(tmp_path / "seq"), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["frames"] == 3 and out["points_median"] == 120 and out["format"] == "ply"
    lo = np.min([f.min(0) for f in frames], axis=0)
    np.testing.assert_allclose(out["bounds_min"], lo)


def test_bad_input_exits_nonzero_with_one_line(tmp_path, capsys):
    code = main(["info", str(tmp_path / "missing")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1
    assert len(err) == 1 and "missing" in err[0] and "not found" in err[0]


def test_help_and_info_do_not_import_scipy(tmp_path, rng):
    """`pointrig --help` and `info` start fast: they do not import scipy (the pipeline's)."""
    write_sequence(tmp_path / "s", [rng.normal(size=(10, 3))] * 2, fmt="npy")
    code = (
        "import sys; from pointrig.cli import main;"
        f" main(['info', {str(tmp_path / 's')!r}]);"
        " print('scipy' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip().splitlines()[-1] == "False"
    res = subprocess.run([sys.executable, "-m", "pointrig", "--help"], capture_output=True,
                         text=True)
    assert res.returncode == 0 and "info" in res.stdout


def test_bad_config_choice_fails_before_step_1(tmp_path, rng, capsys):
    """A mistyped choice in --config is reported at once (exit 1, one line naming the stage
    and field), before any step runs, and nothing is written."""
    src = tmp_path / "seq"
    write_sequence(src, [rng.normal(size=(300, 3)) for _ in range(3)])
    cfg = tmp_path / "bad.toml"
    cfg.write_text('[joints]\ninit = "xyz"\n')
    out = tmp_path / "out"
    assert main(["extract", str(src), "-o", str(out), "--config", str(cfg)]) == 1
    err = capsys.readouterr().err
    assert "[joints] init must be one of" in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_closed_stdout_pipe_ends_quietly():
    # `pointrig synth --list | head -0`: the reader is gone before the first write; the CLI
    # must end with 128 + SIGPIPE and no traceback (before: BrokenPipeError traceback)
    r, w = os.pipe()
    os.close(r)
    try:
        res = subprocess.run([sys.executable, "-m", "pointrig", "synth", "--list"], stdout=w,
                             stderr=subprocess.PIPE, text=True, timeout=120)
    finally:
        os.close(w)
    assert res.returncode == 141
    assert "Traceback" not in res.stderr and "BrokenPipe" not in res.stderr


@pytest.mark.parametrize("text,what", [(None, "not found"), ("[1, 2]", "JSON object"),
                                       ("{", "not valid JSON")])
def test_bad_bone_names_file_fails_before_step_1(tmp_path, rng, capsys, text, what):
    """--bone-names with a missing or malformed file: exit 1, one line naming the file, before
    any step runs, nothing written."""
    src = tmp_path / "seq"
    write_sequence(src, [rng.normal(size=(300, 3)) for _ in range(3)])
    names = tmp_path / "names.json"
    if text is not None:
        names.write_text(text)
    out = tmp_path / "out"
    assert main(["extract", str(src), "-o", str(out), "--bone-names", str(names)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "names.json" in err[0] and what in err[0]
    assert not out.exists()


@pytest.mark.parametrize("command", ["extract", "batch"])
def test_preset_is_the_base_the_config_file_overrides(tmp_path, command):
    """``--preset`` picks the configuration that ``--config`` then overrides, field by field:
    ``fast`` is the defaults with its three fields changed, ``paper`` is
    ``PipelineConfig.paper()``, and an unknown name is refused by the parser (exit 2)."""
    from pointrig.cli import _config_from_args, build_parser
    from pointrig.config import PipelineConfig

    toml = tmp_path / "over.toml"
    toml.write_text("[joints]\ntrack_iterations = 7\n")

    def config(*extra):
        args = build_parser().parse_args([command, "in", "-o", str(tmp_path / "o"), *extra])
        return _config_from_args(args)

    assert config() == PipelineConfig()
    assert config("--preset", "paper") == PipelineConfig.paper()
    fast = config("--preset", "fast", "--config", str(toml))
    d, f = PipelineConfig().to_dict(), fast.to_dict()
    changed = {(stage, k) for stage in d for k in d[stage] if f[stage][k] != d[stage][k]}
    assert changed == {("registration", "refine_rounds"), ("joints", "estep_max_points"),
                       ("joints", "track_iterations")}
    assert fast.joints.track_iterations == 7  # the file over the preset
    assert fast.registration.refine_rounds == 0 and fast.joints.estep_max_points == 2000
    with pytest.raises(SystemExit) as exc:
        config("--preset", "quick")
    assert exc.value.code == 2
