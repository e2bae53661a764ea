"""LIBERO task roles, obstacle boxes and the expert's geometry: pure logic, no LIBERO needed."""

from __future__ import annotations

import numpy as np
import pytest

from gazereg.envs.libero.expert import DOWN_ALONG_Y, SpatialExpert, axis_angle_of, yawed
from gazereg.envs.libero.scene import Boxes, TaskRoles, task_roles


def test_roles_from_the_goal_predicate():
    spatial = task_roles(
        [["on", "akita_black_bowl_1", "plate_1"]],
        ["akita_black_bowl_1", "plate_1"],
        movable={"akita_black_bowl_1", "akita_black_bowl_2", "plate_1", "cookies_1"},
        places={"akita_black_bowl_1", "akita_black_bowl_2", "plate_1", "cookies_1", "wooden_cabinet_1"},
    )
    assert spatial == TaskRoles(obj="akita_black_bowl_1", goal="plate_1", relation="on")
    # libero_object: (In obj basket_1_contain_region), a region
    obj = task_roles(
        [["In", "alphabet_soup_1", "basket_1_contain_region"]],
        ["alphabet_soup_1", "basket_1"],
        movable={"alphabet_soup_1", "basket_1"},
        places={"alphabet_soup_1", "basket_1", "basket_1_contain_region"},
    )
    assert obj == TaskRoles("alphabet_soup_1", "basket_1_contain_region", "in")
    # libero_goal: a unary predicate has no goal; obj from obj_of_interest
    goal = task_roles(
        [["open", "wooden_cabinet_1_middle_region"]],
        ["wooden_cabinet_1_middle_region"],
        movable={"plate_1"},
        places={"plate_1", "wooden_cabinet_1", "wooden_cabinet_1_middle_region"},
    )
    assert goal == TaskRoles("wooden_cabinet_1_middle_region", None, None)
    # libero_10: two placements, the first is used
    two = task_roles(
        [["on", "a_1", "b_1"], ["on", "c_1", "d_1"]],
        [],
        movable={"a_1", "c_1"},
        places={"a_1", "b_1", "c_1", "d_1"},
    )
    assert two.obj == "a_1" and two.goal == "b_1"
    with pytest.raises(KeyError, match="not in the scene"):
        task_roles([["on", "a_1", "nowhere"]], [], movable={"a_1"}, places={"a_1"})


def test_boxes_distance_and_top():
    turn = yawed(30.0) @ DOWN_ALONG_Y.T  # a rotation about the vertical by 30 degrees
    boxes = Boxes(
        centre=np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 1.0]]),
        rot=np.stack([np.eye(3), turn]),
        half=np.array([[0.1, 0.2, 0.3], [0.1, 0.1, 0.1]]),
    )
    np.testing.assert_allclose(boxes.top(), [1.3, 1.1])
    d = boxes.distance(np.array([[0.0, 0.0, 1.0], [0.0, 0.5, 1.0], [1.0, 0.0, 1.25]]))
    assert d.shape == (3, 2)
    np.testing.assert_allclose(d[:, 0], [0.0, 0.3, 0.9], atol=1e-12)
    np.testing.assert_allclose(d[2, 1], 0.15, atol=1e-12)
    assert Boxes.concat([]).centre.shape == (0, 3) and len(Boxes.concat([boxes, boxes])) == 4


def test_axis_angle_and_yaw():
    assert np.allclose(axis_angle_of(np.eye(3)), 0.0)
    R = yawed(45.0) @ DOWN_ALONG_Y.T
    np.testing.assert_allclose(axis_angle_of(R), [0.0, 0.0, np.pi / 4], atol=1e-9)
    half_turn = np.diag([-1.0, -1.0, 1.0])
    aa = axis_angle_of(half_turn)
    assert np.isclose(np.linalg.norm(aa), np.pi) and np.allclose(np.abs(aa), [0, 0, np.pi])
    np.testing.assert_allclose(yawed(0.0), DOWN_ALONG_Y)


def test_expert_validates_noise_and_needs_a_reset():
    with pytest.raises(ValueError, match="noise"):
        SpatialExpert(noise=-0.1)
    with pytest.raises(RuntimeError, match="reset"):
        SpatialExpert()(None)


def test_decimation_keeps_each_faces_texture_coordinates():
    from gazereg.envs.libero.render import decimate_with_texcoords

    # two triangles sharing an edge, plus a sliver whose corners all fall into one grid cube
    vert = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [0.001, 0, 0], [0, 0.001, 0]], float)
    face = np.array([[0, 1, 2], [1, 3, 2], [0, 4, 5]])
    tex = np.array([[10, 11, 12], [13, 14, 15], [16, 17, 18]])
    v, f, t, kept = decimate_with_texcoords(vert, face, tex, cell=0.01)
    assert len(v) == 4 and f.shape == (2, 3) and kept.tolist() == [0, 1]
    np.testing.assert_array_equal(t, tex[:2])
    np.testing.assert_allclose(v[f[0]][:, :2].sum(), 2.0005, atol=1e-3)  # the merged corner is the mean
    _, _, none, _ = decimate_with_texcoords(vert, face, None, cell=0.01)
    assert none is None


def test_quaternion_to_axis_angle_matches_the_rotation():
    from gazereg.envs.libero.scene import quat_xyzw_to_axis_angle

    half = np.radians(90) / 2  # 90 degrees about z
    np.testing.assert_allclose(
        quat_xyzw_to_axis_angle(np.array([0, 0, np.sin(half), np.cos(half)])), [0, 0, np.pi / 2], atol=1e-12
    )
    np.testing.assert_array_equal(quat_xyzw_to_axis_angle(np.array([0.0, 0.0, 0.0, 1.0])), np.zeros(3))


def test_camera_names_and_aliases_resolve_to_ids():
    mujoco = pytest.importorskip("mujoco")
    from gazereg.envs.libero.render import camera_ids

    model = mujoco.MjModel.from_xml_string(
        "<mujoco><worldbody><camera name='agentview'/><camera name='robot0_eye_in_hand'/></worldbody></mujoco>"
    )
    assert camera_ids(model, ("agentview_rgb", "wrist", "agentview")) == {
        "agentview_rgb": 0,
        "wrist": 1,
        "agentview": 0,
    }
    with pytest.raises(KeyError, match="no camera 'side'.*'agentview', 'robot0_eye_in_hand'"):
        camera_ids(model, ("side",))


def test_clear_transients_zeroes_what_a_soft_reset_keeps():
    from types import SimpleNamespace

    from gazereg.envs.libero.setup import clear_transients

    goals = []
    robot = SimpleNamespace(
        gripper=SimpleNamespace(current_action=np.ones(2)),
        controller=SimpleNamespace(reset_goal=lambda: goals.append(1)),
    )
    fields = ("ctrl", "act", "qacc_warmstart", "qfrc_applied", "xfrc_applied")
    data = SimpleNamespace(**{name: np.ones(3) for name in fields})
    clear_transients(SimpleNamespace(robots=[robot]), data)
    assert not robot.gripper.current_action.any() and goals == [1]
    assert all(not getattr(data, name).any() for name in fields)
