"""Joint names by place in the tree, and a user's renaming.

:func:`tree_names` names the joints of a skeleton the way rigs are named: ``root``, then one
name per chain of joints from a branching joint to the next branch or a tip, numbered along
the chain (``spine_1``, ``spine_2``, ``arm_l_1``, ...). A chain's kind comes from its
direction in the rest pose, in the y-up frame of the exports (``export.CAMERA_TO_YUP``):
up ``head`` (``spine`` from the root when nothing else is), down ``leg``, else (sideways or
along the view) ``arm``. Sides assume the subject faces the camera: the subject's left is the
camera's ``+x``, so a chain ending at ``x`` above its start is ``_l``. From the root, a chain
that ends in a branching (the trunk), or the only one going down, is ``spine``. When two
chains would
share a name (a quadruped's legs, a hand's fingers), the tree's shape does not allow these
names and every chain is named ``chain_a``, ``chain_b``, ... in the order of its first joint's
rest position; so names are the same for the same rest skeleton, run after run.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .errors import InputError
from .jsonfile import read_json
from .skeleton import Skeleton

__all__ = ["apply_names", "read_name_mapping", "rename_joints", "tree_names"]

_YUP = np.diag([1.0, -1.0, -1.0])


def _chains(parents: np.ndarray) -> tuple[list[list[int]], list[int]]:
    """The chains below the root: each a list of joints ``[first, ..., last]`` where only the
    last may have other than one child; and each chain's start joint (the parent of its first
    joint). Chains are listed parent before child."""
    J = len(parents)
    children: list[list[int]] = [[] for _ in range(J)]
    for j in range(J):
        if parents[j] >= 0:
            children[int(parents[j])].append(j)
    root = int(np.flatnonzero(parents < 0)[0])
    chains, starts = [], []
    todo = [(root, k) for k in children[root]]
    while todo:
        start, j = todo.pop(0)
        chain = [j]
        while len(children[chain[-1]]) == 1:
            chain.append(children[chain[-1]][0])
        chains.append(chain)
        starts.append(start)
        todo.extend((chain[-1], k) for k in children[chain[-1]])
    return chains, starts


def _kind(d: np.ndarray, from_root: bool, branches: bool, spine_elsewhere: bool,
          lone_down: bool) -> str:
    """A chain's kind from its direction ``d (3,)`` (y-up frame, start to end), whether it
    starts at the root, ends in a branching, whether another chain from the root is the
    spine, and whether it is the only chain going down from its start."""
    up = int(np.argmax(np.abs(d))) == 1
    if from_root and branches:
        return "spine"
    if up and d[1] > 0:
        return "head" if (spine_elsewhere or not from_root) else "spine"
    if up and from_root and lone_down and not spine_elsewhere:
        return "spine"
    side = "_l" if d[0] > 0 else "_r"
    return ("leg" if up else "arm") + side


def tree_names(parents: np.ndarray, rest_positions: np.ndarray) -> list[str]:
    """Names of the joints by place in the tree (see the module).

    Parameters
    ----------
    parents
        ``(J,)`` parent joint, ``-1`` for the root (one root).
    rest_positions
        ``(J, 3)`` rest joints, metres, camera frame (y down, z forward).

    Returns
    -------
    list of str
        ``J`` distinct names.
    """
    parents = np.asarray(parents)
    rest = np.asarray(rest_positions, dtype=float) @ _YUP.T
    J = len(parents)
    names = [""] * J
    root = int(np.flatnonzero(parents < 0)[0])
    names[root] = "root"
    chains, starts = _chains(parents)
    ends = {c[-1] for c in chains}
    starts_at = {j: [i for i, st in enumerate(starts) if st == j] for j in ends | {root}}
    branches = [len(starts_at.get(c[-1], [])) >= 2 for c in chains]
    dirs = [rest[c[-1]] - rest[st] for c, st in zip(chains, starts)]

    def down(i: int) -> bool:
        return int(np.argmax(np.abs(dirs[i]))) == 1 and dirs[i][1] < 0

    from_root = [i for i in range(len(chains)) if starts[i] == root]
    trunk = [i for i in from_root if branches[i]]
    downs = [i for i in from_root if down(i)]
    kinds = []
    for i in range(len(chains)):
        at_root = starts[i] == root
        kinds.append(_kind(dirs[i], at_root, branches[i],
                           spine_elsewhere=any(k != i for k in trunk) or (
                               at_root and not down(i) and len(downs) == 1 and not trunk),
                           lone_down=len(downs) == 1))
    if len(set(kinds)) < len(kinds):
        order = sorted(range(len(chains)),
                       key=lambda i: (*np.round(rest[chains[i][0]], 4), i))
        for n, i in enumerate(order):
            for m, j in enumerate(chains[i]):
                names[j] = f"chain_{_letters(n)}_{m + 1}"
        return names
    for kind, chain in zip(kinds, chains):
        for m, j in enumerate(chain):
            names[j] = f"{kind}_{m + 1}"
    return names


def _letters(n: int) -> str:
    """0 -> a, 25 -> z, 26 -> aa, ..."""
    s = ""
    n += 1
    while n:
        n, r = divmod(n - 1, 26)
        s = chr(ord("a") + r) + s
    return s


def rename_joints(skel: Skeleton, names: list[str]) -> Skeleton:
    """``skel`` with joint ``j`` named ``names[j]`` and each bone named after its tail joint
    (in place; returned for chaining)."""
    skel.joint_names = list(names)
    skel.bone_names = [names[int(t)] for t in skel.bone_tails]
    return skel


def read_name_mapping(path: str | Path) -> dict[str, str]:
    """A ``{joint name: new name}`` JSON object from ``path``.

    Raises
    ------
    InputError
        If the file is missing or not a JSON object of non-empty strings.
    """
    p = Path(path)
    mapping = read_json(p, missing="bone-name mapping not found",
                        invalid="bone-name mapping is not valid JSON")
    if not isinstance(mapping, dict) or not all(
            isinstance(k, str) and isinstance(v, str) and v.strip() for k, v in mapping.items()):
        raise InputError("bone-name mapping must be a JSON object of names to new names", p)
    return mapping


def apply_names(skel: Skeleton, scheme: str, mapping: dict[str, str] | None = None,
                where: str | Path = "bone-name mapping") -> Skeleton:
    """Name ``skel``'s joints: ``scheme`` ``"tree"`` (:func:`tree_names`) or ``"index"``
    (as built, ``j0, j1, ...``), then a user's ``{name: new name}`` mapping on top (in place;
    returned for chaining).

    Raises
    ------
    InputError
        If the mapping (from file ``where``) names a joint the skeleton does not have, or
        would give two joints one name.
    """
    if scheme == "tree" and skel.n_joints:
        rename_joints(skel, tree_names(skel.parents, skel.rest_positions))
    if not mapping:
        return skel
    unknown = sorted(set(mapping) - set(skel.joint_names))
    if unknown:
        raise InputError(f"bone-name mapping names joints the skeleton does not have: "
                         f"{', '.join(unknown)} (joints: {', '.join(skel.joint_names)})",
                         Path(where))
    new = [mapping.get(n, n) for n in skel.joint_names]
    if len(set(new)) < len(new):
        dup = sorted({n for n in new if new.count(n) > 1})
        raise InputError(f"bone-name mapping gives two joints one name: {', '.join(dup)}",
                         Path(where))
    return rename_joints(skel, new)
