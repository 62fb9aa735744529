"""The ``pointrig`` command line. The only module that prints or exits.

Subcommands: ``extract``, ``demo``, ``synth``, ``evaluate``, ``info``. Heavy imports (open3d,
the pipeline) happen inside the subcommands so that ``pointrig --help`` and ``pointrig info``
start fast.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from collections.abc import Sequence

from .errors import PointrigError

__all__ = ["main", "build_parser"]


def _floats3(text: str) -> tuple[float, float, float]:
    try:
        vals = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected x,y,z numbers, got {text!r}") from None
    if len(vals) != 3:
        raise argparse.ArgumentTypeError(f"expected 3 comma-separated numbers, got {text!r}")
    return vals  # type: ignore[return-value]


def _add_input_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", help="a folder of frames (ply/pcd/xyz/txt/npy/depth png) or an .npz")
    p.add_argument("--start", type=int, default=0, help="first frame (default 0)")
    p.add_argument("--stop", type=int, default=None, help="stop before this frame")
    p.add_argument("--stride", type=int, default=1, help="use every n-th frame")
    p.add_argument("--crop-min", type=_floats3, default=None, metavar="X,Y,Z",
                   help="crop box minimum corner, metres")
    p.add_argument("--crop-max", type=_floats3, default=None, metavar="X,Y,Z",
                   help="crop box maximum corner, metres")
    p.add_argument("--voxel", type=float, default=0.0, help="voxel downsampling size, metres")
    p.add_argument("--scale", type=float, default=1.0,
                   help="multiply coordinates to get metres (0.001 for millimetres)")
    p.add_argument("--intrinsics", default=None, help="camera intrinsics JSON for depth PNGs")


def _read_input(args: argparse.Namespace):
    from .io import read_sequence

    return read_sequence(
        args.input, start=args.start, stop=args.stop, stride=args.stride,
        crop_min=args.crop_min, crop_max=args.crop_max, voxel_size=args.voxel,
        intrinsics=args.intrinsics, scale=args.scale,
    )


def cmd_info(args: argparse.Namespace) -> int:
    """Print a sequence summary."""
    seq = _read_input(args)
    s = seq.summary()
    if args.json:
        print(json.dumps(s, indent=1))
        return 0
    print(f"source   {s['source']}")
    print(f"format   {s['format']}")
    print(f"frames   {s['frames']}")
    print(f"points   min {s['points_min']}  median {s['points_median']}  max {s['points_max']}")
    lo = ", ".join(f"{v:.3f}" for v in s["bounds_min"])
    hi = ", ".join(f"{v:.3f}" for v in s["bounds_max"])
    print(f"bounds   [{lo}] .. [{hi}] m")
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

    from .config import load_config

    cfg = load_config(args.config)
    given = {
        "crop_min": args.crop_min, "crop_max": args.crop_max,
        "voxel_size": args.voxel or None, "frame_start": args.start or None,
        "frame_stop": args.stop, "frame_stride": None if args.stride == 1 else args.stride,
    }
    pre = dataclasses.replace(cfg.preprocess, **{k: v for k, v in given.items() if v is not None})
    return dataclasses.replace(cfg, preprocess=pre)


def _read_configured(args: argparse.Namespace, cfg):
    from .io import read_sequence

    pre = cfg.preprocess
    return read_sequence(
        args.input, start=pre.frame_start, stop=pre.frame_stop, stride=pre.frame_stride,
        crop_min=pre.crop_min, crop_max=pre.crop_max, voxel_size=pre.voxel_size,
        intrinsics=args.intrinsics, scale=args.scale, min_points=pre.min_points,
    )


def _summary_line(res, out) -> str:
    sk = res.skeleton
    t = res.timings
    total = sum(t.values())
    parts = [f"{k} {v:.1f}s" for k, v in t.items()]
    reused = " (registration reused)" if res.reused_registration else ""
    return (f"{sk.n_joints} joints, {sk.n_bones} bones over {sk.n_frames} frames in "
            f"{total:.1f}s ({', '.join(parts)}){reused} -> {out}")


def cmd_extract(args: argparse.Namespace) -> int:
    """Run the pipeline on a sequence."""
    from .pipeline import extract

    cfg = _config_from_args(args)
    seq = _read_configured(args, cfg)
    res = extract(seq, cfg, args.output, resume=args.resume, stop_after=args.stop_after,
                  pictures=not args.no_pictures, progress=_ProgressPrinter(args.quiet))
    if res.skeleton is None:
        print(f"registration written to {res.files.get('registration')}")
    else:
        print(_summary_line(res, args.output))
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    """Run the main job on the bundled demo sequence."""
    from .data import demo_path
    from .io import read_sequence

    path = demo_path()
    seq = read_sequence(path / "frames")
    s = seq.summary()
    print(f"demo sequence {path}: {s['frames']} frames, "
          f"{s['points_min']}-{s['points_max']} points per frame")
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``pointrig`` command."""
    from . import __version__

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
    p.add_argument("--config", default=None, help="TOML file overriding any parameter")
    p.add_argument("--resume", action=argparse.BooleanOptionalAction, default=True,
                   help="reuse OUT/registration.npz when input and step-1 parameters match")
    p.add_argument("--stop-after", choices=["registration", "structure", "joints"],
                   default="joints", help="stop after this step (structure: score step 2 alone)")
    p.add_argument("--no-pictures", action="store_true", help="skip skeleton.png/.gif")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    p.set_defaults(func=cmd_extract)

    p = sub.add_parser("demo", help="run the pipeline on the bundled demo sequence")
    p.add_argument("-o", "--output", default=None, help="output folder (default: a temp folder)")
    p.set_defaults(func=cmd_demo)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit code (0 ok, 1 pointrig error, 2 usage error)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING - 10 * min(args.verbose, 2),
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        return int(args.func(args) or 0)
    except PointrigError as exc:
        print(f"pointrig {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
