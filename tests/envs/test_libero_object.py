"""LIBERO-Object's expert geometry, its registration and its presets: pure logic, no LIBERO needed (the expert
in the simulator: tests/envs/test_libero.py, slow, in the LIBERO venv)."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from gazereg.envs.collect_config import collect_seeds
from gazereg.envs.libero.collector import EXPERTS, LiberoCollector, make_expert
from gazereg.envs.libero.expert import SpatialExpert, yawed
from gazereg.envs.libero.expert_object import YAWS, ItemShape, ObjectExpert, ObjectParams, closing_axes
from gazereg.envs.libero.scene import Boxes, TaskRoles
from gazereg.evaluation.config import presets as eval_presets
from gazereg.experiment.config import PRESETS
from gazereg.experiment.demos import demo_collections
from gazereg.experiment.runner import Experiment


def box(centre, half, yaw_deg=0.0) -> Boxes:
    """One box (centre (3,), half sizes (3,)) turned by `yaw_deg` about the vertical."""
    c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return Boxes(np.array([centre], dtype=float), rot[None], np.array([half], dtype=float))


def test_box_corners_and_an_items_footprint():
    b = box([0.1, 0.2, 0.03], [0.04, 0.02, 0.03], yaw_deg=90.0)  # long along world y once turned
    corners = b.corners()
    assert corners.shape == (8, 3)
    np.testing.assert_allclose(corners.min(axis=0), [0.08, 0.16, 0.0], atol=1e-12)
    np.testing.assert_allclose(corners.max(axis=0), [0.12, 0.24, 0.06], atol=1e-12)
    shape = ItemShape.of(b)
    assert (shape.bottom, shape.top) == pytest.approx((0.0, 0.06))
    # yaw 0 closes along world y (DOWN_ALONG_Y): the long side; yaw 90 along x: the short side
    assert shape.footprint(0)[0] == pytest.approx(0.08) and shape.footprint(90)[0] == pytest.approx(0.04)
    np.testing.assert_allclose(shape.footprint(45)[1], [0.1, 0.2], atol=1e-12)
    a, perp = closing_axes(30.0)
    np.testing.assert_allclose(yawed(30.0)[:2, 0], a, atol=1e-12)  # the gripper's closing axis (x column)
    assert abs(a @ perp) < 1e-12


def test_a_box_is_taken_across_and_a_tall_neighbour_turns_the_palm_away():
    ex = ObjectExpert()
    cheese = ItemShape.of(box([0.0, 0.0, 0.01], [0.02, 0.04, 0.01]))  # long along y
    yaw, centre = ex._choose_yaw(cheese, pad=0.016, boxes=Boxes.concat([]))
    assert yaw == 90.0 and ex.grasp_choice["width"] == pytest.approx(0.04)
    np.testing.assert_allclose(centre, [0.0, 0.0], atol=1e-12)

    can = ItemShape.of(box([0.0, 0.0, 0.038], [0.031, 0.031, 0.038]))
    assert ex._choose_yaw(can, pad=0.06, boxes=Boxes.concat([]))[0] == 0.0  # nothing in the way: no turn
    # A carton 0.13 m tall whose near side is 0.08 m from the can along y: the open fingers (0.048 m out) miss
    # it, the palm (0.105 m out along the closing axis, 0.02 m above the pads) does not, unless turned.
    carton = box([0.0, 0.1, 0.065], [0.025, 0.02, 0.065])
    yaw, _ = ex._choose_yaw(can, pad=0.06, boxes=carton)
    assert abs(yaw) >= 45.0 and yaw in YAWS


class FakeFacts:
    """What `ObjectExpert._plan` reads of a scene: the item's and the container's collision boxes."""

    def __init__(self, item: Boxes, basket: Boxes):
        self._boxes = {"bottle_1": item, "basket_1": basket}

    def geom_boxes(self, name: str) -> Boxes:
        return self._boxes[name]

    def owner(self, name: str) -> str:
        return "basket_1" if name == "basket_1_contain_region" else name


def test_a_tall_bottle_is_taken_below_its_top_and_released_just_above_the_basket_floor():
    p = ObjectParams()
    bottle = box([0.0, -0.1, 0.073], [0.018, 0.026, 0.073])  # 0.146 m tall, origin at its middle
    floor = box([0.0, 0.25, 0.01], [0.07, 0.07, 0.01])  # top at 0.02
    wall = box([0.075, 0.25, 0.07], [0.005, 0.07, 0.07])  # top at 0.14
    env = SimpleNamespace(
        scene_facts=FakeFacts(bottle, Boxes.concat([floor, wall])),
        roles=TaskRoles("bottle_1", "basket_1_contain_region", "in"),
    )
    pts = {"obj": np.array([0.0, -0.1, 0.073]), "goal": np.array([0.0, 0.25, 0.067])}
    plan = ObjectExpert()._plan(env, pts, Boxes.concat([]))
    pad = pts["obj"][2] + plan.offset[2]
    assert pad == pytest.approx(0.146 - p.palm_room)  # the palm stays above the cap, not at mid-height
    assert plan.hang == pytest.approx(pad) and plan.hand_above == pytest.approx(plan.offset[2])
    # lowered until the origin is place_dz above the goal point: the bottom is release_gap above the floor
    bottom_at_release = pts["goal"][2] + plan.place_dz - 0.073
    assert bottom_at_release == pytest.approx(0.02 + p.release_gap)
    # across its narrow side (0.036 m along x: yaw 90)
    np.testing.assert_allclose(plan.rot, yawed(90.0))


def test_each_suite_gets_its_expert_and_others_are_refused():
    assert isinstance(make_expert("libero_object", 0.1), ObjectExpert)
    assert type(make_expert("libero_spatial")) is SpatialExpert
    assert make_expert("libero_object", 0.1).noise == 0.1
    assert LiberoCollector.suites == tuple(EXPERTS)
    assert tuple(EXPERTS) == ("libero_spatial", "libero_object", "libero_goal", "libero_10")
    with pytest.raises(ValueError, match="no scripted LIBERO expert for 'libero_90'"):
        make_expert("libero_90")
    with pytest.raises(ValueError, match="puts an object 'in' another"):
        ObjectExpert().reset(
            SimpleNamespace(roles=TaskRoles("a_1", "plate_1", "on"), task="libero_spatial/0")
        )


@pytest.mark.parametrize(
    ("suite", "steps"), [("libero_object", 280), ("libero_goal", 300), ("libero_10", 520)]
)
def test_the_libero_suite_presets(suite, steps):
    """`libero_object`, `libero_goal` and `libero_10`: LIBERO-Spatial's experiment over the suite's tasks, its evaluation
    length, a folder of its own; demonstrations never on an evaluation setup."""
    ev = eval_presets()[f"{suite.replace('_', '-')}-25"]()
    assert ev.tasks == tuple(f"{suite}/{k}" for k in range(10))
    assert (ev.env, ev.seed_start, ev.episodes, ev.max_steps) == ("libero", 25, 25, steps)
    cfg = PRESETS[suite]()
    assert cfg.tasks == ev.tasks and cfg.eval.max_steps == cfg.demo_max_steps == steps
    assert cfg.out == Path(f"runs/{suite}") and cfg.demo_max_failures == 0
    # the same experiment as LIBERO-Spatial's but for the suite (tasks, evaluation length, folder)
    spatial = PRESETS["libero"]()
    assert cfg.arms == spatial.arms and cfg.train == spatial.train and cfg.glc_folds[1] == ev.tasks[5:]
    exp = Experiment(cfg)
    demo_seeds = set(collect_seeds(demo_collections(cfg, exp.out)["train"]))
    ecfg = exp.eval_config("eval", {})
    for condition in ecfg.conditions:
        assert not demo_seeds & set(ecfg.seeds(condition)), condition
    assert max(demo_seeds) < min(ecfg.seeds("clean"))


def test_libero_demonstrations_may_take_as_long_as_the_evaluation_and_reach_the_collector():
    """LIBERO-Object's expert needs up to ~230 steps (docs/benchmarks/libero_object_expert.json), more than the
    collector's default of LIBERO-Spatial's 220: each suite's demonstrations get its evaluation's length."""
    for name in ("libero", "libero_object"):
        cfg = PRESETS[name]()
        assert cfg.demo_max_steps == cfg.eval.max_steps
        assert {c.max_steps for c in demo_collections(cfg, cfg.out).values()} == {cfg.eval.max_steps}
    assert PRESETS["quick"]().demo_max_steps == 0  # Meta-World: the simulator's default
