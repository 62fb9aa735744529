"""The accuracy suite: the default pipeline (or variants of it) on the 14 sequences of
:data:`bench_refine.SEQUENCES` (or the validation set), with the rounding spread.

Each variant is a JSON object of per-stage overrides of :class:`pointrig.config.PipelineConfig`
(``{}`` = the defaults). Every sequence runs ``--repeats`` times per variant, repeat ``k > 0``
on the input moved by at most 1e-9 m (``bench_refine._jittered``, docs/registration.md
"Session 27": a difference smaller than this spread is not a measured difference). Prints per
sequence and variant recall / precision / raw / normalised cm (means over the repeats), then
per variant and repeat the suite means (errors over the sequences where every run matches a
joint) and the recall of the procedural figures and of the glTF rigs::

    PYTHONPATH=python python benchmarks/bench_suite.py                      # ~13 min a repeat
    PYTHONPATH=python python benchmarks/bench_suite.py --repeats 2 '{}' \\
        '{"registration": {"rest_frame": "middle"}}'                        # an ablation
    PYTHONPATH=python python benchmarks/bench_suite.py --frames 40 --only human,hand
    PYTHONPATH=python python benchmarks/bench_suite.py --set validation    # ~9 min a repeat

``--set validation`` runs :data:`bench_refine.VALIDATION` instead: 16 sequences of the same
figures and rigs with seeds, views and clips no change was tuned on (choose a variant on the
suite, then check it there). ``--set limbs`` runs :data:`bench_refine.LIMBS`: the bare arm
and the robot arm, five sequences the suite lacks. ``--set hands`` runs
:data:`bench_refine.HANDS`: six procedural hands (a 24 cm subject) at seeds and yaws no
session had run (session 56).

``--json FILE`` also writes every run's report.

A variant may carry the bench-only key ``"max_joints_from": "skinned"``: each sequence then runs
with ``[structure] max_joints`` set to its rig's number of skinned joints (what a user who knows
the subject would give, docs/structure.md "Session 39")::

    PYTHONPATH=python python benchmarks/bench_suite.py '{}' '{"max_joints_from": "skinned"}'
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "python"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_refine import _jittered, add_variant_options, chosen, suite  # noqa: E402
from bench_registration_downstream import score_joints  # noqa: E402
from compare_runs import common_means, run_from_reports  # noqa: E402

from pointrig.config import apply_overrides  # noqa: E402
from pointrig.pipeline import extract  # noqa: E402

#: The bench-only variant key (not a config key) that caps each sequence's joints at its rig's
#: skinned joint count (see the module docstring).
_CAP_KEY = "max_joints_from"


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_variant_options(ap)
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--json", type=Path, default=None, help="write every run's report here")
    a = ap.parse_args(argv)
    if a.repeats < 1:
        ap.error("--repeats must be >= 1")
    sequences, only = chosen(ap, a)
    procedural = {n for n, (src, _) in sequences.items() if not src.endswith(".glb")}
    try:
        overs = [json.loads(v) for v in a.variants]
        caps = [o.get(_CAP_KEY) for o in overs]
        if set(caps) - {None, "skinned"}:
            raise ValueError(f"{_CAP_KEY} must be \"skinned\"")
        cfgs = [apply_overrides({k: x for k, x in o.items() if k != _CAP_KEY},
                                where=f"variant {v}") for v, o in enumerate(overs)]
    except (ValueError, AttributeError) as exc:  # bad JSON, a ConfigError, not a mapping
        ap.error(f"bad variant: {exc}")
    # every run's report (errors in metres) and seconds, keyed "variant/repeat/name"
    reports: dict[str, dict] = {}
    print(f"{'sequence':<24}" + "".join(f"{'variant ' + str(v):>34}" for v in range(len(cfgs))))
    for name, syn in suite(a.frames, only, sequences):
        seq0 = syn.to_point_sequence()
        cells = []
        for v, cfg in enumerate(cfgs):
            if caps[v] == "skinned":
                cfg = dataclasses.replace(cfg, structure=dataclasses.replace(
                    cfg.structure, max_joints=int(np.sum(syn.skinned))))
            rows = []  # per repeat: recall, precision, raw cm, normalised cm, seconds
            for k in range(a.repeats):
                seq = seq0 if k == 0 else _jittered(seq0, k)
                t0 = time.perf_counter()
                out = extract(seq, cfg, None, pictures=False)
                secs = time.perf_counter() - t0
                rep = score_joints(out.skeleton.joint_positions, syn)
                rows.append((rep.recall, rep.precision, 100 * rep.raw_error,
                             100 * rep.normalized_error, secs))
                reports[f"{v}/{k}/{name}"] = rep.to_dict() | {"seconds": secs}
            g = np.array(rows)
            m = np.nanmean(g, axis=0) if np.isfinite(g[:, 3]).any() else g.mean(axis=0)
            cells.append(f"{m[0]:.2f}/{m[1]:.2f} {m[2]:5.2f} {m[3]:5.2f} ({m[4]:3.0f} s)")
        print(f"{name:<24}" + "".join(f"{c:>34}" for c in cells), flush=True)
        if a.json:
            a.json.write_text(json.dumps({"variants": overs, "runs": reports}, indent=1,
                                         default=str))
    if not reports:
        return 0
    keys = [(v, k) for v in range(len(cfgs)) for k in range(a.repeats)]
    runs = [run_from_reports(reports, v, k, f"{v}/{k}") for v, k in keys]
    names, every, means = common_means(runs)
    print(f"\nmeans over {len(names)} sequences of {a.frames} frames (raw / normalised over the "
          f"{len(every)} where every run matches a joint); recall of the procedural figures / "
          "the glTF rigs:")
    for (v, k), run, m in zip(keys, runs, means):
        proc = [run.rows[n][0] for n in names if n in procedural]
        gl = [run.rows[n][0] for n in names if n not in procedural]
        f = lambda x: f"{np.mean(x):.3f}" if len(x) else "-"  # noqa: E731
        secs = sum(reports[f"{v}/{k}/{n}"]["seconds"] for n in names)
        print(f"variant {v} repeat {k}: recall {m[0]:.3f} precision {m[1]:.3f} raw "
              f"{100 * m[2]:.2f} cm normalised {100 * m[3]:.2f} cm; procedural {f(proc)} glTF "
              f"{f(gl)}; {secs:.0f} s  {a.variants[v]}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
