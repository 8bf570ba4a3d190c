"""The obstacle manager's search area (managers/obstacle_zone.py): its shape along straight and
curved trajectories, the bands of ARES §3.5.3 with hand-computed limits, and noise."""
from __future__ import annotations

import math

import numpy as np
import pytest

from managers.obstacle_zone import ObstacleParams, judge, occupied_cells, zone_for

P = ObstacleParams()
WIDTH, BUMPER = 2.0, 3.4           # body width; front bumper ahead of the rear axle


def blob(x: float, y: float) -> tuple[np.ndarray, np.ndarray]:
    """An obstacle of four 0.2 m cells around (x, y)."""
    return np.array([x, x + 0.2, x, x + 0.2]), np.array([y, y, y + 0.2, y + 0.2])


def test_the_area_grows_with_speed_and_narrows_with_distance():
    assert zone_for(P, 4.0, 0.0, WIDTH, BUMPER).length_m == pytest.approx(10.0)      # ARES: 10 m at 4 m/s
    assert zone_for(P, 0.5, 0.0, WIDTH, BUMPER).length_m == P.min_length_m
    zone = zone_for(P, 4.0, 0.0, WIDTH, BUMPER)
    assert zone.half_width(np.array([0.0, 10.0])).tolist() == pytest.approx([1.3, 1.05])
    # beside the body near the bumper it counts; as far to the side at the far end it does not
    near, _ = zone.contains(np.array([BUMPER + 0.5]), np.array([1.25]))
    far, _ = zone.contains(np.array([BUMPER + 9.5]), np.array([1.25]))
    assert near[0] and not far[0]


@pytest.mark.parametrize("ahead,band,limit", [
    (None, "clear", 4.0),
    (9.5, "ready", 4.0),
    (7.0, "slow", 4.0 * (0.7 - 0.5) / 0.4),
    (5.5, "slow", 4.0 * (0.55 - 0.5) / 0.4),
    (3.0, "stop", 0.0),
])
def test_the_bands_of_the_paper(ahead, band, limit):
    zone = zone_for(P, 4.0, 0.0, WIDTH, BUMPER)
    x, y = blob(BUMPER + ahead, -0.1) if ahead is not None else (np.zeros(0), np.zeros(0))
    verdict = judge(P, zone, x, y, 4.0)
    assert verdict.band == band and verdict.limit_mps == pytest.approx(limit, abs=0.06)
    if ahead is not None:
        assert verdict.nearest_m == pytest.approx(ahead, abs=0.01) and verdict.share == pytest.approx(ahead / 10, abs=0.01)


def test_the_area_follows_the_arc_the_wheels_are_turned_to():
    radius = 12.0
    left_turn = zone_for(P, 4.0, 1.0 / radius, WIDTH, BUMPER)
    # a point on the arc 5 m past the bumper, and the point straight ahead at the same distance
    a = (BUMPER + 5.0) / radius
    on_arc = (radius * math.sin(a), radius * (1 - math.cos(a)))
    inside, s = left_turn.contains(np.array([on_arc[0], BUMPER + 5.0]), np.array([on_arc[1], 0.0]))
    assert inside.tolist() == [True, False] and s[0] == pytest.approx(5.0)
    right_turn = zone_for(P, 4.0, -1.0 / radius, WIDTH, BUMPER)
    inside, _ = right_turn.contains(np.array([on_arc[0]]), np.array([-on_arc[1]]))
    assert inside[0]
    # the outline's first corner: the near half-width left of the arc's point at the bumper
    a = BUMPER / radius
    bumper_on_arc = np.array([radius * math.sin(a), radius * (1 - math.cos(a))])
    first = np.array(left_turn.outline()[0])
    assert np.hypot(*(first - bumper_on_arc)) == pytest.approx(1.3)
    assert left_turn.contains(np.array([first[0] + 0.05 * math.sin(a)]), np.array([first[1] - 0.05 * math.cos(a)]))[0][0]


def test_a_stray_cell_is_not_an_obstacle_and_walls_beside_a_narrow_lane_are_none():
    zone = zone_for(P, 4.0, 0.0, WIDTH, BUMPER)
    assert judge(P, zone, np.array([BUMPER + 2.0]), np.array([0.0]), 4.0).band == "clear"
    # walls 1.6 m each side (the tour's 3.2 m lane) from the bumper to 12 m ahead
    x = np.arange(0.0, 15.0, 0.2)
    walls_x, walls_y = np.r_[x, x], np.r_[np.full(len(x), 1.6), np.full(len(x), -1.6)]
    assert judge(P, zone, walls_x, walls_y, 4.0).band == "clear"


def test_occupied_cells_are_read_from_the_grid():
    cells = np.zeros((4, 5), dtype=np.uint8)
    cells[1, 3] = 100
    cells[2, 0] = 255           # unknown: not an obstacle
    x, y = occupied_cells(cells, -1.0, -0.4, 0.2)
    assert x.tolist() == pytest.approx([-0.3]) and y.tolist() == pytest.approx([-0.1])


# ---- the node ------------------------------------------------------------------------------------

def test_the_node_stops_for_what_stays_and_not_for_one_grid(run_config):
    from ares.clock import ManualClock
    from ares.membus import MemoryNetwork
    from ares.messages import CarState, DriveMode, OccupancyGrid
    from managers.obstacle import ObstacleManager

    clock, network = ManualClock(), MemoryNetwork()
    node = ObstacleManager(run_config, clock=clock, bus=network.bus("obstacle_manager", clock))
    node.setup()
    bus = network.bus("test", clock)
    states = bus.subscribe("obstacle/state")
    events = bus.subscribe("events", queue=100)

    def step(t: float, obstacle_at: float | None):
        clock.set(t)
        cells = np.zeros((100, 100), dtype=np.uint8)
        if obstacle_at is not None:                 # a pedestrian on the path, 0.4 m square
            col = int((node.bumper_m + obstacle_at + 8.6) / 0.2)
            cells[49:51, col:col + 2] = 100
        bus.publish("perception/grid", OccupancyGrid(t=t, frame="vehicle", resolution_m=0.2, origin_x=-8.6,
                                                     origin_y=-10.0, cells=cells))
        bus.publish("dbw/car_state", CarState(t=t, mode=DriveMode.AUTOMATIC, engaged=True, watchdog_tripped=False,
                                              setpoint_age_s=0.05, v_command=3.0, kappa_command=0.0, speed_mps=3.0,
                                              steering_wheel_deg=0.0, reason=""))
        node.step_once(t)
        return states.latest

    assert step(0.1, None).band == "clear"
    once = step(0.2, 2.0)                           # one grid: be ready, no braking yet
    assert once.band == "ready" and once.limit_mps == node.vehicle.max_speed_mps and once.nearest_m == pytest.approx(2.0, abs=0.2)
    assert step(0.3, None).limit_mps == node.vehicle.max_speed_mps
    step(0.4, 2.0)
    stays = step(0.5, 2.0)
    assert stays.band == "stop" and stays.limit_mps == 0.0 and stays.score < 0.5
    assert len(stays.area_x) == len(stays.area_y) > 4
    assert step(0.6, None).band == "clear"           # gone: the higher of the two limits, at once
    kinds = [(e.kind, e.message) for _, e in events.drain()]
    assert [k for k, _ in kinds] == ["obstacle_stop", "obstacle_stop"] and "m ahead (4 cells)" in kinds[0][1]
