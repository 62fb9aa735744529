"""report.html: written by extract through the output set, self-contained, and rendered by a
real browser (headless Chromium driven by playwright) with every network request blocked.

Oracles: skeleton.json (the joints' count, names and frame-0 positions the page's joint trace
must hold; the frame count its slider must have), the page's own request log (no request but
the file itself), the screenshot's pixels (not blank) and the absence of plotly (the report
skipped under "auto", an error under "on").
"""

from __future__ import annotations

import io
import json
import os
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from pointrig import PointrigError
from pointrig.cli import main
from pointrig.config import PipelineConfig, RigConfig, apply_overrides
from pointrig.io import write_sequence
from pointrig.io.outdir import read_manifest
from pointrig.pipeline import extract
from pointrig.report import PLOT_ID, subsample_points
from pointrig.synth import Camera, NoiseConfig, synthesize

FRAMES = 6
#: the browsers tried, in order (POINTRIG_CHROMIUM names another)
BROWSERS = ("chromium-headless-shell", "chromium")


def _config(**rig: object) -> PipelineConfig:
    return apply_overrides({
        "registration": {"n_rest_points": 600, "rest_frame": 0, "refine_rounds": 0},
        "structure": {"ensemble_seeds": 1},
        "rig": {"mesh": "off", "usd": "off", **rig}})


@pytest.fixture(scope="module")
def seq():
    s = synthesize("arm", n_frames=FRAMES, seed=2, speed=3.0, camera=Camera.kinect(320),
                   noise=NoiseConfig(seed=2))
    from pointrig.sequence import PointSequence

    return PointSequence(list(s.frames), source="take_a", fmt="ply")


@pytest.fixture(scope="module")
def run(seq, tmp_path_factory) -> Path:
    """``pointrig extract --report on`` with 500 points a frame (the config file's)."""
    root = tmp_path_factory.mktemp("report")
    write_sequence(root / "take_a", seq.frames)
    cfg = root / "fast.toml"
    cfg.write_text("[registration]\nn_rest_points = 600\nrest_frame = 0\nrefine_rounds = 0\n"
                   "[structure]\nensemble_seeds = 1\n"
                   '[rig]\nmesh = "off"\nusd = "off"\nreport = "off"\nreport_points = 500\n')
    out = root / "out"
    assert main(["extract", str(root / "take_a"), "-o", str(out), "--config", str(cfg),
                 "--report", "on", "--no-pictures", "-q"]) == 0
    return out


def _browser() -> str:
    """The headless Chromium executable; fails (not skips) with the reason when missing."""
    given = os.environ.get("POINTRIG_CHROMIUM")
    found = [given] if given else [shutil.which(b) for b in BROWSERS]
    found = [b for b in found if b]
    if not found:
        raise AssertionError(
            "no headless Chromium: none of " + ", ".join(BROWSERS) + " is on PATH; run "
            "`bash scripts/setup.sh` (it installs Debian's chromium-headless-shell, ~290 MB) "
            "or set POINTRIG_CHROMIUM to a Chromium executable")
    return found[0]


def test_report_is_part_of_the_output_set(run):
    doc = json.loads((run / "skeleton.json").read_text())
    page = (run / "report.html").read_text()
    assert doc["params"]["rig"]["report"] == "on"  # --report over the config file's "off"
    assert "report.html" in read_manifest(run)
    assert not (run / ".pointrig-partial").exists()
    # self-contained: plotly's JavaScript inline, no script or style fetched from elsewhere
    # (the browser test below blocks the network and checks that the page renders)
    assert "<script src=" not in page and '<link rel="stylesheet"' not in page
    assert "Plotly.newPlot" in page and len(page) > 1_000_000  # plotly.js itself is inline
    for stage in doc["params"]["timings_s"]:
        assert f"<td>{stage}</td>" in page


def test_subsample_is_even_and_bounded():
    pts = np.arange(3 * 4999, dtype=float).reshape(-1, 3)
    sub = subsample_points(pts, 2000)
    assert len(sub) <= 2000 and sub.dtype == np.float32
    assert np.array_equal(sub, pts[::3].astype(np.float32))
    assert np.array_equal(subsample_points(pts[:10], 2000), pts[:10].astype(np.float32))


def test_report_renders_offline_in_chromium(run):
    from playwright.sync_api import sync_playwright

    exe = _browser()
    doc = json.loads((run / "skeleton.json").read_text())
    names = [j["name"] for j in doc["joints"]]
    want0 = np.array(doc["joint_positions"][0])
    url = (run / "report.html").resolve().as_uri()
    asked: list[str] = []

    def block_network(route) -> None:
        asked.append(route.request.url)
        if route.request.url == url:
            route.continue_()
        else:
            route.abort()

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=exe, headless=True,
                                    args=["--no-sandbox"])
        try:
            page = browser.new_page(viewport={"width": 1000, "height": 820})
            page.route("**/*", block_network)
            page.goto(url)
            page.wait_for_function(
                f"() => {{ const g = document.getElementById('{PLOT_ID}'); "
                "return g && g._fullData && g.querySelector('canvas'); }", timeout=60_000)
            page.wait_for_timeout(500)
            got = page.evaluate(f"""() => {{
                const g = document.getElementById('{PLOT_ID}');
                const j = g._fullData.find(d => d.name === 'joints');
                return {{n: j.x.length, text: Array.from(j.text),
                         xyz: [Array.from(j.x), Array.from(j.y), Array.from(j.z)],
                         traces: g._fullData.map(d => d.name),
                         steps: g.layout.sliders[0].steps.length}};
            }}""")
            png = page.screenshot()
            # Play runs the sequence: the slider moves on
            page.get_by_text("Play", exact=True).click()
            page.wait_for_function(
                f"() => document.getElementById('{PLOT_ID}')._fullLayout.sliders[0].active > 0",
                timeout=30_000)
        finally:
            browser.close()
    assert [u for u in asked if u != url] == []  # nothing but the file itself was asked for
    assert got["traces"] == ["points", "bones", "joints"]
    assert got["n"] == len(names) and got["text"] == names
    assert np.allclose(np.array(got["xyz"]).T, want0, atol=1e-6)  # float32 of the metres
    assert got["steps"] == FRAMES
    img = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=float)
    assert img.std() > 10, "the screenshot is blank"
    # the skeleton's red bones are drawn
    red = (img[..., 0] > 180) & (img[..., 1] < 80) & (img[..., 2] < 80)
    assert red.sum() > 200, red.sum()


def test_auto_skips_the_report_without_plotly(seq, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "plotly", None)  # import fails
    res = extract(seq, _config(report="auto"), tmp_path / "a", stop_after="structure",
                  pictures=False)
    assert "report" not in res.files and not (tmp_path / "a" / "report.html").exists()
    with pytest.raises(PointrigError, match=r"pip install 'pointrig\[report\]'"):
        extract(seq, _config(report="on"), tmp_path / "b", stop_after="structure",
                pictures=False)
    assert not (tmp_path / "b").exists()  # refused before any work


def test_report_off_writes_none(seq, tmp_path):
    res = extract(seq, _config(report="off"), tmp_path / "c", stop_after="structure",
                  pictures=False)
    assert "report" not in res.files and "report.html" not in read_manifest(tmp_path / "c")
    assert RigConfig().report == "auto"
