"""Why each missed joint is missed: hidden, shared, depth, placement or absent.

The recall counts the scorable true joints that the evaluation's one-to-one matching gives an
output joint closer than the threshold (mean distance over the frames). This benchmark sorts
every *missed* scorable joint into one cause, checked in this order:

* **hidden**: the bone the joint heads is seen on average in less than ``--hidden`` (0.15) of
  its exact surface samples (:func:`bone_visibility`: a sample is seen in a frame when an
  observed point rendered from the same bone lies within 2 cm of it). Its motion is barely in
  the data, so no placement rule can be asked to find it.
* **shared**: the output joint nearest to it is within the threshold but matched to another
  true joint: the skeleton is short of a joint there (two true joints, one output joint).
* **depth**: the nearest output joint with the offsets along the camera ray left out
  (``bench_step3.lateral_costs``, as ``lateral_recall`` measures) is within the threshold:
  depth alone loses it.
* **placement**: none of these, and the nearest output joint is within twice the threshold:
  there is a joint, off across the ray as well.
* **absent**: the nearest output joint is twice the threshold away or more: the skeleton has
  no joint there (a limb end that got no bone of its own, a limb merged into its parent).

On ``bench_step3.py``'s cache (step 3 rerun with the defaults on the cached inputs, as
``bench_step3.py`` scores it)::

    PYTHONPATH=python python benchmarks/bench_misses.py --cache /tmp/step3 --set all

prints each sequence's recall, its misses (true joint, cause, nearest output joint's distance
against the threshold and its offset split along the camera ray and across it
(:func:`ray_offsets`), the bone's visibility) and, per set of sequences (all, human-sized),
the recall gap split by cause and the recall over the joints that are not hidden.
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
from bench_registration_downstream import score_joints  # noqa: E402
from bench_step3 import cached_inputs, human_sized, lateral_costs, step3_skeleton  # noqa: E402

from pointrig.config import JointsConfig, StructureConfig  # noqa: E402
from pointrig.evaluate import match_pairs  # noqa: E402

#: The causes, in the order they are checked.
CAUSES = ("hidden", "shared", "depth", "placement", "absent")


def bone_visibility(frames: list[np.ndarray], point_labels: list[np.ndarray],
                    surface: np.ndarray, surface_labels: np.ndarray, n_bones: int,
                    tol: float = 0.02, min_samples: int = 20) -> np.ndarray:
    """``(F, n_bones)`` fraction of each bone's exact surface samples seen in each frame.

    Parameters
    ----------
    frames
        ``F`` observed clouds ``(N_t, 3)``, metres.
    point_labels
        ``F`` arrays ``(N_t,)``: the bone each observed point was rendered from (``-1`` for
        outliers and background, never matched).
    surface
        ``(F, S, 3)`` exact surface samples (the same material point in every frame), metres.
    surface_labels
        ``(S,)`` bone of each sample.
    n_bones
        Number of bones ``J``.
    tol
        A sample is seen when an observed point of its own bone lies within ``tol`` metres
        (2 cm: the depth noise at 2.3 m is about 0.8 cm; a limb's far side lies further).
    min_samples
        A bone with fewer samples (a rig bone that hardly carries skin) reads nan.

    Samples cover the whole surface, so a limb in full view reads about 0.5-0.9 (its front
    and sides), one behind another part near 0.
    """
    lab = np.asarray(surface_labels)
    out = np.full((len(frames), n_bones), np.nan)
    for t, (X, L) in enumerate(zip(frames, point_labels)):
        for j in range(n_bones):
            s = lab == j
            if s.sum() < min_samples:
                continue
            own = np.asarray(X)[np.asarray(L) == j]
            if len(own) == 0:
                out[t, j] = 0.0
                continue
            d = cKDTree(own).query(surface[t, s], distance_upper_bound=tol)[0]
            out[t, j] = float(np.mean(d <= tol))
    return out


def classify_misses(joint_positions: np.ndarray, gt_joints: np.ndarray,
                    scorable: np.ndarray, threshold: float, visibility: np.ndarray,
                    hidden: float = 0.15) -> list[tuple[int, str, int, float]]:
    """The cause of every missed scorable true joint.

    Parameters
    ----------
    joint_positions
        ``(F, P, 3)`` output joints, metres, in the camera frame (camera at the origin).
    gt_joints
        ``(F, J, 3)`` true joints, metres.
    scorable
        ``(J,)`` bool: the evaluation's scorable joints.
    threshold
        The evaluation's matching threshold, metres.
    visibility
        ``(J,)`` mean fraction of each true joint's own bone seen (:func:`bone_visibility`
        averaged over the frames; nan = no samples, never hidden).
    hidden
        Below this visibility a missed joint is *hidden*.

    Returns
    -------
    list of (int, str, int, float)
        ``(true joint, cause, nearest output joint, its mean distance in metres)`` per missed
        scorable joint, the cause one of :data:`CAUSES`. The matching is the evaluation's
        (:func:`pointrig.evaluate.match_pairs` on the mean distances).
    """
    cols = np.flatnonzero(scorable)
    if not len(cols) or joint_positions.shape[1] == 0:
        return [(int(j), "hidden" if visibility[j] < hidden else "absent", -1,
                 float("inf")) for j in cols]
    g = gt_joints[:, cols]  # (F, Js, 3)
    cost = np.linalg.norm(joint_positions[:, :, None] - g[:, None], axis=3).mean(axis=0)
    lateral = lateral_costs(joint_positions, g)  # (P, Js)
    pairs = match_pairs(cost, threshold)
    owner = {p: c for p, c in pairs}
    matched = {c for _, c in pairs}
    out = []
    for c, j in enumerate(cols):
        if c in matched:
            continue
        k = int(np.argmin(cost[:, c]))
        if visibility[j] < hidden:
            cause = "hidden"
        elif cost[k, c] < threshold and owner.get(k, c) != c:
            cause = "shared"
        elif lateral[:, c].min() < threshold:
            cause = "depth"
        elif cost[k, c] < 2.0 * threshold:
            cause = "placement"
        else:
            cause = "absent"
        out.append((int(j), cause, k, float(cost[k, c])))
    return out


def ray_offsets(joint_positions: np.ndarray, gt_joint: np.ndarray) -> tuple[float, float]:
    """How an output joint is off a true joint, split along the camera ray and across it.

    Parameters
    ----------
    joint_positions
        ``(F, 3)`` one output joint over the frames, metres, camera at the origin.
    gt_joint
        ``(F, 3)`` the true joint, metres.

    Returns
    -------
    (float, float)
        The mean over frames of ``(p - g) . u`` (metres; negative = nearer the camera than the
        truth), ``u`` the unit ray from the camera to ``g``, and the mean of
        ``|(p - g) - ((p - g) . u) u|`` (metres, the offset across the ray).
    """
    u = gt_joint / np.linalg.norm(gt_joint, axis=1, keepdims=True)
    along = np.einsum("fi,fi->f", joint_positions - gt_joint, u)
    across = lateral_costs(joint_positions[:, None], gt_joint[:, None])[0, 0]
    return float(along.mean()), float(across)


def _gap_line(label: str, rows: list[tuple[float, float, dict[str, float]]]) -> str:
    """One summary line: mean recall, the mean gap share of each cause, and the recall over
    the joints that are not hidden."""
    rec = np.mean([r[0] for r in rows])
    shares = {c: np.mean([r[2].get(c, 0.0) for r in rows]) for c in CAUSES}
    seen = np.nanmean([r[1] for r in rows])
    return (f"{label:<28} recall {rec:.3f}  gap {1 - rec:.3f} = "
            + " + ".join(f"{c} {shares[c]:.3f}" for c in CAUSES)
            + f"  | recall without hidden joints {seen:.3f}")


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_cache_options(ap)
    ap.add_argument("--hidden", type=float, default=0.15,
                    help="a missed joint whose bone is seen in less than this fraction of its "
                         "samples is hidden")
    a = ap.parse_args(argv)
    sequences, only = chosen(ap, a)
    rows: list[tuple[float, float, dict[str, float]]] = []
    human: list[tuple[float, float, dict[str, float]]] = []
    for name, syn in suite(a.frames, only, sequences):
        d = cached_inputs(name, syn, Path(a.cache))
        sk, _ = step3_skeleton(d, d["structure"], JointsConfig(), StructureConfig())
        r = score_joints(sk.joint_positions, syn)
        seen_t = bone_visibility(syn.frames, syn.point_labels, syn.surface,
                                 syn.surface_labels, len(syn.joint_names))
        vis = np.full(len(syn.joint_names), np.nan)
        has = ~np.isnan(seen_t).all(axis=0)
        vis[has] = seen_t[:, has].mean(axis=0)
        misses = classify_misses(sk.joint_positions, syn.gt_joints, np.asarray(r.scorable),
                                 r.threshold, vis, a.hidden)
        n_sc = int(np.sum(r.scorable))
        share = {c: sum(m[1] == c for m in misses) / max(n_sc, 1) for c in CAUSES}
        # the recall over the scorable joints that are not hidden (nan visibility = seen)
        seen_rows = [row for i, row in enumerate(r.rows) if row.scorable
                     and not vis[i] < a.hidden]
        seen = (sum(row.matched >= 0 for row in seen_rows) / len(seen_rows) if seen_rows
                else float("nan"))
        row = (float(r.recall), float(seen), share)
        rows.append(row)
        if human_sized(r.subject_size):
            human.append(row)
        cells = []
        for j, cause, k, dist in misses:
            along, across = (ray_offsets(sk.joint_positions[:, k], syn.gt_joints[:, j])
                             if k >= 0 else (float("nan"), float("nan")))
            cells.append(f"{syn.joint_names[j]} {cause} (j{k} {100 * dist:.1f} cm: along ray "
                         f"{100 * along:+.1f}, across {100 * across:.1f}; seen {vis[j]:.2f})")
        print(f"{name:<24} recall {r.recall:.2f} thr {100 * r.threshold:4.1f} cm: "
              + ("; ".join(cells) if cells else "no miss"), flush=True)
    if rows:
        print()
        print(_gap_line(f"all ({len(rows)})", rows))
        if human:
            print(_gap_line(f"human-sized ({len(human)})", human))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
