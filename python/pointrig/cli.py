"""The ``pointrig`` command line. The only module that prints or exits.

Subcommands: ``extract``, ``batch``, ``demo``, ``synth``, ``evaluate``, ``info``,
``preview``. Heavy imports (scipy, the pipeline) happen inside the subcommands so that
``pointrig --help`` and ``pointrig info`` start fast.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import time
from collections.abc import Sequence

from .config import PRESETS, PreprocessConfig
from .errors import ConfigError, InputError, PointrigError
from .sequence import check_units

__all__ = ["main", "build_parser"]


def _floats3(text: str) -> tuple[float, float, float]:
    try:
        vals = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected x,y,z numbers, got {text!r}") from None
    if len(vals) != 3:
        raise argparse.ArgumentTypeError(f"expected 3 comma-separated numbers, got {text!r}")
    return vals  # type: ignore[return-value]


def _ints4(text: str) -> tuple[int, int, int, int]:
    try:
        vals = tuple(int(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected U0,V0,U1,V1 whole pixels, got {text!r}") \
            from None
    if len(vals) != 4:
        raise argparse.ArgumentTypeError(f"expected 4 comma-separated pixels, got {text!r}")
    return vals  # type: ignore[return-value]


def _add_input_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", help="a recording (Azure Kinect/Orbbec .mkv, RealSense .bag, ROS 2 "
                   "bag, Record3D .r3d, Stray Scanner folder), a folder of frames "
                   "(ply/pcd/xyz/txt/npy/depth png) or an .npz (docs/inputs.md)")
    _add_reading_options(p)


def _add_config_options(p: argparse.ArgumentParser) -> None:
    """``--config`` and ``--preset`` (extract and batch; read by :func:`_config_from_args`)."""
    p.add_argument("--config", default=None, help="TOML file overriding any parameter")
    p.add_argument("--preset", choices=PRESETS, default="default",
                   help="the parameters the --config file overrides: default; fast (about "
                   "half the time, a larger joint error; docs/parameters.md); paper (the "
                   "paper's method)")


def _add_reading_options(p: argparse.ArgumentParser) -> None:
    """How a recording is read (frames, depth range, crops, units, camera): extract, info,
    preview and batch (where they apply to every recording)."""
    p.add_argument("--topic", default=None,
                   help="ROS bags: the depth image or PointCloud2 topic to read")
    p.add_argument("--near", type=float, default=None, metavar="M",
                   help="drop depth nearer than M metres (camera z)")
    p.add_argument("--far", type=float, default=None, metavar="M",
                   help="drop depth farther than M metres (camera z): the room behind a subject")
    p.add_argument("--crop", type=_ints4, default=None, metavar="U0,V0,U1,V1",
                   help="keep this pixel box of the depth images (columns U0..U1-1, rows "
                   "V0..V1-1; pick it on `pointrig preview`)")
    p.add_argument("--start", type=int, default=0, help="first frame (default 0)")
    p.add_argument("--stop", type=int, default=None, help="stop before this frame")
    p.add_argument("--stride", type=int, default=1,
                   help="use every n-th frame (2 for a 60 fps camera: the defaults were chosen "
                   "at 30 fps)")
    p.add_argument("--crop-min", type=_floats3, default=None, metavar="X,Y,Z",
                   help="crop box minimum corner, metres")
    p.add_argument("--crop-max", type=_floats3, default=None, metavar="X,Y,Z",
                   help="crop box maximum corner, metres")
    p.add_argument("--voxel", type=float, default=0.0, help="voxel downsampling size, metres")
    p.add_argument("--scale", type=float, default=1.0,
                   help="multiply coordinates to get metres (0.001 for millimetres)")
    p.add_argument("--skip-bad-frames", action="store_true",
                   help="leave out frame files that cannot be read, with a warning (recorded "
                   "with each used frame's index in skeleton.json), instead of stopping")
    p.add_argument("--intrinsics", default=None,
                   help="camera intrinsics JSON for depth PNGs: fx, fy, cx, cy[, depth_scale] or "
                   "Open3D's intrinsic_matrix (default: intrinsics.json, intrinsic.json or "
                   "camera_intrinsic.json in the folder or its parent)")


def _isolation(args: argparse.Namespace):
    from .io.depthcam import Isolation

    return Isolation(near=args.near, far=args.far, crop=args.crop)


def _read_input(args: argparse.Namespace, min_frames: int = 2):
    from .io import read_sequence

    return read_sequence(
        args.input, start=args.start, stop=args.stop, stride=args.stride,
        crop_min=args.crop_min, crop_max=args.crop_max, voxel_size=args.voxel,
        intrinsics=args.intrinsics, scale=args.scale, min_frames=min_frames,
        skip_bad_frames=args.skip_bad_frames,
        topic=args.topic, isolation=_isolation(args),
    )


def _print_recording(s: dict) -> None:
    """The recording's own description (device, image, rate, calibration, time), if any."""
    if "device" in s:
        print(f"device   {s['device']}")
    k = s.get("intrinsics", {})
    if "resolution" not in s and "width" in k and "height" in k:  # depth PNGs
        print(f"depth    {int(k['width'])} x {int(k['height'])} px")
    if s.get("resolution"):
        fps = f", {s['fps']:g} fps" if s.get("fps") else ""
        print(f"depth    {s['resolution'][0]} x {s['resolution'][1]} px{fps}"
              + (f", mode {s['depth_mode']}" if s.get("depth_mode") else ""))
    if "frames_in_file" in s:
        dur = s.get("duration_s")
        n = s["frames_in_file"]
        print(f"file     {n} frame{'' if n == 1 else 's'}"
              + (f", {dur:.3f} s" if dur is not None else ""))
    if "topic" in s:
        print(f"topic    {s['topic']} ({s.get('message_type', '')})")
    if "isolation" in s:
        iso = s["isolation"]
        parts = [f"{k} {iso[k]:g} m" for k in ("near", "far") if iso[k] is not None]
        if iso["crop"] is not None:
            parts.append("crop " + ",".join(str(c) for c in iso["crop"]) + " px")
        print(f"kept     {', '.join(parts)}")


def cmd_info(args: argparse.Namespace) -> int:
    """Print a sequence summary."""
    seq = _read_input(args, min_frames=1)
    s = seq.summary()
    if args.json:
        print(json.dumps(s, indent=1))
        return 0
    print(f"source   {s['source']}")
    print(f"format   {s['format']}")
    _print_recording(s)
    print(f"frames   {s['frames']}")
    print(f"points   min {s['points_min']}  median {s['points_median']}  max {s['points_max']}")
    lo = ", ".join(f"{v:.3f}" for v in s["bounds_min"])
    hi = ", ".join(f"{v:.3f}" for v in s["bounds_max"])
    print(f"bounds   [{lo}] .. [{hi}] m")
    if "intrinsics" in s:
        k = s["intrinsics"]
        unit = k.get("depth_scale", s.get("depth_unit_m"))
        where = k["source"] if "source" in k else (k.get("path") or "given")
        model = f", {k['model']}" if k.get("model", "pinhole") != "pinhole" else ""
        print(f"camera   fx {k['fx']:g} fy {k['fy']:g} cx {k['cx']:g} cy {k['cy']:g} px{model}, "
              + (f"depth unit {unit:g} m " if unit else "") + f"({where})")
    try:
        check_units(seq, PreprocessConfig().max_extent)
    except InputError as exc:  # info only describes; extract refuses such input
        print(f"note     {exc.problem}")
    return 0


class _ProgressPrinter:
    """Progress on stderr: a live line on a terminal, a line per step/decile otherwise."""

    def __init__(self, quiet: bool = False):
        self.quiet = quiet
        self.tty = sys.stderr.isatty()
        self.last: tuple[str, int] = ("", -1)

    def __call__(self, step: str, done: int, total: int, detail: str = "") -> None:
        if self.quiet:
            return
        frac = done / max(total, 1)
        msg = f"[{step}] {done}/{total}" + (f" {detail}" if detail else "")
        if self.tty:
            bar = "#" * int(24 * frac)
            end = "\n" if done >= total else ""
            print(f"\r{msg:<40} [{bar:<24}]", end=end, file=sys.stderr, flush=True)
            return
        decile = int(10 * frac)
        if (step, decile) != self.last:
            self.last = (step, decile)
            print(msg, file=sys.stderr, flush=True)


def _config_from_args(args: argparse.Namespace):
    """The TOML config (if any) with the input options given on the command line on top."""
    import dataclasses

    from .config import PipelineConfig, load_config

    cfg = load_config(args.config, base=PipelineConfig.preset(args.preset))
    given = {
        "crop_min": args.crop_min, "crop_max": args.crop_max,
        "voxel_size": args.voxel or None, "frame_start": args.start or None,
        "frame_stop": args.stop, "frame_stride": None if args.stride == 1 else args.stride,
    }
    pre = dataclasses.replace(cfg.preprocess, **{k: v for k, v in given.items() if v is not None})
    cfg = dataclasses.replace(cfg, preprocess=pre)
    if getattr(args, "max_joints", None) is not None:  # extract only; checked by the config
        cfg = dataclasses.replace(cfg, structure=dataclasses.replace(
            cfg.structure, max_joints=args.max_joints))
    if getattr(args, "fps", None) is not None:  # extract only; checked by the config
        cfg = dataclasses.replace(cfg, rig=dataclasses.replace(cfg.rig, fps=args.fps))
    if getattr(args, "report", None) is not None:  # extract and batch; checked by the config
        cfg = dataclasses.replace(cfg, rig=dataclasses.replace(cfg.rig, report=args.report))
    if getattr(args, "rest_frame", None) is not None:  # extract only; checked by the config
        cfg = dataclasses.replace(cfg, registration=dataclasses.replace(
            cfg.registration, rest_frame=_rest_frame_arg(args.rest_frame)))
    return cfg


def _rest_frame_arg(text: str) -> int | str:
    """``--rest-frame``'s value: a frame index (an integer) or a choice name, as given (the
    config checks both: a bad name or an index outside the frames is one error line)."""
    try:
        return int(text)
    except ValueError:
        return text


def _read_configured(args: argparse.Namespace, cfg, spill: str | os.PathLike | None = None):
    """The input as ``[preprocess]`` selects and cleans it, its frames kept on disk in the
    folder ``spill`` (read back on demand) when given."""
    from .batch import read_recording

    return read_recording(
        args.input, cfg, scale=args.scale, intrinsics=args.intrinsics, topic=args.topic,
        isolation=_isolation(args), skip_bad_frames=args.skip_bad_frames, spill=spill,
        background_note=lambda line: print(f"[background] {line}", file=sys.stderr))


def _summary_line(res, out, input_s: float | None = None) -> str:
    """One line: joints, bones, frames, the time per stage (``input_s``: reading and
    background removal, seconds, when measured) and the output folder."""
    sk = res.skeleton
    t = ({"input": input_s} if input_s is not None else {}) | res.timings
    total = sum(t.values())
    parts = [f"{k} {v:.1f}s" for k, v in t.items()]
    reused = " (registration reused)" if res.reused_registration else ""
    return (f"{sk.n_joints} joints, {sk.n_bones} bones over {sk.n_frames} frames in "
            f"{total:.1f}s ({', '.join(parts)}){reused} -> {out}")


def cmd_extract(args: argparse.Namespace) -> int:
    """Run the pipeline on a sequence."""
    from .io.outdir import FRAMES, OutputDir
    from .pipeline import extract

    cfg = _config_from_args(args)
    # the output folder checked and locked before the input is read
    with OutputDir(args.output) as od:
        t0 = time.perf_counter()
        # the frames wait on disk in the staging folder, so memory does not grow with them
        seq = _read_configured(args, cfg, spill=od.staged(FRAMES))
        input_s = time.perf_counter() - t0
        res = extract(seq, cfg, od, resume=args.resume, stop_after=args.stop_after,
                      pictures=not args.no_pictures, progress=_ProgressPrinter(args.quiet),
                      bone_names=args.bone_names)
    if res.skeleton is None:
        print(f"registration written to {res.files.get('registration')}")
    else:
        print(_summary_line(res, args.output, input_s))
    return 0


def cmd_batch(args: argparse.Namespace) -> int:
    """Run extract on many recordings; the summary table; exit code 1 if any failed."""
    from .batch import BatchOptions, format_table, run_batch

    if args.scheduler and args.jobs != 1:
        raise ConfigError("--jobs and --scheduler exclude each other (the cluster's workers "
                          "set how many recordings run at once)")
    opts = BatchOptions(config=_config_from_args(args), pictures=not args.no_pictures,
                        resume=args.resume, scale=args.scale, intrinsics=args.intrinsics,
                        topic=args.topic, isolation=_isolation(args),
                        skip_bad_frames=args.skip_bad_frames)
    n = len(args.inputs)
    count = [0]

    def done(row) -> None:
        count[0] += 1
        if args.quiet:
            return
        what = (f"FAILED: {row.failure}" if row.failure else
                f"{row.joints} joints, {row.frames} frames in {row.time_s:.1f}s")
        print(f"[batch] {count[0]}/{n} {row.recording}: {what}", file=sys.stderr, flush=True)

    res = run_batch(args.inputs, args.output, opts, jobs=args.jobs, threads=args.threads,
                    scheduler=args.scheduler, done=done)
    print(format_table(res.rows))
    print(f"summary {res.summary}, index {res.index}")
    if res.failed:
        names = ", ".join(r.recording for r in res.failed)
        print(f"pointrig batch: {len(res.failed)} of {n} recordings failed ({names}); the "
              f"others are done, see {res.summary}", file=sys.stderr)
        return 1
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    """Run the main job on the bundled demo sequence and score it against its ground truth."""
    from .config import PipelineConfig
    from .data import demo_path
    from .evaluate import evaluate_files
    from .io import read_sequence
    from .pipeline import extract

    path = demo_path()
    seq = read_sequence(path / "frames")
    s = seq.summary()
    print(f"demo sequence {path}: {s['frames']} frames, "
          f"{s['points_min']}-{s['points_max']} points per frame")
    res = extract(seq, PipelineConfig(), args.output, progress=_ProgressPrinter(args.quiet))
    print(_summary_line(res, args.output))
    rep = evaluate_files(args.output + "/skeleton.json", path / "gt.npz")
    print(rep.format_table())
    print(f"outputs: {', '.join(str(p) for p in res.files.values())}")
    return 0


def _noise_from_args(args: argparse.Namespace):
    from dataclasses import replace

    from .synth import NoiseConfig

    base = NoiseConfig.clean() if args.clean else NoiseConfig()
    over = {"seed": args.noise_seed, "floor": args.floor, "background": args.background}
    for key in ("dropout", "outliers", "flying", "lateral_px"):
        val = getattr(args, key)
        if val is not None:
            over[key] = val
    if args.no_quantize:
        over["quantize"] = False
    return replace(base, **over)


def _check_synth_output(path: str, force: bool) -> None:
    """Refuse, before rendering, an output that is a file or a non-empty folder (without
    ``force``): writing the sequence replaces ``frames/frame_*.ply`` and ``gt.npz``."""
    from pathlib import Path

    from .errors import OutputError

    out = Path(path)
    if out.exists() and not out.is_dir():
        raise OutputError("the output path is a file, not a folder", out)
    if out.is_dir() and any(out.iterdir()) and not force:
        raise OutputError("the output folder is not empty; pass --force to replace its "
                          "frames/ and gt.npz", out)


def cmd_synth(args: argparse.Namespace) -> int:
    """Render a synthetic depth-camera sequence with ground truth."""
    from .synth import FIGURES, Camera, synthesize

    if args.list:
        print("figures: " + ", ".join(FIGURES))
        print("or a rigged, animated .glb/.gltf file")
        return 0
    if args.source is None or args.output is None:
        raise ConfigError("give a SOURCE (figure name or .glb/.gltf) and -o OUTPUT")
    if args.source in FIGURES or args.source.lower().endswith((".glb", ".gltf", ".bvh")):
        _check_synth_output(args.output, args.force)  # else synthesize names the bad source
    seq = synthesize(
        args.source, n_frames=args.frames, seed=args.seed, camera=Camera.kinect(args.resolution),
        noise=_noise_from_args(args), fps=args.fps, speed=args.speed, amplitude=args.amplitude,
        walk=args.walk, yaw=args.yaw, clip=args.clip, start=args.clip_start,
        surface_points=args.surface_points,
    )
    out = seq.write(args.output)
    n = [len(f) for f in seq.frames]
    print(f"wrote {out}/frames ({seq.n_frames} frames, {min(n)}-{max(n)} points) and "
          f"{out}/gt.npz ({len(seq.joint_names)} joints, {seq.surface.shape[1]} surface samples)")
    if args.preview:
        from .viz import preview_sequence

        png = preview_sequence(out, args.preview, frame=min(args.preview_frame,
                                                             seq.n_frames - 1))
        print(f"preview {png}")
    return 0


def cmd_evaluate(args: argparse.Namespace) -> int:
    """Score a predicted skeleton against ground truth."""
    from .evaluate import THRESHOLD_FRACTION, evaluate_files

    rep = evaluate_files(
        args.pred, args.gt, start=args.start, stop=args.stop, stride=args.stride,
        threshold=args.threshold,
        threshold_fraction=(args.threshold_fraction if args.threshold_fraction is not None
                            else THRESHOLD_FRACTION),
        swing_source=args.swing_source,
    )
    if args.json:
        print(json.dumps(rep.to_dict(), indent=1))
    else:
        print(rep.format_table())
    return 0


def cmd_preview(args: argparse.Namespace) -> int:
    """Write a PNG of one frame: of a recording or depth PNGs, what subject isolation keeps;
    of a synthetic sequence, its points with ground-truth (and predicted) joints."""
    from pathlib import Path

    from .viz import preview_input, preview_sequence

    png = None
    if args.skeleton is None and not (Path(args.sequence) / "gt.npz").exists():
        png = preview_input(args.sequence, args.output, frame=args.frame,
                            isolation=_isolation(args), intrinsics=args.intrinsics,
                            topic=args.topic)
    if png is None:
        png = preview_sequence(args.sequence, args.output, frame=args.frame,
                               skeleton_json=args.skeleton, isolation=_isolation(args),
                               topic=args.topic)
    print(f"preview {png}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``pointrig`` command."""
    from . import __version__
    from .evaluate import SWING_SOURCES

    parser = argparse.ArgumentParser(
        prog="pointrig",
        description="Extract an articulated skeleton from a depth-camera point cloud sequence.",
    )
    parser.add_argument("--version", action="version", version=f"pointrig {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more logging")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("info", help="summarise a sequence (frames, points, bounds, format)")
    _add_input_options(p)
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=cmd_info)

    p = sub.add_parser("extract", help="extract a skeleton from a sequence (steps 1-3)")
    _add_input_options(p)
    p.add_argument("-o", "--output", required=True, help="output folder")
    _add_config_options(p)
    p.add_argument("--resume", action=argparse.BooleanOptionalAction, default=True,
                   help="reuse OUT/registration.npz when input and step-1 parameters match")
    p.add_argument("--stop-after", choices=["registration", "structure", "joints"],
                   default="joints", help="stop after this step (structure: score step 2 alone)")
    p.add_argument("--no-pictures", action="store_true", help="skip skeleton.png/.gif")
    p.add_argument("--max-joints", type=int, default=None, metavar="N",
                   help="at most N joints, when you know the subject (an arm: 3, shoulder, "
                        "elbow, wrist); overrides [structure] max_joints (default 0: as many "
                        "as the motion shows)")
    p.add_argument("--rest-frame", default=None, metavar="N|fit",
                   help="the frame whose pose is the rest pose: an index among the frames used "
                        "(after --start/--stride), or fit (default: the frame showing the most "
                        "surface near the middle, unless a frame of another pose registers "
                        "clearly better, e.g. legs that touch in the first one); overrides "
                        "[registration] rest_frame. A frame where no limb touches the body or "
                        "another limb (a T- or A-pose) gives the best skeleton")
    p.add_argument("--fps", type=float, default=None,
                   help="frame rate of the recording, Hz (default 30); the outputs play at "
                        "fps / --stride; overrides [rig] fps")
    p.add_argument("--bone-names", default=None, metavar="JSON",
                   help="a JSON object {joint name: new name} renaming joints in every output")
    p.add_argument("--report", choices=("auto", "on", "off"), default=None,
                   help="report.html, a page with a 3D view of the run (auto: when the report "
                   "extra, plotly, is installed); overrides [rig] report")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    p.set_defaults(func=cmd_extract)

    p = sub.add_parser(
        "batch", help="extract skeletons from many recordings: OUT/<name>/ each, a summary",
        description="Run extract on every INPUT into OUT/<name>/ (name: the file or folder name "
        "without its suffix), then write OUT/summary.csv and OUT/index.html (the table, each "
        "recording linked to its report.html) and print the table. A recording that fails is "
        "recorded with its error and the others go on; the exit code is 1 if any failed. "
        "See docs/batch.md.")
    p.add_argument("inputs", nargs="+", metavar="INPUT",
                   help="recordings, as for extract (docs/inputs.md)")
    p.add_argument("-o", "--output", required=True, help="output folder of the batch")
    _add_config_options(p)
    p.add_argument("-j", "--jobs", type=int, default=1, metavar="N",
                   help="recordings at once on this machine, each in its own process with "
                   "its threads capped so that N x threads = cores (default 1)")
    p.add_argument("--threads", type=int, default=None, metavar="T",
                   help="threads per recording (default: cores / N; 1 with --scheduler)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="run the recordings on an existing Dask distributed cluster, e.g. "
                   "tcp://10.0.0.5:8786 (the batch extra; inputs and OUT on a shared file "
                   "system)")
    p.add_argument("--resume", action=argparse.BooleanOptionalAction, default=True,
                   help="reuse OUT/<name>/registration.npz when input and step-1 parameters "
                   "match")
    p.add_argument("--no-pictures", action="store_true", help="skip skeleton.png/.gif")
    p.add_argument("--report", choices=("auto", "on", "off"), default=None,
                   help="report.html per recording (as for extract); overrides [rig] report")
    _add_reading_options(p)
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    p.set_defaults(func=cmd_batch)

    p = sub.add_parser("demo", help="run the pipeline on the bundled demo sequence")
    p.add_argument("-o", "--output", default="pointrig-demo",
                   help="output folder (default: ./pointrig-demo)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    p.set_defaults(func=cmd_demo)

    p = sub.add_parser("synth", help="render a synthetic depth-camera sequence with ground truth")
    p.add_argument("source", nargs="?", default=None,
                   help="a figure (human, upper_body, arm, hand, quadruped, snake, robot_arm) "
                        "or a rigged, animated .glb/.gltf")
    p.add_argument("-o", "--output", default=None, help="output folder (frames/ and gt.npz)")
    p.add_argument("--list", action="store_true", help="list the procedural figures")
    p.add_argument("--force", action="store_true",
                   help="write into a non-empty output folder, replacing its frames/ and gt.npz")
    p.add_argument("--frames", type=int, default=30, help="number of frames (default 30)")
    p.add_argument("--seed", type=int, default=0, help="motion and sampling seed")
    p.add_argument("--fps", type=float, default=30.0, help="frame rate, Hz (default 30)")
    p.add_argument("--speed", type=float, default=1.0,
                   help="motion speed factor (6 makes the arm move > 25 cm per frame)")
    p.add_argument("--amplitude", type=float, default=1.0,
                   help="joint-angle excursion as a fraction of the joint range")
    p.add_argument("--walk", type=float, default=0.0,
                   help="metres of root translation across the view over the sequence")
    p.add_argument("--yaw", type=float, default=0.0, help="turn the subject, degrees")
    p.add_argument("--clip", default=None, help="glTF animation name or index")
    p.add_argument("--clip-start", type=float, default=0.0, help="glTF clip time offset, s")
    p.add_argument("--resolution", type=int, choices=(640, 320), default=640,
                   help="640 (640x480, fx 525) or 320 (320x240)")
    p.add_argument("--surface-points", type=int, default=3000,
                   help="exact surface samples stored in gt.npz")
    p.add_argument("--clean", action="store_true", help="no sensor corruption at all")
    p.add_argument("--noise-seed", type=int, default=0, help="seed of the sensor noise")
    p.add_argument("--dropout", type=float, default=None, help="random pixel dropout fraction")
    p.add_argument("--outliers", type=float, default=None,
                   help="uniform outliers, fraction of the points")
    p.add_argument("--flying", type=float, default=None,
                   help="probability of a flying pixel at a depth edge")
    p.add_argument("--lateral-px", type=float, default=None, help="lateral jitter, pixels")
    p.add_argument("--no-quantize", action="store_true", help="no disparity quantisation")
    p.add_argument("--floor", action="store_true", help="add floor points")
    p.add_argument("--background", action="store_true", help="add a background wall")
    p.add_argument("--preview", default=None, metavar="PNG",
                   help="also write a PNG preview of a frame")
    p.add_argument("--preview-frame", type=int, default=0, help="frame of the preview")
    p.set_defaults(func=cmd_synth)

    p = sub.add_parser("evaluate", help="score a skeleton.json against ground truth (gt.npz)")
    p.add_argument("pred", help="skeleton.json (or its folder, or an .npz with 'joints')")
    p.add_argument("gt", help="gt.npz (or the synthetic sequence folder)")
    p.add_argument("--threshold", type=float, default=None,
                   help="matching threshold, metres (default: a fraction of the subject size)")
    p.add_argument("--threshold-fraction", type=float, default=None,
                   help="matching threshold as a fraction of the subject size (default 0.08)")
    p.add_argument("--start", type=int, default=0, help="first GT frame used for extraction")
    p.add_argument("--stop", type=int, default=None, help="stop before this GT frame")
    p.add_argument("--stride", type=int, default=1, help="GT frame stride used for extraction")
    p.add_argument("--swing-source", choices=SWING_SOURCES, default="auto",
                   help="motions of the 'visibly articulates' test: the rig's bone transforms "
                        "(auto: when gt.npz has them) or Kabsch fits of the surface parts")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=cmd_evaluate)

    p = sub.add_parser("preview", help="PNG of a frame: of a recording or depth PNGs, the depth "
                       "image and what --near/--far/--crop keep; else points and GT joints")
    p.add_argument("sequence", help="a recording, a folder of depth PNGs, or a sequence folder "
                   "(frames/ and optional gt.npz)")
    p.add_argument("--near", type=float, default=None, metavar="M", help="as for extract")
    p.add_argument("--far", type=float, default=None, metavar="M", help="as for extract")
    p.add_argument("--crop", type=_ints4, default=None, metavar="U0,V0,U1,V1",
                   help="as for extract: the box is drawn")
    p.add_argument("--topic", default=None, help="ROS bags: the topic")
    p.add_argument("--intrinsics", default=None, help="as for extract")
    p.add_argument("--frame", type=int, default=0, help="frame index (default 0)")
    p.add_argument("-o", "--output", required=True, help="output PNG")
    p.add_argument("--skeleton", default=None, help="also overlay a predicted skeleton.json")
    p.set_defaults(func=cmd_preview)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit code (0 ok, 1 pointrig error, 2 usage error)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING - 10 * min(args.verbose, 2),
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        code = int(args.func(args) or 0)
        sys.stdout.flush()  # a closed pipe shows here, inside the handler below
        return code
    except PointrigError as exc:
        print(f"pointrig {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # the reader of stdout went away (`pointrig evaluate ... | head`): stop quietly, as
        # other command-line tools do, instead of a traceback; point stdout at devnull so the
        # interpreter's final flush does not raise again
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 141  # 128 + SIGPIPE, the shell's code for a process ended by a closed pipe
