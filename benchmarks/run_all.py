"""Run the benchmarks behind the README's performance table, one after the other.

Each benchmark prints its own table (with a reference measured in the same run); this script
only runs them in sequence with the project's paths set and reports which failed. Figures are
recorded by hand in ``benchmarks/RESULTS.md`` and the README. Run (``make bench``)::

    .venv/bin/python benchmarks/run_all.py [--quick]

``--quick`` shortens the sequences (40 frames instead of 100) for a smoke run.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="40-frame sequences (smoke run)")
    args = ap.parse_args(argv)
    frames = "40" if args.quick else "100"
    runs = [
        ["bench_registration.py", "--frames", frames],
        ["bench_structure.py"],
        ["bench_structure_suite.py", "--timing"],
        ["bench_render.py"],
        ["bench_nearest.py"],
        ["bench_refine.py", "--frames", frames],
        ["bench_joint_oracle.py", "--frames", frames],
        ["bench_bone_spin.py", "--frames", frames],
        ["bench_registration_twist.py", "--frames", frames,
         '{"joints": {"bone_twist": "fit"}}', "{}"],
    ]
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(
        [str(ROOT / "python"), str(ROOT / "tests"), env.get("PYTHONPATH", "")]
    ).rstrip(os.pathsep)
    failed = []
    for run in runs:
        print(f"\n=== {' '.join(run)}", flush=True)
        t0 = time.perf_counter()
        rc = subprocess.call([sys.executable, str(ROOT / "benchmarks" / run[0]), *run[1:]],
                             env=env)
        print(f"=== {run[0]}: exit {rc}, {time.perf_counter() - t0:.0f} s", flush=True)
        if rc != 0:
            failed.append(run[0])
    if failed:
        print(f"\nfailed: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
