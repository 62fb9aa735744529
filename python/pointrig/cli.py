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
