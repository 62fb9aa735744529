"""Where the normalised joint error sits: the joints' rest positions or the bones' motions.

The pipeline's output joint ``k`` moves as ``q_t = A_t c_k + b_t``: its rest position ``c_k``
(metres, rest-frame coordinates) carried by the mean of its two bones' transforms
(:func:`pointrig.kinematics.joint_trajectories`; the root by its own bone). For each matched
ground-truth joint ``g_t``, the normalised error (mean over frames of ``|q_t - g_t|`` after
subtracting the mean offset, :mod:`pointrig.evaluate`) is linear least squares in ``c_k``, so
the rest position that minimises it has a closed form (``numpy.linalg.lstsq`` on the centred
``A_t``). That *oracle* error is what the same motions would score with the best rest joints:

- ``actual - oracle`` is the share of the error in the rest joints (placement);
- ``oracle`` is the share in the motions (tracking), which no joint placement removes.

The oracle's rest positions also absorb part of the motions' errors, so they are not where
the ground-truth joints are. ``gt rest`` scores the ground-truth joints of the rest frame
(``RegistrationResult.params["rest_frame_index"]``) as rest positions under the same motions:
what a perfect geometric placement would give; ``raw`` and ``raw gt rest`` are the raw errors
(mean over frames of ``|q_t - g_t|``) of the pipeline and of that placement.

The same motions also score step 2's joints and the Eq. 20 prior targets ``c~``
(``StructureResult.c_tilde``), the two estimates step 3 starts from. ``|c - c*|`` is the mean
distance of the pipeline's rest joints from the oracle ones, split (root mean square) into
``axis`` (along the joint's bone: from the joint to its bone's rest-point centroid), ``depth``
(along the camera ray, ``StructureResult.view_camera``, the origin if unset) and ``across``
(the rest). Where the motions leave the best rest position undetermined (a joint turning about
one axis or not at all), ``c*`` is the best one nearest ``c``, and the distance leaves out the
directions in which the motion turns less than ``DETERMINED`` (0.1 rad RMS over the frames):
it counts only what the motions determine. All on the joints the evaluation matches
in the pipeline's output (the same matching for every row).

Runs the default pipeline on the sequences of ``bench_refine.py`` (100 frames; a glTF rig
needs ``../shared/data/models``)::

    PYTHONPATH=python python benchmarks/bench_joint_oracle.py                 # ~14 min
    PYTHONPATH=python python benchmarks/bench_joint_oracle.py --only human --frames 40

The oracle uses the ground truth: it is a diagnosis, not a method.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "python"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_refine import selected, suite  # noqa: E402
from bench_registration_downstream import score_joints  # noqa: E402

from pointrig.config import PipelineConfig  # noqa: E402
from pointrig.evaluate import pair_errors  # noqa: E402
from pointrig.kinematics import joint_trajectories  # noqa: E402
from pointrig.pipeline import extract  # noqa: E402


#: directions in which a joint's motion turns less than this (radians, RMS over frames) do
#: not count in ``|c - c*|`` and its parts
DETERMINED = 0.1
#: the keys of :func:`decompose` (besides ``matched``), in the order the table prints them
COLUMNS = ("actual", "oracle", "gt_rest", "step2", "ctilde", "dist", "axis", "depth", "across",
           "raw", "raw_gt_rest")


def joint_maps(R: np.ndarray, T: np.ndarray, bone_parent: np.ndarray) -> tuple[np.ndarray,
                                                                               np.ndarray]:
    """The affine map of each joint's rest position to its trajectory.

    Parameters
    ----------
    R, T
        ``(F, B, 3, 3)``, ``(F, B, 3)`` bone transforms ``T_frame_rest`` (metres).
    bone_parent
        ``(B,)`` parent bone, ``-1`` for the root; joint ``k`` is the head of bone ``k``.

    Returns
    -------
    A, b
        ``(F, B, 3, 3)``, ``(F, B, 3)`` with ``joint_trajectories(c, R, T, bone_parent)[t, k]
        == A[t, k] @ c[k] + b[t, k]``.
    """
    parent = np.asarray(bone_parent)
    p = np.where(parent >= 0, parent, np.arange(len(parent)))
    return 0.5 * (R + R[:, p]), 0.5 * (T + T[:, p])


def oracle_rest_position(A: np.ndarray, b: np.ndarray, g: np.ndarray,
                         start: np.ndarray | None = None,
                         min_turn: float = 0.0) -> np.ndarray:
    """The rest position ``c (3,)`` minimising ``sum_t |(A_t c + b_t - g_t) - mean|^2``.

    ``A (F, 3, 3)``, ``b (F, 3)``, ``g (F, 3)`` (metres). With the mean offset free, only the
    centred ``A_t`` and ``g_t - b_t`` enter. Where ``A`` does not determine ``c`` (a joint
    that turns about one axis or not at all) the minimiser nearest ``start (3,)`` (default
    the origin) is returned: the smallest move of ``start`` that reaches the minimum.
    ``min_turn > 0`` (radians) also leaves at ``start`` the directions in which the motion
    turns less than that (root mean square over frames): singular values of the centred
    ``A`` below ``min_turn * sqrt(F)``."""
    c0 = np.zeros(3) if start is None else np.asarray(start, dtype=np.float64)
    Ac = (A - A.mean(0)).reshape(-1, 3)
    r = (g - b) - np.einsum("fij,j->fi", A, c0)
    y = (r - r.mean(0)).reshape(-1)
    U, sv, Vt = np.linalg.svd(Ac, full_matrices=False)
    keep = sv > max(min_turn * np.sqrt(len(A)), 1e-12 * max(float(sv[0]), 1e-300))
    return c0 + Vt[keep].T @ ((U[:, keep].T @ y) / sv[keep])


def decompose(syn, result) -> dict[str, float]:
    """Normalised errors (m) of the pipeline's joints and of the alternatives, same motions.

    Returns the means over the matched joints: ``actual``, ``oracle``, ``gt_rest``, ``step2``,
    ``ctilde``, and ``dist`` (mean ``|c - c*|``); the RMS components of ``c - c*`` ``axis``,
    ``depth``, ``across``; the raw errors ``raw`` and ``raw_gt_rest``; and ``matched``
    (count). NaN when nothing matched."""
    st, jr = result.structure, result.joints
    reg = result.refined_registration or result.registration
    rest_index = int((reg.params or {}).get("rest_frame_index", 0))
    cam = np.zeros(3) if st.view_camera is None else np.asarray(st.view_camera, dtype=float)
    parent = np.asarray(st.bone_parent)
    traj = joint_trajectories(jr.joints_rest, jr.R, jr.T, parent)
    rep = score_joints(traj, syn)
    A, b = joint_maps(jr.R, jr.T, parent)
    rows = []
    for j, row in enumerate(rep.rows):
        k = row.matched
        if k < 0:
            continue
        g = syn.gt_joints[:, j]
        c_star = oracle_rest_position(A[:, k], b[:, k], g, jr.joints_rest[k])

        def errors(c: np.ndarray) -> tuple[float, float]:
            """(raw, normalised) of joint ``k`` with rest position ``c`` under the motions."""
            return pair_errors(np.einsum("fij,j->fi", A[:, k], c) + b[:, k], g)

        def err(c: np.ndarray) -> float:
            return errors(c)[1]

        c = jr.joints_rest[k]
        # the distance counts only the directions the motions determine well: a joint that
        # barely turns would otherwise move far for a vanishing gain
        d = c - oracle_rest_position(A[:, k], b[:, k], g, c, min_turn=DETERMINED)
        ray = c - cam
        ray /= max(float(np.linalg.norm(ray)), 1e-12)
        axis = st.rest_points[st.labels == k].mean(0) - c if np.any(st.labels == k) else ray
        axis = axis - (axis @ ray) * ray  # orthogonal to the ray, so the parts add up
        axis /= max(float(np.linalg.norm(axis)), 1e-12)
        da, dr = float(d @ axis), float(d @ ray)
        rows.append((err(c), err(c_star), err(g[rest_index]), err(st.joints_rest[k]),
                     err(st.c_tilde[k]), float(np.linalg.norm(d)), da * da, dr * dr,
                     float(d @ d) - da * da - dr * dr, errors(c)[0], errors(g[rest_index])[0]))
    if not rows:
        return {key: float("nan") for key in COLUMNS} | {"matched": 0}
    m = np.mean(rows, axis=0)
    m[6:9] = np.sqrt(np.maximum(m[6:9], 0.0))
    return dict(zip(COLUMNS, (float(v) for v in m))) | {"matched": len(rows)}


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--only", default="", help="comma-separated sequence names")
    a = ap.parse_args(argv)
    only = selected(ap, a.only)
    print("normalised errors (cm) under the pipeline's motions with its rest joints (actual), "
          "the oracle's, the ground truth's at the rest frame, step 2's, c~; |c - c*| and its "
          "axis / depth / across parts; raw errors (cm) of actual and gt rest")
    print(f"{'sequence':<16} {'matched':>7} " + " ".join(f"{c:>11}" for c in COLUMNS)
          + f" {'placement %':>11}")
    table = []
    for name, syn in suite(a.frames, only):
        res = extract(syn.to_point_sequence(), PipelineConfig(), None, pictures=False)
        d = decompose(syn, res)
        if d["matched"] == 0:
            print(f"{name:<16} {0:>7} (no joint matched)")
            continue
        share = 100.0 * (d["actual"] - d["oracle"]) / d["actual"]
        table.append([d[c] for c in COLUMNS] + [share])
        print(f"{name:<16} {d['matched']:>7} " + " ".join(f"{100 * d[c]:>11.2f}" for c in COLUMNS)
              + f" {share:>11.0f}", flush=True)
    if table:
        m = np.mean(table, axis=0)
        print(f"{'mean':<16} {'':>7} " + " ".join(f"{100 * v:>11.2f}" for v in m[:-1])
              + f" {m[-1]:>11.0f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
