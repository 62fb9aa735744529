"""A generalisation corpus: depth sequences of many subjects, split BY SUBJECT into a tuning set
and a check set before any tuning.

Subjects come from the rigged, animated glTF models of ``shared/data/models/extra`` (humans and
humanoids of many proportions, robots and mechs, quadrupeds, dinosaurs, fish and snakes,
creatures; licences in its LICENSES.md), from the CMU motion-capture BVH clips there dressed in
capsule bodies (:mod:`pointrig.synth.bvh`), and from pointrig's procedural figures with
randomised proportions (``make_figure(name, seed)``). Every model is scaled to a stated size
(``synthesize(size=...)``: the median bounding-box diagonal of its mesh, metres).

**Subjects.** A subject is one character, or one family of models that share a rig and its
animations (the four men and three women of one pack, Bull and Cow, Husky and Shiba Inu, the
four astronauts, ...): a family counts as one subject, so no rig is in both sets. The two CMU
performers are two subjects (60: salsa lead, 61: salsa follow), whatever their clips. The
procedural figures are one subject per figure (its seeds vary proportions, not the rig); the
accuracy suite has been tuned on them, so their category measures the suite's own domain.

**Split rule.** Within each category (humanoid, robot, quadruped, dinosaur, fish_snake,
creature, mocap, procedural), the subjects are ordered by the SHA-1 of their id; the 1st, 3rd,
5th, ... go to :data:`TUNING`, the 2nd, 4th, ... to :data:`CHECK`. Nothing else decides it, so
the split is reproducible and each category is balanced (one subject apart at most).

**Sequences.** Each take is a subject model, a clip (looped, or played once over the sequence
when the clip is not a cycle), a view (yaw, degrees; quadrupeds and fish face ``+z`` in their
files, so 90 is a side view), a camera (Kinect v1 at 640x480 or 320x240) and a distance
(by default 1.6 times the subject's size, which puts about 10k points a frame on a human at
640x480; about a third of the takes are far: 320x240 at 2.5-4 m), Kinect noise with 2 %
outliers. 60 frames at 30 fps by default.

**Groups.** Each subject is also tagged ``human-sized`` (humanoids, robots and mechs, mocap, the
procedural human), ``animal`` (quadrupeds, dinosaurs, fish, snakes, birds) or ``other``
(creatures, blobs, flying machines, hands), because targets differ.

Models not in the corpus are listed in :data:`EXCLUDED` with the reason (near-static clips) or
in :data:`UNUSED` (members of no subject: the time budget).

Usage::

    python -m benchmarks.corpus            # the table of both sets
    python -m benchmarks.corpus --check    # load every take, clip motion
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pointrig.synth import FIGURES, Camera, NoiseConfig, synthesize

#: A take without a distance is seen from this many times its subject's size (a 1.9 m human
#: from 3.0 m: about 10k points a frame at 640x480), at least MIN_DISTANCE metres.
DISTANCE_PER_SIZE = 1.6
MIN_DISTANCE = 0.8
#: Frames per sequence and frame rate by default.
FRAMES = 60
FPS = 30.0
#: A clip must move the mesh (largest RMS vertex displacement from its first frame after
#: removing the mean translation) by at least this fraction of its size to be used.
MIN_MOTION = 0.04
CATEGORIES = ("humanoid", "robot", "quadruped", "dinosaur", "fish_snake", "creature", "mocap",
              "procedural")
GROUPS = ("human-sized", "animal", "other")


def models_dir() -> Path:
    """The folder of the extra models: ``$POINTRIG_MODELS`` if set, else the first
    ``shared/data/models/extra`` found beside a parent of this file."""
    env = os.environ.get("POINTRIG_MODELS")
    if env:
        return Path(env)
    for p in Path(__file__).resolve().parents:
        cand = p / "shared" / "data" / "models" / "extra"
        if cand.is_dir():
            return cand
    return Path(__file__).resolve().parents[2] / "shared" / "data" / "models" / "extra"


@dataclass(frozen=True)
class Take:
    """One sequence of a subject: ``model`` (file in the models folder, or a figure name),
    ``clip`` (glTF animation name, ``None`` for BVH and figures), ``once`` (play the clip once
    over the sequence instead of looping it), ``yaw`` (degrees), ``camera`` (640 or 320),
    ``distance`` (metres from the motion's centre; ``None``: :data:`DISTANCE_PER_SIZE` times
    the subject's size, at least :data:`MIN_DISTANCE`), ``start`` (seconds into
    the clip), ``seed`` (figure proportions and motion)."""

    model: str
    clip: str | None = None
    once: bool = False
    yaw: float = 0.0
    camera: int = 640
    distance: float | None = None
    start: float = 0.0
    seed: int = 0


@dataclass(frozen=True)
class Subject:
    """A subject: its id (the unit of the split), category, group, size (metres, the median
    bounding-box diagonal of its mesh), the models of its family and its takes."""

    id: str
    category: str
    group: str
    size: float
    models: tuple[str, ...]
    takes: tuple[Take, ...]


@dataclass(frozen=True)
class Sequence:
    """One corpus sequence: a take of a subject, with its name, set and tags."""

    name: str
    subject: str
    category: str
    group: str
    size: float
    take: Take
    set: str

    @property
    def source(self) -> str:
        """The figure name or the model's path."""
        m = self.take.model
        return m if m in FIGURES else str(models_dir() / m)


Q = "quaternius_"
FBX = Q + "fbx_"


def _s(id: str, category: str, group: str, size: float, models: tuple[str, ...] | str,
       *takes: Take) -> Subject:
    ms = (models,) if isinstance(models, str) else models
    return Subject(id, category, group, size, ms, takes)


SUBJECTS: tuple[Subject, ...] = (
    # humanoids
    _s("mannequiny", "humanoid", "human-sized", 1.9, "gdquest_mannequiny.glb",
       Take("gdquest_mannequiny.glb", "run_root", yaw=30)),
    _s("kaykit", "humanoid", "human-sized", 1.9, "kaykit_mannequin_medium.glb",
       Take("kaykit_mannequin_medium.glb", "Rig_Medium|Walking_A"),
       Take("kaykit_mannequin_medium.glb", "Rig_Medium|Ranged_Magic_Spellcasting_Long",
            once=True, yaw=40, camera=320, distance=3.0)),
    _s("quat_people", "humanoid", "human-sized", 1.9,
       tuple(f"{FBX}Animated_{g}_Characters__{n}.glb" for g, n in (
           ("Men", "Male_Casual"), ("Men", "Male_LongSleeve"), ("Men", "Male_Shirt"),
           ("Men", "Male_Suit"), ("Women", "Female_Alternative"), ("Women", "Female_Dress"),
           ("Women", "Female_TankTop"))),
       Take(f"{FBX}Animated_Women_Characters__Female_Dress.glb", "Female_Clapping", yaw=20,
            camera=320, distance=3.5)),
    _s("man_animated", "humanoid", "human-sized", 1.9, f"{FBX}Man_Animated__Animated_Human.glb",
       Take(f"{FBX}Man_Animated__Animated_Human.glb", "Punch", once=True, yaw=45)),
    _s("woman_animated", "humanoid", "human-sized", 1.9,
       f"{FBX}Woman_Animated__Animated_Woman.glb",
       Take(f"{FBX}Woman_Animated__Animated_Woman.glb", "Walking", yaw=-45)),
    _s("zombie", "humanoid", "human-sized", 1.9, f"{FBX}Zombie_Animated__Zombie.glb",
       Take(f"{FBX}Zombie_Animated__Zombie.glb", "ZombieWalk", yaw=20, camera=320,
            distance=3.0)),
    _s("goblin", "humanoid", "human-sized", 1.4, f"{FBX}Goblin_Animated__Goblin.glb",
       Take(f"{FBX}Goblin_Animated__Goblin.glb", "Goblin_Walk", yaw=-20)),
    _s("cowboy", "humanoid", "human-sized", 1.9, f"{FBX}Cowboy_Pack__Cowboy.glb",
       Take(f"{FBX}Cowboy_Pack__Cowboy.glb", "12RussianDance")),
    _s("alien", "humanoid", "human-sized", 1.9, f"{FBX}Alien_Animated__Alien.glb",
       Take(f"{FBX}Alien_Animated__Alien.glb", "Alien_Clapping", yaw=30)),
    _s("skeleton", "humanoid", "human-sized", 1.9, f"{FBX}Monster_Pack_Animated__Skeleton.glb",
       Take(f"{FBX}Monster_Pack_Animated__Skeleton.glb", "Skeleton_Attack", once=True,
            yaw=-40, camera=320, distance=3.5)),
    _s("cyber_character", "humanoid", "human-sized", 1.9, f"{Q}cyberpunk_pack__Character.glb",
       Take(f"{Q}cyberpunk_pack__Character.glb", "CharacterArmature|Run", yaw=30)),
    _s("platformer_character", "humanoid", "human-sized", 1.5,
       f"{Q}platformer_game_pack__Character.glb",
       Take(f"{Q}platformer_game_pack__Character.glb", "CharacterArmature|Walk", yaw=10)),
    _s("space_humanoid", "humanoid", "human-sized", 1.6,
       tuple(f"{Q}ultimate_space_pack__{n}.glb" for n in (
           "Astronaut_BarbaraTheBee", "Astronaut_FernandoTheFlamingo", "Astronaut_FinnTheFrog",
           "Astronaut_RaeTheRedPanda", "Enemy_Large")),
       Take(f"{Q}ultimate_space_pack__Astronaut_FinnTheFrog.glb", "Wave")),
    # robots and mechs
    _s("robot", "robot", "human-sized", 1.8, f"{FBX}Animated_Robot__Robot.glb",
       Take(f"{FBX}Animated_Robot__Robot.glb", "Robot_Walking"),
       Take(f"{FBX}Animated_Robot__Robot.glb", "Robot_Dance", yaw=-30, camera=320,
            distance=3.0)),
    _s("mech_leela", "robot", "human-sized", 2.2, f"{Q}mech_pack__Leela.glb",
       Take(f"{Q}mech_pack__Leela.glb", "Walk", yaw=30)),
    _s("mech_mike_stan", "robot", "human-sized", 2.2,
       (f"{Q}mech_pack__Mike.glb", f"{Q}mech_pack__Stan.glb"),
       Take(f"{Q}mech_pack__Stan.glb", "Dance", yaw=20, camera=320, distance=3.5)),
    _s("space_mech", "robot", "human-sized", 2.0,
       tuple(f"{Q}ultimate_space_pack__Mech_{n}.glb" for n in (
           "BarbaraTheBee", "FernandoTheFlamingo", "FinnTheFrog", "RaeTheRedPanda")),
       Take(f"{Q}ultimate_space_pack__Mech_RaeTheRedPanda.glb", "Walk", yaw=30)),
    _s("cyber_enemy", "robot", "human-sized", 1.8,
       (f"{Q}cyberpunk_pack__Enemy_2Legs.glb", f"{Q}cyberpunk_pack__Enemy_Large.glb"),
       Take(f"{Q}cyberpunk_pack__Enemy_2Legs.glb", "Walk", yaw=90, camera=320, distance=3.0)),
    _s("godot_enemy", "robot", "other", 1.5, "godot_platformer_enemy.glb",
       Take("godot_platformer_enemy.glb", "walk", yaw=30)),
    # quadrupeds (facing +z in their files)
    _s("ap_bovine", "quadruped", "animal", 2.4,
       (f"{Q}animals_pack__Bull.glb", f"{Q}animals_pack__Cow.glb"),
       Take(f"{Q}animals_pack__Bull.glb", "AnimalArmature|Walk", yaw=110)),
    _s("ap_alpaca", "quadruped", "animal", 2.0, f"{Q}animals_pack__Alpaca.glb",
       Take(f"{Q}animals_pack__Alpaca.glb", "AnimalArmature|Walk", yaw=60)),
    _s("ap_donkey", "quadruped", "animal", 2.0, f"{Q}animals_pack__Donkey.glb",
       Take(f"{Q}animals_pack__Donkey.glb", "AnimalArmature|Gallop", yaw=120, camera=320,
            distance=4.0)),
    _s("ap_fox_wolf", "quadruped", "animal", 1.3,
       (f"{Q}animals_pack__Fox.glb", f"{Q}animals_pack__Wolf.glb"),
       Take(f"{Q}animals_pack__Fox.glb", "AnimalArmature|Walk", yaw=90)),
    _s("ap_dog", "quadruped", "animal", 1.1,
       (f"{Q}animals_pack__Husky.glb", f"{Q}animals_pack__ShibaInu.glb"),
       Take(f"{Q}animals_pack__Husky.glb", "AnimalArmature|Walk", yaw=110, camera=320,
            distance=3.0)),
    _s("ap2_quadruped", "quadruped", "animal", 1.0,
       tuple(f"{FBX}Animal_Pack_Vol.2__{n}.glb" for n in ("Cat", "Dog", "Wolf")),
       Take(f"{FBX}Animal_Pack_Vol.2__Cat.glb", "Walking", yaw=20)),
    _s("farm_equine", "quadruped", "animal", 2.6,
       (f"{FBX}Farm_Animals_Animated___Horse.glb", f"{FBX}Farm_Animals_Animated___Zebra.glb"),
       Take(f"{FBX}Farm_Animals_Animated___Horse.glb", "Walk", yaw=70)),
    _s("farm_cow", "quadruped", "animal", 2.4, f"{FBX}Farm_Animals_Animated___Cow.glb",
       Take(f"{FBX}Farm_Animals_Animated___Cow.glb", "WalkSlow", yaw=130, camera=320,
            distance=4.0)),
    _s("farm_small", "quadruped", "animal", 1.3,
       tuple(f"{FBX}Farm_Animals_Animated___{n}.glb" for n in ("Llama", "Pig", "Pug", "Sheep")),
       Take(f"{FBX}Farm_Animals_Animated___Sheep.glb", "Jump", once=True, yaw=110)),
    _s("red_fox", "quadruped", "animal", 1.1, f"{FBX}Animals_Pack__Red_Fox.glb",
       Take(f"{FBX}Animals_Pack__Red_Fox.glb", "ArmatureAction", yaw=120)),
    _s("rat", "quadruped", "animal", 0.8, f"{Q}easy_enemies_pack__Rat.glb",
       Take(f"{Q}easy_enemies_pack__Rat.glb", "Rat_Walk", yaw=70)),
    # dinosaurs
    _s("trex", "dinosaur", "animal", 3.0, f"{Q}dinosaurs_pack__Trex.glb",
       Take(f"{Q}dinosaurs_pack__Trex.glb", "TRex_Walk", yaw=110)),
    _s("velociraptor", "dinosaur", "animal", 2.0, f"{Q}dinosaurs_pack__Velociraptor.glb",
       Take(f"{Q}dinosaurs_pack__Velociraptor.glb", "Velociraptor_Run", yaw=60, camera=320,
            distance=3.5)),
    _s("parasaurolophus", "dinosaur", "animal", 2.8,
       f"{Q}dinosaurs_pack__Parasaurolophus.glb",
       Take(f"{Q}dinosaurs_pack__Parasaurolophus.glb", "Parasaurolophus_Walk", yaw=120)),
    _s("apatosaurus", "dinosaur", "animal", 3.5, f"{Q}dinosaurs_pack__Apatosaurus.glb",
       Take(f"{Q}dinosaurs_pack__Apatosaurus.glb", "Apatosaurus_Walk", yaw=70)),
    _s("stegosaurus", "dinosaur", "animal", 3.0, f"{Q}dinosaurs_pack__Stegosaurus.glb",
       Take(f"{Q}dinosaurs_pack__Stegosaurus.glb", "Stegosaurus_Walk", yaw=110, camera=320,
            distance=4.0)),
    _s("triceratops", "dinosaur", "animal", 3.0, f"{Q}dinosaurs_pack__Triceratops.glb",
       Take(f"{Q}dinosaurs_pack__Triceratops.glb", "Triceratops_Walk", yaw=90)),
    # fish and snakes
    _s("cute_koi", "fish_snake", "animal", 1.0, f"{Q}cute_fish_pack__Koi.glb",
       Take(f"{Q}cute_fish_pack__Koi.glb", "Swimming_Fast", yaw=110)),
    _s("cute_swordfish", "fish_snake", "animal", 1.5, f"{Q}cute_fish_pack__Swordfish.glb",
       Take(f"{Q}cute_fish_pack__Swordfish.glb", "Swimming_Normal", yaw=70, camera=320,
            distance=3.0)),
    _s("cute_puffer", "fish_snake", "animal", 0.8, f"{Q}cute_fish_pack__Puffer.glb",
       Take(f"{Q}cute_fish_pack__Puffer.glb", "Swimming_Fast", yaw=90)),
    _s("dolphin", "fish_snake", "animal", 2.0, f"{Q}fish_pack__Dolphin.glb",
       Take(f"{Q}fish_pack__Dolphin.glb", "Swim", yaw=110)),
    _s("whale", "fish_snake", "animal", 3.0, f"{Q}fish_pack__Whale.glb",
       Take(f"{Q}fish_pack__Whale.glb", "Swim", yaw=70, camera=320, distance=4.0)),
    _s("snake", "fish_snake", "animal", 1.5,
       (f"{Q}easy_enemies_pack__Snake.glb", f"{Q}easy_enemies_pack__Snake_angry.glb"),
       Take(f"{Q}easy_enemies_pack__Snake.glb", "Snake_Walk", yaw=60)),
    # creatures
    _s("bat", "creature", "other", 1.2, f"{FBX}Monster_Pack_Animated__Bat.glb",
       Take(f"{FBX}Monster_Pack_Animated__Bat.glb", "Bat_Flying", yaw=20)),
    _s("dragon", "creature", "other", 2.0, f"{FBX}Monster_Pack_Animated__Dragon.glb",
       Take(f"{FBX}Monster_Pack_Animated__Dragon.glb", "Dragon_Flying", yaw=-20, camera=320,
            distance=3.5)),
    _s("chick", "creature", "animal", 0.6, f"{FBX}Animals_Pack__Chick.glb",
       Take(f"{FBX}Animals_Pack__Chick.glb", "ArmatureAction", yaw=30)),
    _s("spider", "creature", "other", 1.2, f"{Q}easy_enemies_pack__Spider.glb",
       Take(f"{Q}easy_enemies_pack__Spider.glb", "Spider_Walk", yaw=30, camera=320,
            distance=2.5)),
    _s("slime", "creature", "other", 0.8, f"{FBX}Monster_Pack_Animated__Slime.glb",
       Take(f"{FBX}Monster_Pack_Animated__Slime.glb", "Slime_Attack", once=True, yaw=20)),
    _s("fruit", "creature", "other", 1.6,
       (f"{FBX}Fruit_Characters_Animated__Avocado.glb",
        f"{FBX}Fruit_Characters_Animated__Pineapple.glb"),
       Take(f"{FBX}Fruit_Characters_Animated__Pineapple.glb", "Wave", yaw=-20)),
    _s("space_enemy_small", "creature", "other", 1.0,
       (f"{Q}ultimate_space_pack__Enemy_Small.glb",
        f"{Q}ultimate_space_pack__Enemy_ExtraSmall.glb"),
       Take(f"{Q}ultimate_space_pack__Enemy_Small.glb", "Headbutt", once=True, yaw=40)),
    _s("frog", "creature", "animal", 0.8, f"{Q}easy_enemies_pack__Frog.glb",
       Take(f"{Q}easy_enemies_pack__Frog.glb", "Frog_Jump", once=True, yaw=60, camera=320,
            distance=2.5)),
    # motion capture (capsule bodies)
    _s("cmu_60", "mocap", "human-sized", 1.9,
       tuple(f"cmu_60_0{k}_scaled.bvh" for k in range(1, 5)),
       Take("cmu_60_02_scaled.bvh", start=4.0, yaw=20),
       Take("cmu_60_03_scaled.bvh", start=9.0, yaw=-40, camera=320, distance=3.5)),
    _s("cmu_61", "mocap", "human-sized", 1.8,
       tuple(f"cmu_61_0{k}_scaled.bvh" for k in range(1, 5)),
       Take("cmu_61_01_scaled.bvh", start=6.0, yaw=-20),
       Take("cmu_61_04_scaled.bvh", start=3.0, yaw=40, camera=320, distance=3.5)),
    # procedural figures with randomised proportions (seeds no suite or set uses)
    _s("proc_human", "procedural", "human-sized", 1.9, "human",
       Take("human", seed=101, yaw=25, camera=320, distance=3.0)),
    _s("proc_quadruped", "procedural", "animal", 1.2, "quadruped",
       Take("quadruped", seed=102, yaw=-25)),
    _s("proc_snake", "procedural", "animal", 1.4, "snake", Take("snake", seed=103, yaw=30)),
    _s("proc_hand", "procedural", "other", 0.25, "hand", Take("hand", seed=104, yaw=20)),
)

#: Models left out, and why (each clip's motion measured as :func:`clip_motion` does).
EXCLUDED: dict[str, str] = {
    f"{Q}fish_pack__Fish1.glb": "no clip moves the mesh by 3 % of its size",
    f"{Q}fish_pack__Fish2.glb": "near-static: its one clip moves the mesh by 3.0 % of its size",
    f"{Q}fish_pack__Fish3.glb": "near-static: its one clip moves the mesh by 3.5 % of its size",
    f"{FBX}Animal_Pack_Vol.2__Piranha.glb":
        "near-static: its clips move the mesh by at most 3.6 % of its size",
    f"{FBX}Animal_Pack_Vol.2__Eagle.glb":
        "a level camera sees its flying clip edge-on: a sheet of wings a few pixels high",
}
#: Models that load and move but are in no subject (the time budget of the corpus).
UNUSED: tuple[str, ...] = (
    f"{Q}cute_fish_pack__Anglerfish.glb", f"{Q}cute_fish_pack__Shark.glb",
    f"{Q}fish_pack__Manta_ray.glb", f"{Q}fish_pack__Shark.glb",
    f"{Q}cyberpunk_pack__Enemy_Flying.glb", f"{Q}platformer_game_pack__Enemy.glb",
    f"{Q}platformer_game_pack__Skull.glb", f"{Q}ultimate_space_pack__Enemy_Flying.glb",
)


def subject_hash(subject_id: str) -> str:
    """The split key: the SHA-1 of the subject id, hex."""
    return hashlib.sha1(subject_id.encode("utf-8")).hexdigest()


def split(subjects: tuple[Subject, ...] = SUBJECTS) -> dict[str, str]:
    """Subject id -> ``"tuning"`` or ``"check"`` (the module docstring's rule)."""
    out: dict[str, str] = {}
    for cat in CATEGORIES:
        ids = sorted((s.id for s in subjects if s.category == cat), key=subject_hash)
        for k, sid in enumerate(ids):
            out[sid] = "tuning" if k % 2 == 0 else "check"
    return out


def sequences(subjects: tuple[Subject, ...] = SUBJECTS) -> dict[str, Sequence]:
    """Every corpus sequence by name (``<subject>_<k>``), both sets."""
    which = split(subjects)
    out: dict[str, Sequence] = {}
    for s in subjects:
        for k, t in enumerate(s.takes):
            name = f"{s.id}_{k}"
            out[name] = Sequence(name, s.id, s.category, s.group, s.size, t, which[s.id])
    return out


SEQUENCES = sequences()
TUNING: dict[str, Sequence] = {n: q for n, q in SEQUENCES.items() if q.set == "tuning"}
CHECK: dict[str, Sequence] = {n: q for n, q in SEQUENCES.items() if q.set == "check"}


def noise_for(seq: Sequence) -> NoiseConfig:
    """Kinect v1 noise with 2 % outliers, seeded by the sequence name."""
    seed = int(hashlib.sha1(seq.name.encode("utf-8")).hexdigest()[:8], 16)
    return dataclasses.replace(NoiseConfig(seed=seed), outliers=0.02)


def distance(seq: Sequence) -> float:
    """The camera distance of ``seq``, metres (:class:`Take`)."""
    if seq.take.distance is not None:
        return float(seq.take.distance)
    return max(DISTANCE_PER_SIZE * seq.size, MIN_DISTANCE)


def synth_kwargs(seq: Sequence, frames: int = FRAMES) -> dict[str, Any]:
    """The :func:`pointrig.synth.synthesize` keywords of ``seq`` at ``frames`` frames."""
    t = seq.take
    kw: dict[str, Any] = {"n_frames": frames, "fps": FPS, "seed": t.seed, "yaw": t.yaw,
                          "size": seq.size, "distance": distance(seq), "start": t.start,
                          "camera": Camera.kinect(t.camera), "noise": noise_for(seq)}
    if t.clip is not None:
        kw["clip"] = t.clip
    if t.once:
        from pointrig.synth.gltf import _pick_clip, load_gltf

        model = load_gltf(seq.source)
        dur = model.clip_duration(_pick_clip(model, t.clip))
        kw["speed"] = dur * FPS / max(frames - 1, 1)
    return kw


def synthesize_sequence(seq: Sequence, frames: int = FRAMES):
    """Render ``seq`` (a :class:`pointrig.synth.SynthSequence`)."""
    return synthesize(seq.source, **synth_kwargs(seq, frames))


def clip_motion(seq: Sequence, samples: int = 24) -> tuple[str, float, float]:
    """``(clip name, duration s, motion)`` of a glTF take: the motion is the largest RMS vertex
    displacement from the clip's first sample, after removing each sample's mean translation,
    as a fraction of the mesh's bounding-box diagonal."""
    from pointrig.kinematics import skin
    from pointrig.synth.gltf import _pick_clip, load_gltf

    model = load_gltf(seq.source)
    c = _pick_clip(model, seq.take.clip)
    dur = model.clip_duration(c)
    G = model.globals_at(c, np.linspace(0, dur, samples))
    M = G[:, model.joints] @ model.inverse_bind
    v = skin(model.vertices, model.weights, M[..., :3, :3], M[..., :3, 3])
    size = float(np.median(np.linalg.norm(v.max(axis=1) - v.min(axis=1), axis=1)))
    d = v - v.mean(axis=1, keepdims=True)
    motion = float(np.sqrt(((d - d[0]) ** 2).sum(axis=2).mean(axis=1)).max()) / size
    return model.clip_names()[c], dur, motion


def table(seqs: dict[str, Sequence]) -> str:
    """A text table of sequences."""
    rows = [(f"{'sequence':<24} {'set':<7} {'category':<11} {'group':<12} {'size':>5} "
             f"{'cam':>4} {'dist':>5} {'yaw':>5}  model / clip")]
    for n, q in seqs.items():
        t = q.take
        dist = f"{distance(q):.1f}"
        clip = f" / {t.clip}" + (" (once)" if t.once else "") if t.clip else \
            (f" @ {t.start:.0f} s" if t.start else f" seed {t.seed}")
        rows.append(f"{n:<24} {q.set:<7} {q.category:<11} {q.group:<12} {q.size:5.2f} "
                    f"{t.camera:>4} {dist:>5} {t.yaw:5.0f}  {Path(t.model).stem}{clip}")
    return "\n".join(rows)


def counts() -> str:
    """Sequences and subjects per set and category."""
    lines = [f"{'':<12}" + "".join(f"{c[:10]:>11}" for c in CATEGORIES) + f"{'total':>8}"]
    for name, s in (("tuning", TUNING), ("check", CHECK)):
        cells = []
        for c in CATEGORIES:
            subj = {q.subject for q in s.values() if q.category == c}
            cells.append(f"{sum(q.category == c for q in s.values())}/{len(subj)}")
        lines.append(f"{name:<12}" + "".join(f"{x:>11}" for x in cells) + f"{len(s):>8}")
    lines.append("(sequences/subjects)")
    for name, s in (("tuning", TUNING), ("check", CHECK)):
        lines.append(f"{name}: " + ", ".join(f"{g} {sum(q.group == g for q in s.values())}"
                                              for g in GROUPS))
    return "\n".join(lines)


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true",
                    help="load every glTF take and print its clip, duration and motion")
    a = ap.parse_args(argv)
    print(table(SEQUENCES))
    print()
    print(counts())
    if a.check:
        print()
        bad = 0
        for n, q in SEQUENCES.items():
            if not q.source.endswith(".glb"):
                continue
            clip, dur, mot = clip_motion(q)
            flag = "" if mot >= MIN_MOTION else "  NEAR-STATIC"
            bad += bool(flag)
            print(f"{n:<24} {clip:<48} {dur:5.2f} s  motion {mot:.3f}{flag}")
        return 1 if bad else 0
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
