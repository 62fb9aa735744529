"""The benchmark sequence sets and what the benchmarks share to run and score them.

A sequence is ``name -> (source, keywords)``: ``source`` is a :data:`pointrig.synth.FIGURES`
name or a glTF rig under :data:`MODELS`, ``keywords`` are :func:`pointrig.synth.synthesize`
keywords (``seed``, ``yaw``, ``walk``, ``clip``, ``start``) plus ``camera`` (the Kinect
resolution, ``"640"`` by default). Every sequence is rendered with moderate Kinect noise and
2 % outliers (:func:`synthesize_entry`). A rig whose file is missing is reported and skipped.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from pointrig.config import PipelineConfig
from pointrig.evaluate import EvalReport, evaluate
from pointrig.sequence import PointSequence
from pointrig.synth import Camera, NoiseConfig, SynthSequence, synthesize

__all__ = [
    "MODELS", "Entry", "SEQUENCES", "VALIDATION", "FRESH", "SPREAD", "ALL", "LIMBS", "HANDS",
    "SETS", "synthesize_entry", "add_sequence_options", "selected", "chosen", "suite",
    "jittered", "score_joints", "paper_config",
]

MODELS: Path = Path(os.environ.get(
    "POINTRIG_MODELS", Path(__file__).resolve().parents[2] / "shared" / "data" / "models"))
"""Folder of the glTF rigs (``girl.glb``, ``rigged_figure.glb``, ``greenman.glb``): the
``POINTRIG_MODELS`` environment variable, else ``shared/data/models`` beside the repository."""

Entry = tuple[str, dict[str, Any]]
"""One sequence: ``(figure name or .glb path, synthesis keywords)``."""


def _rig(name: str) -> str:
    return str(MODELS / f"{name}.glb")


SEQUENCES: dict[str, Entry] = {
    "human": ("human", {"seed": 5}),
    "human_s8": ("human", {"seed": 8}),
    "human_walk": ("human", {"seed": 7, "walk": 2.0}),
    "upper_body": ("upper_body", {"seed": 2}),
    "hand": ("hand", {"seed": 2}),
    "quadruped_320": ("quadruped", {"seed": 7, "camera": "320"}),
    "snake": ("snake", {"seed": 2}),
    "girl_run": (_rig("girl"), {"seed": 4, "clip": "RunTrack"}),
    "girl_run_s5": (_rig("girl"), {"seed": 5, "clip": "RunTrack", "yaw": -30}),
    "girl_idle": (_rig("girl"), {"seed": 5, "clip": "IdleTrack"}),
    "rigged_yaw20": (_rig("rigged_figure"), {"seed": 4, "yaw": 20}),
    "rigged_start": (_rig("rigged_figure"), {"seed": 5, "yaw": -40, "start": 0.5}),
    "greenman_move": (_rig("greenman"), {"seed": 4, "clip": "2_move"}),
    "greenman_attack": (_rig("greenman"), {"seed": 5, "clip": "3_attack"}),
}
"""The suite (``--set suite``, the default): 7 procedural figures and 7 glTF rig clips, one
seed each. Defaults are chosen on it; judge a change here first, then on the held-back sets."""

VALIDATION: dict[str, Entry] = {
    "v_human": ("human", {"seed": 21, "yaw": 30}),
    "v_human_walk": ("human", {"seed": 22, "walk": 1.5, "yaw": -20}),
    "v_upper_body": ("upper_body", {"seed": 23}),
    "v_hand": ("hand", {"seed": 24, "yaw": 25}),
    "v_quadruped": ("quadruped", {"seed": 25, "yaw": -30}),
    "v_snake": ("snake", {"seed": 26}),
    "v_girl_run_y30": (_rig("girl"), {"seed": 11, "clip": "RunTrack", "yaw": 30}),
    "v_girl_run_y60": (_rig("girl"), {"seed": 12, "clip": "RunTrack", "yaw": 60}),
    "v_girl_run_y-60": (_rig("girl"), {"seed": 13, "clip": "RunTrack", "yaw": -60}),
    "v_girl_run_320": (_rig("girl"), {"seed": 14, "clip": "RunTrack", "camera": "320"}),
    "v_girl_idle_y40": (_rig("girl"), {"seed": 15, "clip": "IdleTrack", "yaw": 40}),
    "v_rigged_y-20": (_rig("rigged_figure"), {"seed": 16, "yaw": -20}),
    "v_rigged_y60": (_rig("rigged_figure"), {"seed": 17, "yaw": 60, "start": 0.3}),
    "v_greenman_idle": (_rig("greenman"), {"seed": 18, "clip": "1_idle"}),
    "v_greenman_move_y45": (_rig("greenman"), {"seed": 19, "clip": "2_move", "yaw": 45}),
    "v_greenman_attack_y-30": (_rig("greenman"), {"seed": 20, "clip": "3_attack", "yaw": -30}),
}
"""Held-back set (``--set validation``): the suite's figures and rigs with seeds (11-26),
views, clips and start times no default was chosen on. A change chosen on the suite must hold
here before it becomes a default."""

FRESH: dict[str, Entry] = {
    "f_girl_run_y15": (_rig("girl"), {"seed": 31, "clip": "RunTrack", "yaw": 15}),
    "f_girl_idle_y-20": (_rig("girl"), {"seed": 32, "clip": "IdleTrack", "yaw": -20}),
    "f_greenman_idle_y20": (_rig("greenman"), {"seed": 33, "clip": "1_idle", "yaw": 20}),
    "f_greenman_move_y-20": (_rig("greenman"), {"seed": 34, "clip": "2_move", "yaw": -20}),
    "f_greenman_attack_y15": (_rig("greenman"), {"seed": 35, "clip": "3_attack", "yaw": 15}),
    "f_rigged_y40": (_rig("rigged_figure"), {"seed": 36, "yaw": 40}),
    "f_human_y-40": ("human", {"seed": 37, "yaw": -40}),
    "f_quadruped_y20": ("quadruped", {"seed": 38, "yaw": 20}),
    "f_hand_y-15": ("hand", {"seed": 39, "yaw": -15}),
}
"""Second held-back set (``--set fresh``): the rigs' other clips and views and three
procedural figures at seeds 31-39. The glTF rigs score far below the suite here, so it is the
check that a change does not only fit the suite's views."""

SPREAD: dict[str, Entry] = {
    "s_gm_attack_41": (_rig("greenman"), {"seed": 41, "clip": "3_attack", "yaw": -10}),
    "s_gm_attack_42": (_rig("greenman"), {"seed": 42, "clip": "3_attack", "yaw": 30}),
    "s_gm_move_43": (_rig("greenman"), {"seed": 43, "clip": "2_move", "yaw": 10}),
    "s_gm_move_44": (_rig("greenman"), {"seed": 44, "clip": "2_move", "yaw": -35}),
    "s_gm_idle_45": (_rig("greenman"), {"seed": 45, "clip": "1_idle", "yaw": -10}),
    "s_girl_idle_46": (_rig("girl"), {"seed": 46, "clip": "IdleTrack", "yaw": 10}),
    "s_girl_idle_47": (_rig("girl"), {"seed": 47, "clip": "IdleTrack", "yaw": -45}),
    "s_girl_run_48": (_rig("girl"), {"seed": 48, "clip": "RunTrack", "yaw": -10}),
    "s_rigged_49": (_rig("rigged_figure"), {"seed": 49, "yaw": -10}),
    "s_quadruped_50": ("quadruped", {"seed": 50, "yaw": -30}),
    "s_human_walk_51": ("human", {"seed": 51, "walk": 2.0, "yaw": 20}),
}
"""Third held-back set (``--set spread``): more views and seeds (41-51) of the rigs' clips,
weighted to the glTF rigs (greenman's three clips, the girl's idle and run, rigged_figure),
plus a quadruped and a walking human."""

ALL: dict[str, Entry] = {**SEQUENCES, **VALIDATION, **FRESH, **SPREAD}
"""The suite and the three held-back sets together (``--set all``, 50 sequences): one mean to
judge a default by, most of it on sequences no default was chosen on."""

LIMBS: dict[str, Entry] = {
    "arm_s3": ("arm", {"seed": 3}),
    "arm_s31": ("arm", {"seed": 31}),
    "arm_s32": ("arm", {"seed": 32}),
    "robot_arm_s3": ("robot_arm", {"seed": 3}),
    "robot_arm_s33": ("robot_arm", {"seed": 33}),
}
"""Single limbs (``--set limbs``): the bare arm and the robot arm. Their registrations slide
round the limb, so step 2 tends to cut it lengthwise into many bones; the set measures that
over-segmentation and the ``[structure] max_joints`` cap."""

HANDS: dict[str, Entry] = {
    "h_hand_40": ("hand", {"seed": 40, "yaw": -30}),
    "h_hand_41": ("hand", {"seed": 41, "yaw": 0}),
    "h_hand_42": ("hand", {"seed": 42, "yaw": 15}),
    "h_hand_43": ("hand", {"seed": 43, "yaw": 30}),
    "h_hand_44": ("hand", {"seed": 44, "yaw": -10}),
    "h_hand_45": ("hand", {"seed": 45, "yaw": 20}),
}
"""Small subjects (``--set hands``): the procedural hand (a 24 cm rest-pose diagonal, a tenth
of the human's) at seeds 40-45. Step 1's parameters are in metres; this set measures how they
carry down to a hand."""

SETS: dict[str, dict[str, Entry]] = {
    "suite": SEQUENCES, "validation": VALIDATION, "fresh": FRESH, "spread": SPREAD, "all": ALL,
    "limbs": LIMBS, "hands": HANDS,
}
"""The sequence sets by their ``--set`` name."""


def synthesize_entry(source: str, kw: dict[str, Any], frames: int) -> SynthSequence:
    """Render one sequence of ``frames`` frames: ``source`` with keywords ``kw`` (``camera``:
    the Kinect width, ``"640"`` or ``"320"``), moderate Kinect noise and 2 % outliers."""
    kw = dict(kw)
    camera = Camera.kinect(int(kw.pop("camera", "640")))
    return synthesize(source, n_frames=frames, camera=camera,
                      noise=dataclasses.replace(NoiseConfig(), outliers=0.02), **kw)


def add_sequence_options(ap: argparse.ArgumentParser, frames: int = 100,
                         only: str = "") -> None:
    """Add ``--frames`` (default ``frames``), ``--set`` (a key of :data:`SETS`, default
    ``"suite"``) and ``--only`` (comma-separated names, default ``only``; read back by
    :func:`chosen`) to a benchmark's parser."""
    ap.add_argument("--frames", type=int, default=frames, help="frames per sequence")
    ap.add_argument("--set", default="suite", choices=sorted(SETS),
                    help="the sequence set (default: the suite)")
    ap.add_argument("--only", default=only,
                    help="comma-separated sequence names of the set (default: all)")


def selected(ap: argparse.ArgumentParser, only_arg: str,
             sequences: dict[str, Entry] = SEQUENCES) -> set[str]:
    """The names of ``only_arg`` (comma-separated; empty = all) among ``sequences``, or
    ``ap.error`` (exit status 2) naming the unknown ones."""
    only = {n for n in only_arg.split(",") if n}
    if only - set(sequences):
        ap.error(f"--only: unknown {', '.join(sorted(only - set(sequences)))}; "
                 f"known: {', '.join(sequences)}")
    return only


def chosen(ap: argparse.ArgumentParser, args: argparse.Namespace
           ) -> tuple[dict[str, Entry], set[str]]:
    """The sequences of ``args.set`` and the names of ``args.only`` among them
    (:func:`selected`)."""
    sequences = SETS[args.set]
    return sequences, selected(ap, args.only, sequences)


def suite(frames: int, only: set[str], sequences: dict[str, Entry] = SEQUENCES
          ) -> Iterator[tuple[str, SynthSequence]]:
    """``(name, synthesized sequence)`` for each of ``sequences`` in ``only`` (all if empty),
    ``frames`` frames each, in the set's order; a rig whose file is missing is reported and
    skipped."""
    for name, (source, kw) in sequences.items():
        if only and name not in only:
            continue
        if source.endswith(".glb") and not Path(source).exists():
            print(f"{name:<16} skipped: {source} not found (set POINTRIG_MODELS)")
            continue
        yield name, synthesize_entry(source, kw, frames)


def jittered(seq: PointSequence, k: int) -> PointSequence:
    """``seq`` with every coordinate moved by a uniform amount in [-1e-9, 1e-9] m (seed
    ``k``): far below the sensor noise, so any change of the result is the pipeline's
    rounding, which the pipeline amplifies. A difference between two variants smaller than
    the spread over such repeats is not a measured difference."""
    rng = np.random.default_rng(k)
    return PointSequence([f + rng.uniform(-1e-9, 1e-9, f.shape) for f in seq.frames],
                         source=seq.source, names=list(seq.names), fmt=seq.fmt,
                         meta=dict(seq.meta))


def score_joints(joint_positions: np.ndarray, syn: SynthSequence) -> EvalReport:
    """:func:`pointrig.evaluate.evaluate` of predicted joints ``(F, J, 3)`` (metres, camera
    frame) against ``syn``'s ground truth."""
    return evaluate(joint_positions, syn.gt_joints, syn.joint_parents, **syn.eval_kwargs())


def paper_config() -> PipelineConfig:
    """The paper's pipeline (Table 1 values, Algorithms 1-2, none of pointrig's additions,
    :meth:`PipelineConfig.paper`): the reference the accuracy benchmarks compare the default
    with."""
    return PipelineConfig.paper()
