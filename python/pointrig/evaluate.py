"""Scoring an extracted skeleton against ground-truth joints (paper §7.3.3).

Rules (also in the README):

**Subject size** ``s``: the median over frames of the bounding-box diagonal of the
ground-truth surface samples (``gt.npz`` ``surface``), or of the skinned ground-truth joints
when no surface is given.

**Scorable ground-truth joints** (all three must hold):

1. *carries skin*: the joint's bone dominates some skin (``skinned`` in ``gt.npz``; joints
   without skin, such as IK targets or sockets in glTF rigs, are not scored);
2. *visibly articulates* (non-root joints): the joint's part swings relative to its parent
   part by more than ``swing_fraction * s`` (default 1.5 %): the child part's samples are
   mapped back to frame 0 through the parent's motion, and the swing is the largest RMS
   displacement over the frames. The parent is the nearest ancestor carrying at least 3
   samples. Two ways to get the motions (``swing_source``):

   * ``"bones"`` (default whenever the ground truth has its bone transforms, as every
     ``pointrig synth`` gt.npz does): the rig's own transforms ``T_frame_rest`` of the child
     and the parent bone applied to the child part's rest samples; with no skinned ancestor,
     the top bone of the chain (a rig's root moves in the world without skin). This is the
     articulation of the rig itself;
   * ``"surface"`` (the older rule; the fallback without bone transforms): the parent part's
     surface samples give a rigid motion per frame (Kabsch), the world frame if no ancestor
     carries samples. On smoothly skinned rigs this measures skin blending, not articulation:
     it scores joints that never turn against their parent (girl's Neck, 0.0 deg; a glTF arm
     bone rigid to its parent), which no method can find from motion;

   Root joints (parent -1) pass this test. Without surface samples it is skipped;
3. *not a near-duplicate*: if two joints still scorable stay within ``duplicate_fraction * s``
   (default 2 %) of each other on average over the frames, only the one nearer the root (then
   the lower index) is scored.

**Matching**: predicted joints are matched one-to-one to scorable ground-truth joints by the
Hungarian method on the mean distance over frames; pairs whose mean distance is at or above the
threshold ``tau = threshold_fraction * s`` (default 8 %, e.g. ~15 cm for a 1.8 m human, ~6 cm
for a single arm) are forbidden, so the matching maximises the number of valid pairs, then
minimises their total distance.

**Scores**: recall = matched / scorable GT joints; precision = matched / predicted joints;
raw error = mean over matched pairs of the mean over frames of ``|p_t - g_t|``; normalised
error (Helten et al. 2013, as in §7.3.3) = the same after subtracting each pair's mean offset
``mean_t (p_t - g_t)`` from the prediction. Errors are in metres.

**Far joints** (a diagnostic; it changes no score): a predicted joint is *far* when its mean
distance over the frames to EVERY ground-truth joint, scored or not (IK targets, sockets and
static joints included), is at least ``far_fraction * s`` (default 10 %). Such a joint stands
where the source rig has no joint at all; ``EvalReport.far_fraction`` is their share of the
predicted joints.

**Duplicates and near misses** (diagnostics; they change no score): an unmatched predicted
joint is a *duplicate* when it lies within the threshold of a scorable joint that another
predicted joint matched (two joints where the rig has one); a scorable joint left unmatched is a
*near miss* when an unmatched predicted joint whose nearest scorable joint it is lies within
``near_miss_factor`` (default 1.5) times the threshold (found, but placed too far: 8-12 % of the
size by default; a predicted joint matched elsewhere or nearer another joint, such as the missed
joint's parent or a duplicate of it, does not count). They tell a loss of precision by extra
joints at real joints, and a loss of recall by placement, from the rest.

**Pivot error** (a diagnostic; it changes no score): with the rig's bone transforms, each
joint's distance from where its part turns against its reference part (:func:`pivot_errors`).
A rig may put a joint away from that point: at the end of a skinless bone that holds the part
(greenman's legs hang 54 cm below skinless hip bones) or on a bone animated by translation
(greenman's hands slide up to 88 cm against the body in its attack). A scorable joint whose
pivot error reaches the threshold is *off pivot* (``EvalReport.n_off_pivot``, the table's
note): a skeleton whose joints are where its parts turn, as the paper's and ours are, matches
it only through an error of its own.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .errors import ConfigError, InputError

__all__ = ["EvalReport", "JointRow", "evaluate", "evaluate_files", "match_pairs", "pair_errors",
           "normalized_offsets", "pivot_errors", "scorable_joints", "far_joints",
           "subject_size", "load_prediction", "SWING_FRACTION", "DUPLICATE_FRACTION",
           "THRESHOLD_FRACTION", "SWING_SOURCES", "FAR_FRACTION", "NEAR_MISS_FACTOR"]

#: Matching threshold as a fraction of the subject size.
THRESHOLD_FRACTION = 0.08
#: Minimum swing of a part relative to its parent part, fraction of the subject size.
SWING_FRACTION = 0.015
#: Joints closer than this fraction of the subject size (mean over frames) are duplicates.
DUPLICATE_FRACTION = 0.02
#: A predicted joint at least this fraction of the subject size (mean over frames) from every
#: ground-truth joint is far (module docstring).
FAR_FRACTION = 0.10
#: An unmatched scorable joint with a predicted joint within this times the threshold is a
#: near miss (a diagnostic).
NEAR_MISS_FACTOR = 1.5
#: Minimum surface samples for a part to define a rigid motion.
MIN_PART_SAMPLES = 3


@dataclass
class JointRow:
    """One ground-truth joint in the report."""

    name: str
    scorable: bool
    reason: str  # "ok", "no skin", "static (swing x m)", "duplicate of NAME"
    matched: int  # predicted joint index, -1 if unmatched
    raw_error: float  # metres, nan if unmatched
    normalized_error: float  # metres, nan if unmatched
    swing: float  # metres (nan if not measured)
    #: metres: the raw error of a joint at the point about which this joint's part turns
    #: against its parent part (exact motion; :func:`pivot_errors`); nan if not measured
    pivot_error: float = float("nan")


@dataclass
class EvalReport:
    """Scores of one prediction against ground truth (see the module docstring)."""

    recall: float
    precision: float
    raw_error: float
    normalized_error: float
    threshold: float
    subject_size: float
    n_pred: int
    n_gt: int
    n_scorable: int
    n_matched: int
    n_frames: int
    scorable: np.ndarray
    rows: list[JointRow] = field(default_factory=list)
    pred_names: list[str] = field(default_factory=list)
    #: how the articulation test got its motions: "bones", "surface" or "" (no surface)
    swing_source: str = ""
    #: ``(P,)`` bool: predicted joints far from every ground-truth joint (:func:`far_joints`)
    far: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    #: the distance that makes a predicted joint far, metres
    far_distance: float = float("nan")
    #: ``(P,)`` bool: unmatched predicted joints within the threshold of a scorable joint
    #: another predicted joint matched (module docstring)
    duplicate: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    #: ``(J,)`` bool: unmatched scorable joints nearest to an unmatched predicted joint within
    #: ``near_miss_factor`` times the threshold (module docstring)
    near_miss: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))

    @property
    def n_duplicate(self) -> int:
        """Number of :attr:`duplicate` predicted joints."""
        return int(np.sum(self.duplicate))

    @property
    def n_near_miss(self) -> int:
        """Number of :attr:`near_miss` scorable joints."""
        return int(np.sum(self.near_miss))

    @property
    def n_far(self) -> int:
        """Number of predicted joints far from every ground-truth joint."""
        return int(np.sum(self.far))

    @property
    def far_fraction(self) -> float:
        """Share of the predicted joints far from every ground-truth joint (nan without
        predictions)."""
        return self.n_far / self.n_pred if self.n_pred else float("nan")

    @property
    def off_pivot(self) -> np.ndarray:
        """``(J,)`` bool: scorable joints whose pivot error (:func:`pivot_errors`) is at or
        above the threshold; the rig puts them where no joint at a pivot of the rig's own
        parts can match them."""
        return np.array([r.scorable and r.pivot_error >= self.threshold for r in self.rows],
                        dtype=bool)

    @property
    def n_off_pivot(self) -> int:
        """Number of :attr:`off_pivot` joints."""
        return int(self.off_pivot.sum())

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (NaN -> None)."""

        def clean(v):
            if isinstance(v, float) and not np.isfinite(v):
                return None
            return v

        d = {k: clean(getattr(self, k)) for k in (
            "recall", "precision", "raw_error", "normalized_error", "threshold", "subject_size",
            "n_pred", "n_gt", "n_scorable", "n_matched", "n_frames", "swing_source",
            "n_off_pivot", "n_far", "far_fraction", "far_distance", "n_duplicate",
            "n_near_miss")}
        d["joints"] = [{k: clean(v) for k, v in dataclasses.asdict(r).items()} for r in self.rows]
        for j in d["joints"]:
            m = j["matched"]
            j["matched_name"] = self.pred_names[m] if 0 <= m < len(self.pred_names) else None
        return d

    def format_table(self) -> str:
        """Human-readable summary and per-joint table."""
        cm = 100.0
        lines = [
            f"frames {self.n_frames}   predicted joints {self.n_pred}   GT joints {self.n_gt} "
            f"({self.n_scorable} scorable)",
            f"subject size {self.subject_size:.3f} m   match threshold {self.threshold:.3f} m"
            + (f"   articulation from {self.swing_source}" if self.swing_source else ""),
            f"recall     {self.recall:.3f}  ({self.n_matched}/{self.n_scorable})"
            + (f"   off-pivot joints {self.n_off_pivot}" if self.n_off_pivot else ""),
            f"precision  {self.precision:.3f}  ({self.n_matched}/{self.n_pred})"
            f"   duplicates {self.n_duplicate}   near misses {self.n_near_miss}",
            (f"far joints {self.n_far}/{self.n_pred}  (>= {self.far_distance:.3f} m from "
             "every ground-truth joint)"),
            f"raw error         {self.raw_error * cm:7.2f} cm",
            f"normalised error  {self.normalized_error * cm:7.2f} cm",
            "",
            f"{'joint':<18} {'scored':<7} {'matched':<14} {'raw cm':>8} {'norm cm':>8}  note",
        ]
        for r, off in zip(self.rows, self.off_pivot):
            mname = (self.pred_names[r.matched] if 0 <= r.matched < len(self.pred_names)
                     else "-")
            raw = f"{r.raw_error * cm:8.2f}" if np.isfinite(r.raw_error) else f"{'-':>8}"
            nrm = (f"{r.normalized_error * cm:8.2f}" if np.isfinite(r.normalized_error)
                   else f"{'-':>8}")
            note = "" if r.reason == "ok" else r.reason
            if off:
                note = f"off pivot ({r.pivot_error * cm:.1f} cm)"
            lines.append(f"{r.name[:18]:<18} {('yes' if r.scorable else 'no'):<7} "
                         f"{mname[:14]:<14} {raw} {nrm}  {note}")
        return "\n".join(lines)


def _check_joints(arr: Any, what: str, path: str | Path | None) -> np.ndarray:
    try:
        a = np.asarray(arr, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{what}: not a numeric array ({exc})", path) from None
    if a.ndim != 3 or a.shape[2] != 3:
        raise InputError(f"{what}: expected joint positions of shape (F, J, 3), got "
                         f"{a.shape}", path)
    if a.shape[0] == 0 or a.shape[1] == 0:
        raise InputError(f"{what}: no frames or no joints (shape {a.shape})", path)
    bad = ~np.isfinite(a)
    if bad.any():
        f = int(np.argwhere(bad)[0][0])
        raise InputError(f"{what}: {int(bad.any(axis=2).sum())} joint position(s) with NaN/inf",
                         path, frame=f)
    return a


def subject_size(gt_joints: np.ndarray, surface: np.ndarray | None = None,
                 skinned: np.ndarray | None = None) -> float:
    """The subject size ``s`` in metres (see the module docstring)."""
    if surface is not None and np.asarray(surface).size:
        pts = np.asarray(surface, dtype=np.float64)
    else:
        pts = np.asarray(gt_joints, dtype=np.float64)
        if skinned is not None and np.asarray(skinned).any():
            pts = pts[:, np.asarray(skinned, dtype=bool)]
    diag = np.linalg.norm(pts.max(axis=1) - pts.min(axis=1), axis=1)
    return float(np.median(diag))


def _kabsch_batch(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rigid motions ``dst_t ~ R_t src + T_t``: ``src (M, 3)``, ``dst (F, M, 3)`` ->
    ``R (F, 3, 3)``, ``T (F, 3)``."""
    cs = src.mean(axis=0)
    cd = dst.mean(axis=1)
    H = np.einsum("mi,fmj->fij", src - cs, dst - cd[:, None])
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(np.einsum("fij,fjk->fik", U, Vt)))
    D = np.zeros((len(d), 3, 3))
    D[:, 0, 0] = 1
    D[:, 1, 1] = 1
    D[:, 2, 2] = d
    R = np.einsum("fji,fjk,flk->fil", Vt, D, U)  # V D U^T
    T = cd - np.einsum("fij,j->fi", R, cs)
    return R, T


def _swing_references(parents: np.ndarray, labels: np.ndarray) -> list[tuple[int, int, int]]:
    """``(j, a, top)`` for every non-root joint ``j`` with samples: ``a`` is its nearest
    ancestor carrying at least ``MIN_PART_SAMPLES`` samples (``-1`` if none), ``top`` the last
    ancestor passed on the way (the chain's top bone when ``a`` is ``-1``)."""
    J = len(parents)
    counts = np.bincount(labels[labels >= 0], minlength=J)[:J]
    out = []
    for j in range(J):
        if parents[j] < 0 or counts[j] < 1:
            continue
        a = top = int(parents[j])
        while a >= 0 and counts[a] < MIN_PART_SAMPLES:
            top = a
            a = int(parents[a])
        out.append((j, a, top))
    return out


def _max_rms_drift(back: np.ndarray, start: np.ndarray) -> float:
    """Largest over frames of the RMS distance of ``back (F, m, 3)`` from ``start (m, 3)``."""
    return float(np.sqrt(((back - start) ** 2).sum(axis=2).mean(axis=1)).max())


def _swings(parents: np.ndarray, surface: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """Swing of each joint's part against a Kabsch fit of its parent part's samples
    (``surface (F, S, 3)``), or against the world when no ancestor carries samples."""
    out = np.full(len(parents), np.nan)
    for j, a, _top in _swing_references(parents, labels):
        child = surface[:, labels == j]  # (F, m, 3)
        if a < 0:
            back = child
        else:
            par = surface[:, labels == a]
            R, T = _kabsch_batch(par[0], par)
            back = np.einsum("fji,fmj->fmi", R, child - T[:, None])  # R^T (x - T)
        out[j] = _max_rms_drift(back, child[0])
    return out


def _swings_from_bones(parents: np.ndarray, rotations: np.ndarray, translations: np.ndarray,
                       rest_surface: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """Swing of each joint's part against its parent from the rig's bone transforms.

    ``rotations (F, J, 3, 3)``, ``translations (F, J, 3)``: ``T_frame_rest`` of each bone (the
    3x3 part may carry scale); ``rest_surface (S, 3)`` and ``labels (S,)``: the samples in the
    rest pose and their dominant joint. The reference is the nearest ancestor carrying
    samples, else the chain's top bone. The child's samples are carried back through the
    reference's motion to the reference's first-frame pose, so the swing is in world metres
    even when the rest space has another unit (a centimetre armature under a 0.01 scale).
    Returns ``(J,)`` metres, ``nan`` for roots and joints without samples.
    """
    out = np.full(len(parents), np.nan)
    for j, a, top in _swing_references(parents, labels):
        ref = a if a >= 0 else top
        q = rest_surface[labels == j]  # (m, 3)
        x = np.einsum("fij,mj->fmi", rotations[:, j], q) + translations[:, j, None]
        # the exact inverse, not the transpose: a rig's bone matrices may carry scale
        local = np.einsum("fij,fmj->fmi", np.linalg.inv(rotations[:, ref]),
                          x - translations[:, ref, None])
        back = np.einsum("ij,fmj->fmi", rotations[0, ref], local) + translations[0, ref]
        out[j] = _max_rms_drift(back, back[0])
    return out


def pivot_errors(gt_joints: np.ndarray, gt_parents: np.ndarray, bone_rotations: np.ndarray,
                 bone_translations: np.ndarray, surface_labels: np.ndarray) -> np.ndarray:
    """How far each ground-truth joint lies from where its part turns against its parent part.

    An articulated skeleton puts a joint where two parts turn about each other (Eq. 20 of the
    paper). A rig need not: a bone may hang from a skinless bone that holds it away from the
    turning point (a cartoon's leg whose head sits at the end of a skinless hip bone), or be
    animated by translation (a hand that slides against the body). For joint ``j`` and its
    reference part ``a`` (the nearest ancestor carrying samples, else the chain's top bone, as
    for the articulation test), the pivot ``c`` minimises ``sum_t |M_a^t c - M_j^t c|^2`` over
    the rig's own bone transforms ``M^t = (R^t, T^t)`` (``T_frame_rest``), with a vanishing
    pull (1e-9 of the system's scale) towards the joint's rest position that picks, on a
    hinge's axis, the point nearest the joint. The pivot error is the mean over frames of
    ``|(M_a^t c + M_j^t c) / 2 - g_t|``: the raw error of a joint at the pivot of the exact
    motion, placed as :func:`pointrig.kinematics.joint_trajectories` places it. About 0 for a
    joint at its part's turning point; where it reaches the matching threshold, a joint at the
    pivot cannot match, and the rig's joint is matched only by an error of the prediction.

    Parameters
    ----------
    gt_joints
        ``(F, J, 3)`` metres.
    gt_parents
        ``(J,)`` parents, ``-1`` for roots.
    bone_rotations, bone_translations
        ``(F, J, 3, 3)`` and ``(F, J, 3)``: ``T_frame_rest`` of each bone (the 3x3 part may
        carry scale).
    surface_labels
        ``(S,)`` dominant joint of each surface sample (which parts carry samples).

    Returns
    -------
    numpy.ndarray
        ``(J,)`` metres; ``nan`` for roots and joints without samples.
    """
    g = np.asarray(gt_joints, dtype=np.float64)
    parents = np.asarray(gt_parents, dtype=np.int64).reshape(-1)
    Rb = np.asarray(bone_rotations, dtype=np.float64)
    Tb = np.asarray(bone_translations, dtype=np.float64)
    out = np.full(len(parents), np.nan)
    for j, a, top in _swing_references(parents, np.asarray(surface_labels, dtype=np.int64)):
        ref = a if a >= 0 else top
        A = Rb[:, ref] - Rb[:, j]  # (F, 3, 3)
        b = Tb[:, ref] - Tb[:, j]  # (F, 3)
        N = np.einsum("fki,fkl->il", A, A)
        lam = 1e-9 * max(float(np.trace(N)), 1e-12)
        try:
            # the joint's rest position: carried back from frame 0 by its own bone
            g0 = np.linalg.solve(Rb[0, j], g[0, j] - Tb[0, j])
            c = np.linalg.solve(N + lam * np.eye(3), lam * g0 - np.einsum("fki,fk->i", A, b))
        except np.linalg.LinAlgError:  # a degenerate (zero-scale) bone matrix
            continue
        x = 0.5 * (np.einsum("fij,j->fi", Rb[:, ref] + Rb[:, j], c) + Tb[:, ref] + Tb[:, j])
        out[j] = float(np.linalg.norm(x - g[:, j], axis=1).mean())
    return out


def _depths(parents: np.ndarray) -> np.ndarray:
    d = np.zeros(len(parents), dtype=np.int64)
    for j in range(len(parents)):
        k, n = j, 0
        while parents[k] >= 0 and n <= len(parents):
            k = int(parents[k])
            n += 1
        d[j] = n
    return d


SWING_SOURCES = ("auto", "bones", "surface")


def _swing_source(source: str, rotations: Any, translations: Any, rest_surface: Any) -> str:
    """Resolve ``swing_source`` (``"auto"`` -> ``"bones"`` if the transforms are given)."""
    if source not in SWING_SOURCES:
        raise ConfigError(f"swing_source must be one of {SWING_SOURCES}, got {source!r}")
    have = rotations is not None and translations is not None and rest_surface is not None
    if source == "bones" and not have:
        raise InputError("swing_source 'bones' needs the ground truth's bone_rotations, "
                         "bone_translations and rest_surface")
    if source == "auto":
        return "bones" if have else "surface"
    return source


def _check_bones(rotations: Any, translations: Any, rest_surface: Any, F: int, J: int, S: int,
                 path: str | Path | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The ground truth's bone transforms and rest samples as float arrays of the shapes
    ``(F, J, 3, 3)``, ``(F, J, 3)``, ``(S, 3)``, or an InputError naming ``path``."""
    Rb = np.asarray(rotations, dtype=np.float64)
    Tb = np.asarray(translations, dtype=np.float64)
    q = np.asarray(rest_surface, dtype=np.float64)
    if Rb.shape != (F, J, 3, 3) or Tb.shape != (F, J, 3) or q.shape != (S, 3):
        raise InputError(f"ground-truth bone_rotations {Rb.shape}, bone_translations "
                         f"{Tb.shape} and rest_surface {q.shape} do not match {F} frames, "
                         f"{J} joints and {S} surface samples", path)
    for name, a in (("bone_rotations", Rb), ("bone_translations", Tb), ("rest_surface", q)):
        if not np.isfinite(a).all():
            raise InputError(f"ground-truth {name} holds NaN/inf", path)
    return Rb, Tb, q


def scorable_joints(gt_joints: np.ndarray, gt_parents: np.ndarray, *,
                    surface: np.ndarray | None = None,
                    surface_labels: np.ndarray | None = None,
                    skinned: np.ndarray | None = None,
                    names: list[str] | None = None,
                    size: float | None = None,
                    swing_fraction: float = SWING_FRACTION,
                    duplicate_fraction: float = DUPLICATE_FRACTION,
                    bone_rotations: np.ndarray | None = None,
                    bone_translations: np.ndarray | None = None,
                    rest_surface: np.ndarray | None = None,
                    swing_source: str = "auto",
                    gt_source: str | Path | None = None,
                    ) -> tuple[np.ndarray, list[str], np.ndarray]:
    """Which ground-truth joints are scored (rules in the module docstring).

    Parameters
    ----------
    gt_joints
        ``(F, J, 3)`` metres.
    gt_parents
        ``(J,)`` parent index, ``-1`` for roots.
    surface, surface_labels
        Optional ``(F, S, 3)`` surface samples (same material points over frames) and their
        dominant joint ``(S,)``; needed for the articulation test.
    skinned
        Optional ``(J,)`` bool; default: joints dominating some surface sample (all joints if
        no surface).
    names
        Joint names for the reasons (default ``j<i>``).
    size
        Subject size (default :func:`subject_size`).
    bone_rotations, bone_translations, rest_surface
        Optional ground-truth bone transforms ``T_frame_rest`` ``(F, J, 3, 3)``, ``(F, J, 3)``
        (metres) and the samples in the rest pose ``(S, 3)``, for the ``"bones"`` swing.
    swing_source
        ``"auto"`` (``"bones"`` when the transforms and rest samples are given, else
        ``"surface"``), ``"bones"`` or ``"surface"`` (module docstring, rule 2).
    gt_source
        The ground-truth file, named in error messages.

    Returns
    -------
    mask
        ``(J,)`` bool.
    reasons
        ``J`` strings: ``"ok"`` or why the joint is not scored.
    swing
        ``(J,)`` metres, ``nan`` where not measured.
    """
    g = np.asarray(gt_joints, dtype=np.float64)
    parents = np.asarray(gt_parents, dtype=np.int64).reshape(-1)
    J = g.shape[1]
    names = names or [f"j{i}" for i in range(J)]
    have_surface = surface is not None and surface_labels is not None and \
        np.asarray(surface).size > 0
    if skinned is None:
        if have_surface:
            lab = np.asarray(surface_labels, dtype=np.int64)
            skinned = np.bincount(lab[lab >= 0], minlength=J)[:J] > 0
        else:
            skinned = np.ones(J, dtype=bool)
    skinned = np.asarray(skinned, dtype=bool).reshape(-1)
    s = subject_size(g, surface if have_surface else None, skinned) if size is None else size
    mask = skinned.copy()
    reasons = ["ok" if k else "no skin" for k in skinned]
    swing = np.full(J, np.nan)
    source = _swing_source(swing_source, bone_rotations, bone_translations, rest_surface)
    if have_surface and source == "bones":
        lab = np.asarray(surface_labels, dtype=np.int64)
        Rb, Tb, q = _check_bones(bone_rotations, bone_translations, rest_surface, g.shape[0], J,
                                 len(lab), gt_source)
        swing = _swings_from_bones(parents, Rb, Tb, q, lab)
    elif have_surface:
        swing = _swings(parents, np.asarray(surface, dtype=np.float64),
                        np.asarray(surface_labels, dtype=np.int64))
    if have_surface:
        for j in range(J):
            if mask[j] and parents[j] >= 0 and not swing[j] > swing_fraction * s:
                mask[j] = False
                reasons[j] = f"static (swing {swing[j] * 100:.1f} cm)" if np.isfinite(
                    swing[j]) else "static (no samples)"
    depth = _depths(parents)
    order = sorted(np.nonzero(mask)[0], key=lambda j: (depth[j], j))
    kept: list[int] = []
    for j in order:
        dup = [k for k in kept
               if np.linalg.norm(g[:, j] - g[:, k], axis=1).mean() < duplicate_fraction * s]
        if dup:
            mask[j] = False
            reasons[j] = f"duplicate of {names[dup[0]]}"
        else:
            kept.append(j)
    return mask, reasons, swing


def far_joints(pred_joints: np.ndarray, gt_joints: np.ndarray, distance: float) -> np.ndarray:
    """Which predicted joints are far from every ground-truth joint.

    Parameters
    ----------
    pred_joints
        ``(F, P, 3)`` predicted joint positions, metres.
    gt_joints
        ``(F, J, 3)`` ground-truth joints, all of them (scored or not), metres.
    distance
        Metres: a predicted joint whose mean distance over the frames to every ground-truth
        joint is at least this is far.

    Returns
    -------
    numpy.ndarray
        ``(P,)`` bool.
    """
    p = np.asarray(pred_joints, dtype=np.float64)
    g = np.asarray(gt_joints, dtype=np.float64)
    if p.shape[1] == 0:
        return np.zeros(0, dtype=bool)
    if g.shape[1] == 0:
        return np.ones(p.shape[1], dtype=bool)
    mean = np.linalg.norm(p[:, :, None, :] - g[:, None, :, :], axis=3).mean(axis=0)  # (P, J)
    return mean.min(axis=1) >= distance


def match_pairs(cost: np.ndarray, threshold: float) -> list[tuple[int, int]]:
    """The evaluation's matching: the one-to-one assignment of predictions to true joints with
    the least total cost among pairs cheaper than ``threshold``.

    Parameters
    ----------
    cost
        ``(P, J)`` cost of each prediction / true-joint pair (the mean distance over the
        frames, metres).
    threshold
        Pairs at or above it never match (metres).

    Returns
    -------
    list of (int, int)
        ``(prediction, true joint)`` index pairs, each cheaper than ``threshold``.
    """
    from scipy.optimize import linear_sum_assignment

    cost = np.asarray(cost, dtype=np.float64)
    if cost.size == 0:
        return []
    gated = np.where(cost < threshold, cost, 1e6 * (1.0 + float(np.max(cost))))
    ri, ci = linear_sum_assignment(gated)
    return [(int(a), int(b)) for a, b in zip(ri, ci) if cost[a, b] < threshold]


def normalized_offsets(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """``(F,)`` metres: each frame's ``|(p_t - g_t) - mean_s (p_s - g_s)|`` for one matched pair
    of trajectories ``pred``, ``gt`` ``(F, 3)`` (metres); their mean over the frames is the
    pair's normalised error (:func:`pair_errors`)."""
    diff = np.asarray(pred, dtype=np.float64) - np.asarray(gt, dtype=np.float64)
    return np.linalg.norm(diff - diff.mean(axis=0), axis=1)


def pair_errors(pred: np.ndarray, gt: np.ndarray) -> tuple[float, float]:
    """Raw and normalised error (metres) of one matched pair of trajectories.

    ``pred``, ``gt``: ``(F, 3)`` metres. Raw = mean over frames of ``|p_t - g_t|``; normalised
    = the same after subtracting the pair's mean offset ``mean_t (p_t - g_t)`` (module
    docstring, :func:`normalized_offsets`)."""
    diff = np.asarray(pred, dtype=np.float64) - np.asarray(gt, dtype=np.float64)
    return (float(np.linalg.norm(diff, axis=1).mean()),
            float(normalized_offsets(pred, gt).mean()))


def evaluate(pred_joints: np.ndarray, gt_joints: np.ndarray, gt_parents: np.ndarray, *,
             gt_names: list[str] | None = None, pred_names: list[str] | None = None,
             surface: np.ndarray | None = None, surface_labels: np.ndarray | None = None,
             skinned: np.ndarray | None = None, threshold: float | None = None,
             threshold_fraction: float = THRESHOLD_FRACTION,
             swing_fraction: float = SWING_FRACTION,
             duplicate_fraction: float = DUPLICATE_FRACTION,
             pred_source: str | Path | None = None,
             gt_source: str | Path | None = None,
             bone_rotations: np.ndarray | None = None,
             bone_translations: np.ndarray | None = None,
             rest_surface: np.ndarray | None = None,
             swing_source: str = "auto",
             far_fraction: float = FAR_FRACTION,
             near_miss_factor: float = NEAR_MISS_FACTOR) -> EvalReport:
    """Score predicted joint trajectories against ground truth.

    Parameters
    ----------
    pred_joints
        ``(F, P, 3)`` predicted joint positions, metres, same frames and frame as the GT.
    gt_joints
        ``(F, J, 3)`` ground-truth joints, metres.
    gt_parents
        ``(J,)`` parents, ``-1`` for roots.
    gt_names, pred_names
        Optional joint names.
    surface, surface_labels, skinned
        Optional ground-truth surface samples ``(F, S, 3)``, their labels ``(S,)`` and the
        skinned mask ``(J,)`` for the scorable-joint rules.
    threshold
        Absolute matching threshold in metres (default ``threshold_fraction`` * subject size).
    bone_rotations, bone_translations, rest_surface, swing_source
        Optional ground-truth bone transforms and rest samples for the articulation test,
        and which motions it uses (:func:`scorable_joints`).
    far_fraction
        A predicted joint this fraction of the subject size or more from every ground-truth
        joint is far (:func:`far_joints`; it changes no score).
    near_miss_factor
        An unmatched scorable joint with a predicted joint within this times the threshold
        is a near miss (a diagnostic, as the duplicates; module docstring).
    pred_source, gt_source
        File names used in error messages.

    Returns
    -------
    EvalReport

    Raises
    ------
    InputError
        Malformed predictions or ground truth (wrong shape, NaN, frame-count mismatch).
    """
    g = _check_joints(gt_joints, "ground truth", gt_source)
    p = _check_joints(pred_joints, "prediction", pred_source)
    if p.shape[0] != g.shape[0]:
        raise InputError(f"prediction has {p.shape[0]} frames but the ground truth has "
                         f"{g.shape[0]} (use the same frame range)", pred_source)
    F, J = g.shape[:2]
    P = p.shape[1]
    gt_names = list(gt_names) if gt_names is not None else [f"j{i}" for i in range(J)]
    pred_names = list(pred_names) if pred_names is not None else [f"p{i}" for i in range(P)]
    parents = np.asarray(gt_parents, dtype=np.int64).reshape(-1)
    if parents.shape != (J,):
        raise InputError(f"ground truth parents must have {J} entries, got {parents.shape}",
                         gt_source)
    have_surface = surface is not None and surface_labels is not None
    source = _swing_source(swing_source, bone_rotations, bone_translations, rest_surface)
    s = subject_size(g, surface if have_surface else None, skinned)
    mask, reasons, swing = scorable_joints(
        g, parents, surface=surface, surface_labels=surface_labels, skinned=skinned,
        names=gt_names, size=s, swing_fraction=swing_fraction,
        duplicate_fraction=duplicate_fraction, bone_rotations=bone_rotations,
        bone_translations=bone_translations, rest_surface=rest_surface,
        swing_source=source, gt_source=gt_source)
    tau = float(threshold) if threshold is not None else threshold_fraction * s
    cols = np.nonzero(mask)[0]
    dist = np.linalg.norm(p[:, :, None, :] - g[:, None, cols, :], axis=3)  # (F, P, Js)
    cost = dist.mean(axis=0)
    matched = np.full(J, -1, dtype=np.int64)
    raw = np.full(J, np.nan)
    norm = np.full(J, np.nan)
    for a, b in match_pairs(cost, tau):
        j = int(cols[b])
        matched[j] = a
        raw[j], norm[j] = pair_errors(p[:, a], g[:, j])
    n_match = int((matched >= 0).sum())
    n_sc = int(mask.sum())
    pivot = np.full(J, np.nan)
    if have_surface and source == "bones":
        pivot = pivot_errors(g, parents, bone_rotations, bone_translations, surface_labels)
    # diagnostics: unmatched predictions at a joint another one matched; unmatched scorable
    # joints whose own (nearest) unmatched prediction lies just beyond the threshold
    taken = np.isin(np.arange(P), matched[matched >= 0])
    col_matched = matched[cols] >= 0
    duplicate = ~taken & ((cost < tau) & col_matched[None, :]).any(axis=1)
    near_miss = np.zeros(J, dtype=bool)
    if cols.size:
        # a prediction no joint matched stands for the scorable joint nearest to it
        free = np.flatnonzero(~taken)
        own = cost[free].argmin(axis=1)
        hit = ~col_matched[own] & (cost[free, own] < near_miss_factor * tau)
        near_miss[cols[own[hit]]] = True
    rows = [JointRow(gt_names[j], bool(mask[j]), reasons[j], int(matched[j]), float(raw[j]),
                     float(norm[j]), float(swing[j]), float(pivot[j])) for j in range(J)]
    return EvalReport(
        recall=n_match / n_sc if n_sc else float("nan"),
        precision=n_match / P,
        raw_error=float(np.nanmean(raw)) if n_match else float("nan"),
        normalized_error=float(np.nanmean(norm)) if n_match else float("nan"),
        threshold=tau, subject_size=s, n_pred=P, n_gt=J, n_scorable=n_sc, n_matched=n_match,
        n_frames=F, scorable=mask, rows=rows, pred_names=pred_names,
        swing_source=source if have_surface else "",
        far=far_joints(p, g, far_fraction * s), far_distance=far_fraction * s,
        duplicate=duplicate, near_miss=near_miss,
    )


def load_prediction(path: str | Path) -> tuple[np.ndarray, list[str]]:
    """Predicted joints ``(F, P, 3)`` and names from a ``skeleton.json`` (or an ``.npz`` with a
    ``joints`` array, e.g. another ``gt.npz``; or a folder holding ``skeleton.json``).

    Raises
    ------
    InputError
        Missing or malformed file (the message names the file).
    """
    pth = Path(path)
    if pth.is_dir():
        pth = pth / "skeleton.json"
    if not pth.exists():
        raise InputError("prediction file not found", pth)
    if pth.suffix.lower() == ".npz":
        try:
            with np.load(pth, allow_pickle=False) as z:
                if "joints" not in z.files:
                    raise InputError("npz prediction lacks a 'joints' array", pth)
                joints = z["joints"]
                names = [str(n) for n in z["names"]] if "names" in z.files else None
        except InputError:
            raise
        except (ValueError, OSError, EOFError) as exc:
            raise InputError(f"not a readable .npz file: {exc}", pth) from None
    else:
        from .skeleton import load_skeleton_json

        try:
            sk = load_skeleton_json(pth)
        except ValueError as exc:  # Skeleton's own shape checks
            if isinstance(exc, InputError):
                raise
            raise InputError(f"malformed skeleton document: {exc}", pth) from None
        joints, names = sk.joint_positions, sk.joint_names
    joints = _check_joints(joints, "prediction", pth)
    if names is None or len(names) != joints.shape[1]:
        names = [f"p{i}" for i in range(joints.shape[1])]
    return joints, names


def _recorded_frames(pred_path: str | Path) -> np.ndarray | None:
    """``source.frame_indices`` of a ``skeleton.json`` (or of the one in a folder), if any."""
    p = Path(pred_path)
    p = p / "skeleton.json" if p.is_dir() else p
    if p.suffix.lower() != ".json":
        return None
    try:
        idx = json.loads(p.read_text()).get("source", {}).get("frame_indices")
    except (OSError, ValueError, AttributeError):
        return None
    return None if idx is None else np.asarray(idx, dtype=np.int64)


def evaluate_files(pred_path: str | Path, gt_path: str | Path, *, start: int = 0,
                   stop: int | None = None, stride: int = 1, **kwargs: Any) -> EvalReport:
    """:func:`evaluate` a ``skeleton.json`` against a ``gt.npz`` (or their folders).

    ``start, stop, stride`` select the ground-truth frames that the prediction was made from
    (as ``pointrig extract --start/--stop/--stride``). A ``skeleton.json`` that records its
    frames (``source.frame_indices``, written when ``--skip-bad-frames`` left some out) selects
    them itself.
    """
    from .synth.scene import load_gt

    pred, pred_names = load_prediction(pred_path)
    gt = load_gt(gt_path)
    sl: slice | np.ndarray = slice(start, stop, stride)
    recorded = _recorded_frames(pred_path)
    if recorded is not None:
        if (start, stop, stride) != (0, None, 1):
            raise ConfigError("the prediction records the frames it was made from "
                              "(source.frame_indices); leave out --start/--stop/--stride")
        sl = recorded
    surf = gt.get("surface")
    Rb, Tb = gt.get("bone_rotations"), gt.get("bone_translations")
    return evaluate(pred, gt["joints"][sl], gt["parents"], gt_names=gt["names"],
                    pred_names=pred_names, surface=None if surf is None else surf[sl],
                    surface_labels=gt.get("surface_labels"), skinned=gt.get("skinned"),
                    pred_source=Path(pred_path), gt_source=gt["path"],
                    bone_rotations=None if Rb is None else Rb[sl],
                    bone_translations=None if Tb is None else Tb[sl],
                    rest_surface=gt.get("rest_surface"), **kwargs)
