"""Joint names by place in the tree and the user's renaming."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pointrig.errors import InputError
from pointrig.naming import apply_names, tree_names
from pointrig.pipeline import build_skeleton


def _human():
    """A human facing the camera in camera coordinates (y down, z forward, subject's left at
    +x): pelvis root, a 2-joint spine to the chest, a neck/head chain, two arms, two legs."""
    # index: 0 pelvis, 1 spine, 2 chest, 3 neck, 4 head, 5 l shoulder, 6 l elbow, 7 r shoulder,
    # 8 r elbow, 9 l hip, 10 l knee, 11 r hip, 12 r knee
    parents = np.array([-1, 0, 1, 2, 3, 2, 5, 2, 7, 0, 9, 0, 11])
    rest = np.array([
        [0, 0, 2], [0, -0.2, 2], [0, -0.45, 2], [0, -0.6, 2], [0, -0.75, 2],
        [0.2, -0.45, 2], [0.45, -0.45, 2], [-0.2, -0.45, 2], [-0.45, -0.45, 2],
        [0.1, 0.05, 2], [0.1, 0.5, 2], [-0.1, 0.05, 2], [-0.1, 0.5, 2]], float)
    return parents, rest


def test_a_human_tree_gets_rig_names():
    parents, rest = _human()
    names = tree_names(parents, rest)
    assert names == ["root", "spine_1", "spine_2", "head_1", "head_2", "arm_l_1", "arm_l_2",
                     "arm_r_1", "arm_r_2", "leg_l_1", "leg_l_2", "leg_r_1", "leg_r_2"]


def test_four_legs_fall_back_to_generic_names_stable_under_joint_order():
    # a table-like quadruped: root with four legs going down (two per side)
    parents = np.array([-1, 0, 1, 0, 3, 0, 5, 0, 7])
    rest = np.array([[0, 0, 2], [0.2, 0.1, 1.7], [0.2, 0.5, 1.7], [0.2, 0.1, 2.3],
                     [0.2, 0.5, 2.3], [-0.2, 0.1, 1.7], [-0.2, 0.5, 1.7], [-0.2, 0.1, 2.3],
                     [-0.2, 0.5, 2.3]], float)
    names = tree_names(parents, rest)
    assert names[0] == "root" and len(set(names)) == len(names)
    assert all(n.startswith("chain_") for n in names[1:])
    # the same skeleton with its legs listed in another order: each joint keeps its name
    perm = [0, 7, 8, 1, 2, 5, 6, 3, 4]
    inv = np.argsort(perm)
    p2 = np.array([-1 if parents[k] < 0 else inv[parents[k]] for k in perm])
    names2 = tree_names(p2, rest[perm])
    assert [names2[inv[j]] for j in range(9)] == names


def _skeleton():
    parents, rest = _human()
    F, J = 2, len(parents)
    R = np.broadcast_to(np.eye(3), (F, J, 3, 3)).copy()
    T = np.zeros((F, J, 3))
    return build_skeleton(np.zeros((1, 3)), parents, rest, R, T, None, None)


def test_mapping_renames_joints_and_bones(tmp_path):
    sk = apply_names(_skeleton(), "tree", {"head_2": "Head", "root": "Hips"})
    assert sk.joint_names[0] == "Hips" and "Head" in sk.joint_names
    tails = [sk.joint_names[t] for t in sk.bone_tails]
    assert sk.bone_names == tails
    assert apply_names(_skeleton(), "index").joint_names[:2] == ["j0", "j1"]


@pytest.mark.parametrize("mapping,what", [
    ({"nose": "Nose"}, "does not have: nose"),
    ({"arm_l_1": "Arm", "arm_r_1": "Arm"}, "two joints one name: Arm"),
])
def test_bad_mapping_is_an_input_error_naming_the_file(tmp_path, mapping, what):
    path = tmp_path / "names.json"
    path.write_text(json.dumps(mapping))
    with pytest.raises(InputError, match=what) as err:
        apply_names(_skeleton(), "tree", mapping, path)
    assert "names.json" in str(err.value)


def test_mapping_file_must_be_an_object_of_strings(tmp_path):
    from pointrig.naming import read_name_mapping

    path = tmp_path / "names.json"
    path.write_text('["a"]')
    with pytest.raises(InputError, match="JSON object"):
        read_name_mapping(path)
    path.write_text("{")
    with pytest.raises(InputError, match="not valid JSON"):
        read_name_mapping(path)


def test_a_human_rooted_at_the_chest_gets_rig_names():
    # 0 chest (root), 1 neck, 2 l shoulder, 3 r shoulder, 4 belly, 5 pelvis, 6 l knee,
    # 7 r knee: the trunk goes down from the root and branches into the legs
    parents = np.array([-1, 0, 0, 0, 0, 4, 5, 5])
    rest = np.array([[0, -0.45, 2], [0, -0.7, 2], [0.25, -0.45, 2], [-0.25, -0.45, 2],
                     [0, -0.2, 2], [0, 0, 2], [0.1, 0.45, 2], [-0.1, 0.45, 2]], float)
    assert tree_names(parents, rest) == ["root", "head_1", "arm_l_1", "arm_r_1", "spine_1",
                                         "spine_2", "leg_l_1", "leg_r_1"]
