"""Seeded test scenarios: the drawing rule of the README, determinism, and the solvability check."""

from __future__ import annotations

import numpy as np
import pytest

from sim import layout as L
from sim.scenarios import CLEARANCE, LAMP_BOTTOM_RANGE, MIN_BOWL_SOURCE, MIN_MOVE, Scenario, draw_scenario

SEEDS = range(3)


@pytest.fixture(scope="module")
def reach():
    from sim.reach import DumpReach
    with DumpReach("powder") as r:
        yield r


@pytest.fixture(scope="module")
def powder(reach):
    return [draw_scenario("powder", s, reach=reach) for s in SEEDS]


def _in_square(xy) -> bool:
    return bool(np.all(np.abs(np.asarray(xy) - L.SQUARE_CENTER_XY) <= L.SQUARE_HALF + 1e-12))


def _dist_to_line(pt, a, b) -> float:
    a, b, pt = (np.asarray(v, dtype=float) for v in (a, b, pt))
    d = b - a
    s = np.clip(np.dot(pt - a, d) / np.dot(d, d), 0, 1)
    return float(np.linalg.norm(a + s * d - pt))


def test_same_seed_same_scenario_with_or_without_a_shared_check(reach, powder):
    assert draw_scenario("powder", 2).to_dict() == powder[2].to_dict()
    assert draw_scenario("powder", 2, reach=reach).to_dict() == powder[2].to_dict()
    assert len({str(sc.to_dict()["placements"]) for sc in powder}) == len(powder)


def test_powder_scenarios_follow_the_drawing_rule(powder):
    source = np.asarray(L.SOURCE_DEFAULT_XY)
    towel_r, bowl_r = L.PAPER_TOWELS_RADIUS, L.BOWL_RADIUS + L.BOWL_WALL
    for sc in powder:
        bowl, after = np.asarray(sc.placements["bowl"]), np.asarray(sc.bowl_after)
        assert _in_square(bowl) and _in_square(after)
        assert np.linalg.norm(after - bowl) >= MIN_MOVE
        assert min(np.linalg.norm(bowl - source), np.linalg.norm(after - source)) >= MIN_BOWL_SOURCE
        towels = np.asarray(sc.placements["paper_towels"])
        assert _dist_to_line(towels, source, bowl) <= 0.04 + 1e-9      # on the carrying line
        for b in (bowl, after):
            assert np.linalg.norm(towels - b) >= towel_r + bowl_r + CLEARANCE - 1e-9
        lamp = np.asarray(sc.placements["lamp_shade"])
        assert _dist_to_line(lamp[:2], source, bowl) <= 0.05 + 1e-9
        assert LAMP_BOTTOM_RANGE[0] <= lamp[2] - L.TABLE_TOP_Z <= LAMP_BOTTOM_RANGE[1]
        assert sc.move_at == 0.25 and sc.move_step(24) == 6 and sc.move_step(48) == 12 and sc.move_step(25) == 6
        assert sum(k.startswith("marker_") for k in sc.placements) == 4


def test_pour_scenarios_place_the_other_landmarks_and_do_not_move_the_bowl():
    sc = draw_scenario("pour", 0)
    assert sc.bowl_after is None and sc.move_at is None and sc.move_step(48) is None
    assert {"bowl", "paper_towels", "lamp_shade", "vase", "scissors", "spoon"} <= set(sc.placements)


def test_a_pour_scene_gets_a_bowl_move_by_the_powders_rule_and_a_powder_scene_keeps_its_own(powder):
    from sim.reach import DumpReach
    from sim.scenarios import ITEM_RADIUS, with_bowl_move

    assert with_bowl_move(powder[0]) is powder[0]
    source = np.asarray(L.SOURCE_DEFAULT_XY)
    bowl_r = L.BOWL_RADIUS + L.BOWL_WALL
    with DumpReach("pour") as reach:
        for seed in (0, 1):
            sc = draw_scenario("pour", seed, reach=reach)
            moved = with_bowl_move(sc, reach)
            assert moved.to_dict() == with_bowl_move(sc, reach).to_dict()  # seeded by the scene
            assert moved.placements == sc.placements and moved.move_at == 0.25
            after, bowl = np.asarray(moved.bowl_after), np.asarray(sc.placements["bowl"])
            assert _in_square(after) and np.linalg.norm(after - bowl) >= MIN_MOVE
            assert np.linalg.norm(after - source) >= MIN_BOWL_SOURCE
            for name, r in (("paper_towels", L.PAPER_TOWELS_RADIUS), ("vase", L.VASE_RADIUS),
                            ("scissors", ITEM_RADIUS), ("spoon", ITEM_RADIUS)):
                assert np.linalg.norm(after - np.asarray(sc.placements[name][:2])) >= r + bowl_r + CLEARANCE - 1e-9
            assert reach(sc.placements, after)
        with pytest.raises(ValueError, match="reach checks the 'pour' task"):
            with_bowl_move(Scenario(task="powder", seed=0, placements=dict(sc.placements)), reach)


def test_dump_reach_refuses_a_bowl_under_a_low_obstacle_and_accepts_it_in_the_open(reach):
    bowl = (0.82, 0.35)
    assert reach({}, bowl)
    # the lamp shade lowered over the bowl: its rim 8 cm above the table, no tool fits in between
    blocked = {"lamp_shade": (bowl[0], bowl[1], L.TABLE_TOP_Z + 0.08)}
    assert not reach(blocked, bowl)
    assert reach({}, bowl)  # and nothing of the blocked scene stays behind


def test_bad_scenario_arguments(reach):
    with pytest.raises(ValueError, match="task must be"):
        draw_scenario("soup", 0)
    with pytest.raises(ValueError, match="reach checks the 'powder' task"):
        draw_scenario("pour", 0, reach=reach)
    with pytest.raises(ValueError, match="bowl_after and move_at are given together"):
        Scenario(task="powder", seed=0, bowl_after=(0.8, 0.3))
    with pytest.raises(ValueError, match="bowl_after and move_at are given together"):
        Scenario(task="powder", seed=0, move_at=0.25)
    for bad in (-0.1, 1.0, float("nan")):
        with pytest.raises(ValueError, match="move_at is a share of the task"):
            Scenario(task="powder", seed=0, bowl_after=(0.8, 0.3), move_at=bad)
    sc = Scenario(task="powder", seed=0, bowl_after=(0.8, 0.3), move_at=0.5)
    assert sc.move_step(np.int64(24)) == 12 and sc.move_step(1) == 0
    for bad in (0, 2.5, True):
        with pytest.raises(ValueError, match="time_steps must be a whole number"):
            sc.move_step(bad)


def test_a_scene_whose_objects_touch_the_arms_start_is_not_drawn():
    """Pour scenario 24 once put the vase against the forearm of the start configuration (every
    plan: 'start_in_collision'); such scenes are redrawn."""
    from sim.reach import DumpReach
    with DumpReach("pour") as r:
        open_scene = {"bowl": (0.56, 0.22)}
        assert r.start_free(open_scene)
        assert not r.start_free({**open_scene, "vase": (0.468, 0.7245)})
        assert r.start_free(open_scene)  # nothing of the blocked scene stays behind
        assert r.start_free(draw_scenario("pour", 24, reach=r).placements)
