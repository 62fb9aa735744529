"""``report.html``: one page to look at a run, readable offline.

The page holds an interactive 3D view (plotly, its JavaScript embedded inline so that the file
opens without a network) of the observed points and the skeleton (joints and bones) that plays
the sequence (play/pause buttons and a frame slider) and can be rotated and zoomed, the seconds
of each stage (``skeleton.json`` ``params.timings_s``) and the run's warnings
(``source.warnings``). Each frame shows at most ``max_points`` of its points (an even,
deterministic subsample) so that the file stays a few MB.

Coordinates are the camera's (metres, x right, y down, z forward); the view starts from behind
the camera with y down, as the camera saw the subject. The axes span every point shown and every joint of the sequence,
fixed while it plays.

:func:`write_index` writes ``index.html`` of ``pointrig batch``: the summary table with a link
to each recording's report.

Needs the ``report`` extra (``pip install 'pointrig[report]'``: plotly).
"""

from __future__ import annotations

import base64
import html
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .io.atomic import atomic_path
from .skeleton import Skeleton

__all__ = ["PLOT_ID", "report_available", "subsample_points", "write_index", "write_report"]

_EXTRA = "report.html needs the report extra: pip install 'pointrig[report]'"

#: the id of the plotly graph's ``<div>`` in ``report.html``
PLOT_ID = "pointrig-view"

_STYLE = """
body { font-family: system-ui, sans-serif; margin: 1.5em; color: #222; }
table { border-collapse: collapse; margin: 0.5em 0 1.5em; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.7em; text-align: left; }
th { white-space: nowrap; }
td.num { text-align: right; font-variant-numeric: tabular-nums; }
.warn { color: #9a4b00; }
.fail { color: #b00020; }
"""


def report_available(mode: str) -> bool:
    """Whether plotly (the ``report`` extra) is importable; ``mode`` is ``[rig] report``:
    ``"off"`` answers ``False``, ``"on"`` makes its absence a
    :class:`~pointrig.errors.PointrigError`, ``"auto"`` answers ``False`` with a log note."""
    from .rig import extra_available

    return extra_available(mode, ("plotly",), _EXTRA, "report.html not written")


def subsample_points(points: np.ndarray, max_points: int) -> np.ndarray:
    """At most ``max_points`` of ``points (N, 3)``: every ``ceil(N / max_points)``-th one, in
    order (the same rows whatever the run), as ``(n, 3)`` float32 metres."""
    pts = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    step = max(1, -(-len(pts) // max(max_points, 1)))
    return pts[::step]


def _bone_lines(joints: np.ndarray, parents: np.ndarray) -> tuple[np.ndarray, ...]:
    """x, y, z of the polyline joining each joint ``(J, 3)`` to its parent, segments separated
    by NaN (plotly's gap)."""
    kids = np.flatnonzero(parents >= 0)
    seg = np.full((len(kids), 3, 3), np.nan, dtype=np.float32)
    seg[:, 0] = joints[parents[kids]]
    seg[:, 1] = joints[kids]
    seg = seg.reshape(-1, 3)
    return seg[:, 0], seg[:, 1], seg[:, 2]


def _typed(values: np.ndarray) -> dict[str, str]:
    """``values (n,)`` as a plotly.js typed array (little-endian float32, base64), the form
    plotly's own graph objects write: a quarter of the size of JSON numbers."""
    data = np.ascontiguousarray(values, dtype="<f4")
    return {"dtype": "f4", "bdata": base64.b64encode(data.tobytes()).decode("ascii")}


def _frame_traces(points: np.ndarray, joints: np.ndarray, parents: np.ndarray,
                  names: Sequence[str]) -> list[dict[str, Any]]:
    """The three traces of a frame (points, bones, joints) as plotly trace dicts."""
    bx, by, bz = _bone_lines(joints, parents)
    return [
        {"type": "scatter3d", "x": _typed(points[:, 0]), "y": _typed(points[:, 1]),
         "z": _typed(points[:, 2]),
         "mode": "markers", "name": "points", "hoverinfo": "skip",
         "marker": {"size": 1.5, "color": "#7f9fbf", "opacity": 0.6}},
        {"type": "scatter3d", "x": _typed(bx), "y": _typed(by), "z": _typed(bz),
         "mode": "lines", "name": "bones",
         "line": {"width": 6, "color": "#d62728"}, "hoverinfo": "skip"},
        {"type": "scatter3d", "x": _typed(joints[:, 0]), "y": _typed(joints[:, 1]),
         "z": _typed(joints[:, 2]),
         "mode": "markers", "name": "joints", "text": list(names), "hoverinfo": "text",
         "marker": {"size": 4, "color": "#111111"}},
    ]


def _figure(skel: Skeleton, frames: Sequence[np.ndarray], max_points: int) -> dict[str, Any]:
    """The plotly figure as a dict (plain data: building graph objects, which validate every
    property of every frame's traces, took most of the page's time): frame 0's traces, one
    plotly frame per sequence frame, play/pause buttons and a slider; the axes fixed to the
    whole sequence's extent."""
    joints = np.asarray(skel.joint_positions, dtype=np.float32)
    F = min(len(frames), len(joints))
    pts = [subsample_points(frames[t], max_points) for t in range(F)]
    # the axes: every point shown and every joint, over the whole sequence
    allp = np.concatenate(pts + [joints[:F].reshape(-1, 3)])
    allp = allp[np.isfinite(allp).all(axis=1)]
    if not len(allp):
        allp = np.array([[-1.0] * 3, [1.0] * 3], dtype=np.float32)
    lo, hi = allp.min(axis=0), allp.max(axis=0)
    pad = 0.05 * float(np.max(hi - lo)) + 1e-3
    names = list(skel.joint_names)
    traces = [_frame_traces(pts[t], joints[t], skel.parents, names) for t in range(F)]
    fps = float(skel.fps or 30.0)
    ms = int(round(1000.0 / fps))
    anim = {"frame": {"duration": ms, "redraw": True}, "transition": {"duration": 0},
            "fromcurrent": True, "mode": "immediate"}
    axis = {i: {"range": [float(lo[k] - pad), float(hi[k] + pad)], "title": {"text": f"{i} (m)"}}
            for k, i in enumerate("xyz")}
    layout = dict(
        height=720, margin={"l": 0, "r": 0, "t": 10, "b": 0},
        uirevision="keep",
        scene={"xaxis": axis["x"], "yaxis": axis["y"], "zaxis": axis["z"],
               "aspectmode": "data",
               "camera": {"up": {"x": 0, "y": -1, "z": 0}, "eye": {"x": 0.3, "y": -0.4,
                                                                   "z": -1.6}}},
        updatemenus=[{"type": "buttons", "direction": "left", "x": 0.0, "y": 0.0,
                      "xanchor": "left", "yanchor": "top", "pad": {"t": 40},
                      "buttons": [
                          {"label": "Play", "method": "animate", "args": [None, anim]},
                          {"label": "Pause", "method": "animate",
                           "args": [[None], {"frame": {"duration": 0, "redraw": False},
                                             "mode": "immediate"}]}]}],
        sliders=[{"active": 0, "x": 0.16, "len": 0.84, "y": 0.0, "pad": {"t": 30},
                  "currentvalue": {"prefix": "frame "},
                  "steps": [{"label": str(t), "method": "animate",
                             "args": [[str(t)], {"frame": {"duration": 0, "redraw": True},
                                                 "mode": "immediate",
                                                 "transition": {"duration": 0}}]}
                            for t in range(F)]}])
    return {"data": traces[0] if F else [], "layout": layout,
            "frames": [{"data": traces[t], "name": str(t), "traces": [0, 1, 2]}
                       for t in range(F)]}


def _table(header: Sequence[str], rows: Sequence[Sequence[Any]], num: Sequence[bool]) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = []
    for row in rows:
        cells = "".join(
            f'<td class="num">{c}</td>' if n else f"<td>{c}</td>" for c, n in zip(row, num))
        body.append(f"<tr>{cells}</tr>")
    return f"<table><tr>{head}</tr>{''.join(body)}</table>"


def write_report(path: str | Path, skel: Skeleton, frames: Sequence[np.ndarray],
                 timings: Mapping[str, float], warnings: Sequence[str], *, title: str,
                 max_points: int = 2000) -> Path:
    """Write the self-contained ``report.html`` of a run, atomically.

    Parameters
    ----------
    path
        The HTML file to write.
    skel
        The skeleton: ``joint_positions (F, J, 3)`` metres in the camera frame, parents,
        joint names, ``fps``.
    frames
        The ``F`` observed clouds ``(N_t, 3)``, metres, camera frame; each is shown
        subsampled to at most ``max_points`` points (:func:`subsample_points`).
    timings
        Seconds per stage (``skeleton.json`` ``params.timings_s``).
    warnings
        The run's warnings, one line each (``source.warnings``).
    title
        The page's title (the input's name).
    max_points
        Points shown per frame.

    Returns
    -------
    Path
        ``path``.
    """
    import plotly.io as pio

    fig = _figure(skel, frames, max_points)
    # the figure's properties are fixed here and checked by tests/test_report.py in a browser
    plot = pio.to_html(fig, full_html=False, include_plotlyjs=True, div_id=PLOT_ID,
                       auto_play=False, config={"displaylogo": False}, validate=False)
    total = sum(timings.values())
    times = _table(["stage", "seconds"],
                   [[html.escape(k), f"{v:.2f}"] for k, v in timings.items()]
                   + [["<b>total</b>", f"<b>{total:.2f}</b>"]], [False, True])
    warn = ("<ul>" + "".join(f'<li class="warn">{html.escape(w)}</li>' for w in warnings)
            + "</ul>") if warnings else "<p>none</p>"
    n_pts = [len(f) for f in frames]
    facts = (f"{skel.n_joints} joints, {skel.n_bones} bones, {skel.n_frames} frames "
             f"({min(n_pts, default=0)}-{max(n_pts, default=0)} points a frame, at most "
             f"{max_points} shown)")
    doc = (f'<!DOCTYPE html>\n<html><head><meta charset="utf-8">'
           f"<title>{html.escape(title)} - pointrig</title><style>{_STYLE}</style></head>"
           f"<body><h1>{html.escape(title)}</h1><p>{html.escape(facts)}. Drag to rotate, "
           "scroll to zoom, Play to run the sequence.</p>"
           f"{plot}<h2>Time per stage</h2>{times}<h2>Warnings</h2>{warn}</body></html>\n")
    out = Path(path)
    with atomic_path(out) as tmp:
        tmp.write_text(doc, encoding="utf-8")
    return out


def write_index(path: str | Path, header: Sequence[str], rows: Sequence[Sequence[Any]],
                reports: Sequence[str | None], title: str = "pointrig batch") -> Path:
    """Write ``index.html``: the summary table ``rows`` (one per recording, the first column
    its name) with the name linked to its report (``reports``: a path relative to the page, or
    ``None`` when the recording has none), atomically. Needs no plotly."""
    cells = []
    for row, rep in zip(rows, reports):
        name = html.escape(str(row[0]))
        first = f'<a href="{html.escape(rep)}">{name}</a>' if rep else name
        rest = [html.escape(str(c)) for c in row[1:]]
        if rest and rest[-1]:
            rest[-1] = f'<span class="fail">{rest[-1]}</span>'
        cells.append([first, *rest])
    num = [False] + [h in ("frames", "joints", "time s", "warnings") for h in header[1:]]
    doc = (f'<!DOCTYPE html>\n<html><head><meta charset="utf-8">'
           f"<title>{html.escape(title)}</title><style>{_STYLE}</style></head><body>"
           f"<h1>{html.escape(title)}</h1>{_table(header, cells, num)}</body></html>\n")
    out = Path(path)
    with atomic_path(out) as tmp:
        tmp.write_text(doc, encoding="utf-8")
    return out
