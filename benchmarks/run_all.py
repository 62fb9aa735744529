"""Run every benchmark of ``benchmarks/BENCHMARKS.md``, one after the other.

Each benchmark prints its own table with a reference measured in the same run; this script
runs them in sequence from the repository root (``python -m benchmarks.NAME``) and reports
which failed::

    python -m benchmarks.run_all [--quick]

``--quick`` is a smoke run: 20-frame sequences, the suite on two sequences, the smaller sizes.
The whole run takes about 35 minutes on two idle cores, most of it the accuracy suite and the
memory runs (100 and 300 frames of 640x480 depth).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def runs(quick: bool) -> list[list[str]]:
    """The benchmark module names with their arguments, full or ``quick``."""
    if quick:
        return [
            ["bench_kernels", "--frames", "20"],
            ["bench_registration", "--frames", "20"],
            ["bench_nearest", "--sizes", "10000", "--repeat", "1"],
            ["bench_render"],
            ["bench_background", "--frames", "2"],
            ["bench_speed", "--frames", "20"],
            ["bench_speed", "--stages", "--frames", "20"],
            ["bench_dembones", "--frames", "20"],
            ["bench_scaling", "--quick"],
            ["bench_suite", "--frames", "20", "--only", "human,hand"],
            ["bench_memory", "--frames", "20,40"],
        ]
    return [
        ["bench_kernels"],
        ["bench_registration"],
        ["bench_nearest"],
        ["bench_render"],
        ["bench_background"],
        ["bench_speed"],
        ["bench_speed", "--stages"],
        ["bench_dembones"],
        ["bench_scaling", "--quick"],  # the whole table takes hours: run it on its own
        ["bench_suite"],
        ["bench_memory"],
    ]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="short sequences (smoke run)")
    args = ap.parse_args(argv)
    failed = []
    for run in runs(args.quick):
        print(f"\n=== {' '.join(run)}", flush=True)
        t0 = time.perf_counter()
        rc = subprocess.call([sys.executable, "-m", f"benchmarks.{run[0]}", *run[1:]], cwd=ROOT)
        print(f"=== {run[0]}: exit {rc}, {time.perf_counter() - t0:.0f} s", flush=True)
        if rc != 0:
            failed.append(run[0])
    if failed:
        print(f"\nfailed: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
