"""How far the registration slides each part along its own axis (a diagnostic of step 1).

A limb is a tube, and a one-sided depth view has no data force along a tube: a template can
slide along it and still lie on the surface. Session 62 found the girl's left shin template
sliding up towards the knee by up to half the shin (f_girl_run_y15: 21 cm of a 40 cm shin)
while staying within 1-3 cm of the surface, phase-locked to the stride, with the ankle joint
dragged along. This benchmark measures that on the cached inputs of ``bench_step3.py``
(the refined registration the final step 2 and step 3 read): for every true bone with one
child joint, the registered points tied to it (by their nearest exact surface sample of the
rest frame) are compared with the exact motion of those samples, and their mean offset is
split into the part *along* the bone's axis (head joint -> child joint, signed, positive =
towards the child) and the part *across* it (:func:`axial_offsets`)::

    PYTHONPATH=python python benchmarks/bench_slide.py --cache /tmp/step3 --set all
    PYTHONPATH=python python benchmarks/bench_slide.py --cache /tmp/step3 --only girl_run \\
        --frames-of LowerLeg.L

Prints per sequence the mean correspondence error and the three bones with the largest mean
``|along|`` (mean and largest ``|along|``, mean across, cm), then over all bones of all
sequences the share of the correspondence error that lies along the axes. ``--frames-of NAME``
adds that bone's along-axis offset every fourth frame.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "python"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_refine import add_cache_options, chosen, suite  # noqa: E402
from bench_step3 import cached_inputs  # noqa: E402


def axial_offsets(points: np.ndarray, truth: np.ndarray, head: np.ndarray, tail: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Mean offset of registered points from their true positions, along and across an axis.

    Parameters
    ----------
    points
        ``(F, n, 3)`` registered points, metres.
    truth
        ``(F, n, 3)`` the true positions of the same material points, metres.
    head, tail
        ``(F, 3)`` the axis ends per frame (a bone's head joint and its child joint), metres.

    Returns
    -------
    along, across
        ``(F,)`` each: the mean signed offset along the unit axis ``head -> tail`` (metres,
        positive = towards ``tail``) and the mean length of the offsets' components
        perpendicular to it (metres).
    """
    u = np.asarray(tail, dtype=float) - np.asarray(head, dtype=float)
    u = u / np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-12)
    D = np.asarray(points, dtype=float) - np.asarray(truth, dtype=float)  # (F, n, 3)
    a = np.einsum("fni,fi->fn", D, u)
    perp = D - a[..., None] * u[:, None, :]
    return a.mean(axis=1), np.linalg.norm(perp, axis=2).mean(axis=1)


def nearest_samples(rest: np.ndarray, syn: Any, rest_index: int) -> np.ndarray:
    """``(M,)`` index of each rest point's ``(M, 3)`` nearest exact surface sample of frame
    ``rest_index`` (``syn.surface``, ``(F, S, 3)``): the tie to the truth of this benchmark."""
    return cKDTree(syn.surface[rest_index]).query(rest)[1]


def correspondence(points: np.ndarray, syn: Any, nearest: np.ndarray) -> float:
    """Mean distance (metres) of registered ``points`` ``(F, M, 3)`` to the exact motion of
    each rest point's nearest exact sample of the rest frame (``nearest``
    :func:`nearest_samples`, ``(M,)``): the correspondence error of this benchmark."""
    return float(np.linalg.norm(points - syn.surface[:, nearest], axis=2).mean())


def bone_slides(rest: np.ndarray, registered: np.ndarray, syn: Any, rest_index: int,
                min_points: int = 10, nearest: np.ndarray | None = None
                ) -> list[tuple[str, int, np.ndarray, np.ndarray]]:
    """:func:`axial_offsets` of every true bone with exactly one child joint.

    Each rest point ``(M, 3)`` is tied to its nearest exact surface sample of frame
    ``rest_index`` (:func:`nearest_samples`, or ``nearest`` when the caller has it) and takes
    that sample's bone (``syn.surface_labels``); ``registered`` is ``(F, M, 3)``. Returns
    ``(bone name, points, along (F,), across (F,))`` for the bones with at least
    ``min_points`` points, metres.
    """
    nn = nearest_samples(rest, syn, rest_index) if nearest is None else nearest
    lab = syn.surface_labels[nn]
    parents = np.asarray(syn.joint_parents)
    out = []
    for j, name in enumerate(syn.joint_names):
        kids = np.flatnonzero(parents == j)
        m = lab == j
        if len(kids) != 1 or m.sum() < min_points:
            continue
        along, across = axial_offsets(registered[:, m], syn.surface[:, nn[m]],
                                      syn.gt_joints[:, j], syn.gt_joints[:, kids[0]])
        out.append((name, int(m.sum()), along, across))
    return out


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_cache_options(ap)
    ap.add_argument("--frames-of", default="", help="also print this bone's along offsets")
    a = ap.parse_args(argv)
    sequences, only = chosen(ap, a)
    tot_along = tot_corr = 0.0
    print(f"{'sequence':<24} {'corr':>5}  three bones of largest mean |along| "
          "(mean |along| / max |along| / across, cm)")
    for name, syn in suite(a.frames, only, sequences):
        d = cached_inputs(name, syn, Path(a.cache))
        r0 = int(d["rest_index"])
        nn = nearest_samples(d["rest"], syn, r0)
        corr = correspondence(d["regpts"], syn, nn)
        rows = bone_slides(d["rest"], d["regpts"], syn, r0, nearest=nn)
        for _, n, al, ac in rows:
            tot_along += n * float(np.abs(al).mean())
            tot_corr += n * float(np.hypot(al, ac).mean())
        rows.sort(key=lambda r: -float(np.abs(r[2]).mean()))
        cells = [f"{bn} {100 * np.abs(al).mean():.1f}/{100 * np.abs(al).max():.1f}/"
                 f"{100 * ac.mean():.1f}" for bn, _, al, ac in rows[:3]]
        print(f"{name:<24} {100 * corr:5.2f}  " + " | ".join(cells), flush=True)
        for bn, _, al, _ in rows:
            if bn == a.frames_of:
                print(f"  {bn} along, every 4th frame (rest frame {r0}): "
                      + " ".join(f"{100 * x:+.0f}" for x in al[::4]))
    if tot_corr > 0:
        print(f"\nshare of the bones' mean offset (|along|, across) that lies along their axes: "
              f"{tot_along / tot_corr:.2f} (point-weighted, |along| / |offset| of the means)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
