"""The obstacle manager's search area (managers/obstacle.py): its shape along straight and
curved trajectories, the bands of ARES §3.5.3 with hand-computed limits, and noise."""

from __future__ import annotations

import math

import numpy as np
import pytest

from managers.obstacle import ObstacleParams, judge, occupied_cells, zone_for

P = ObstacleParams()
WIDTH, BUMPER = 2.0, 3.4  # body width; front bumper ahead of the rear axle


def blob(x: float, y: float) -> tuple[np.ndarray, np.ndarray]:
    """An obstacle of four 0.2 m cells around (x, y)."""
    return np.array([x, x + 0.2, x, x + 0.2]), np.array([y, y, y + 0.2, y + 0.2])


def test_the_area_grows_with_speed_and_narrows_with_distance():
    assert zone_for(P, 4.0, 0.0, WIDTH, BUMPER).length_m == pytest.approx(10.0)  # ARES: 10 m at 4 m/s
    assert zone_for(P, 0.5, 0.0, WIDTH, BUMPER).length_m == P.min_length_m
    zone = zone_for(P, 4.0, 0.0, WIDTH, BUMPER)
    assert zone.half_width(np.array([0.0, 10.0])).tolist() == pytest.approx([1.3, 1.05])
    # beside the body near the bumper it counts; as far to the side at the far end it does not
    near, _ = zone.contains(np.array([BUMPER + 0.5]), np.array([1.25]))
    far, _ = zone.contains(np.array([BUMPER + 9.5]), np.array([1.25]))
    assert near[0] and not far[0]


@pytest.mark.parametrize(
    "ahead,band,limit",
    [
        (None, "clear", 4.0),
        (9.5, "ready", 4.0),
        (7.0, "slow", 4.0 * (0.7 - 0.5) / 0.4),
        (5.5, "slow", 4.0 * (0.55 - 0.5) / 0.4),
        (3.0, "stop", 0.0),
    ],
)
def test_the_bands_of_the_paper(ahead, band, limit):
    zone = zone_for(P, 4.0, 0.0, WIDTH, BUMPER)
    x, y = blob(BUMPER + ahead, -0.1) if ahead is not None else (np.zeros(0), np.zeros(0))
    verdict = judge(P, zone, x, y, 4.0)
    assert verdict.band == band and verdict.limit_mps == pytest.approx(limit, abs=0.06)
    if ahead is not None:
        assert verdict.nearest_m == pytest.approx(ahead, abs=0.01) and verdict.share == pytest.approx(
            ahead / 10, abs=0.01
        )


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
    assert left_turn.contains(np.array([first[0] + 0.05 * math.sin(a)]), np.array([first[1] - 0.05 * math.cos(a)]))[0][
        0
    ]


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
    cells[2, 0] = 255  # unknown: not an obstacle
    x, y = occupied_cells(cells, -1.0, -0.4, 0.2)
    assert x.tolist() == pytest.approx([-0.3]) and y.tolist() == pytest.approx([-0.1])


# ---- the node ------------------------------------------------------------------------------------


def test_the_node_stops_for_what_stays_and_not_for_one_grid(run_config):
    from ares.core.clock import ManualClock
    from ares.core.membus import MemoryNetwork
    from ares.core.messages import CarState, DriveMode, OccupancyGrid
    from managers.obstacle_node import ObstacleManager

    clock, network = ManualClock(), MemoryNetwork()
    node = ObstacleManager(run_config, clock=clock, bus=network.bus("obstacle_manager", clock))
    node.setup()
    bus = network.bus("test", clock)
    states = bus.subscribe("obstacle/state")
    events = bus.subscribe("events", queue=100)

    def step(t: float, obstacle_at: float | None):
        clock.set(t)
        cells = np.zeros((100, 100), dtype=np.uint8)
        if obstacle_at is not None:  # a pedestrian on the path, 0.4 m square
            col = int((node.bumper_m + obstacle_at + 8.6) / 0.2)
            cells[49:51, col : col + 2] = 100
        bus.publish(
            "perception/grid",
            OccupancyGrid(t=t, frame="vehicle", resolution_m=0.2, origin_x=-8.6, origin_y=-10.0, cells=cells),
        )
        bus.publish(
            "dbw/car_state",
            CarState(
                t=t,
                mode=DriveMode.AUTOMATIC,
                engaged=True,
                watchdog_tripped=False,
                setpoint_age_s=0.05,
                v_command=3.0,
                kappa_command=0.0,
                speed_mps=3.0,
                steering_wheel_deg=0.0,
                reason="",
            ),
        )
        node.step_once(t)
        return states.latest

    assert step(0.1, None).band == "clear"
    once = step(0.2, 2.0)  # one grid: be ready, no braking yet
    assert (
        once.band == "ready"
        and once.limit_mps == node.vehicle.max_speed_mps
        and once.nearest_m == pytest.approx(2.0, abs=0.2)
    )
    assert step(0.3, None).limit_mps == node.vehicle.max_speed_mps
    step(0.4, 2.0)
    stays = step(0.5, 2.0)
    assert stays.band == "stop" and stays.limit_mps == 0.0 and stays.score < 0.5
    assert len(stays.area_x) == len(stays.area_y) > 4
    assert step(0.6, None).band == "clear"  # gone: the higher of the two limits, at once
    kinds = [(e.kind, e.message) for _, e in events.drain()]
    assert [k for k, _ in kinds] == ["obstacle_stop", "obstacle_stop"] and "m ahead (4 cells)" in kinds[0][1]


def test_along_the_path_ahead_the_area_bends_with_a_lane_the_arc_leaves():
    # the wheels straight, the lane bending left on a 15 m radius from the bumper on: along the arc
    # the outer wall comes into the area; along the path ahead it stays beside it
    radius = 15.0
    s = np.arange(-1.0, 25.0, 0.5)
    bend = np.clip(s - BUMPER, 0.0, None) / radius
    straight = np.minimum(s, BUMPER)
    path = np.column_stack([straight + radius * np.sin(bend), radius * (1 - np.cos(bend))])
    # walls 1.6 m either side of that lane, every 0.2 m
    fine = np.arange(0.0, 25.0, 0.2)
    fb = np.clip(fine - BUMPER, 0.0, None) / radius
    cx, cy = np.minimum(fine, BUMPER) + radius * np.sin(fb), radius * (1 - np.cos(fb))
    nx, ny = -np.sin(fb), np.cos(fb)
    walls_x, walls_y = np.r_[cx + 1.6 * nx, cx - 1.6 * nx], np.r_[cy + 1.6 * ny, cy - 1.6 * ny]
    along_arc = zone_for(P, 4.0, 0.0, WIDTH, BUMPER)
    along_path = zone_for(P, 4.0, 0.0, WIDTH, BUMPER, centre=path)
    assert judge(P, along_arc, walls_x, walls_y, 4.0).band in ("slow", "stop")
    assert judge(P, along_path, walls_x, walls_y, 4.0).band == "clear"
    # and a pedestrian on the lane's centre 5 m past the bumper is found along the path, 5 m ahead
    k = int(np.argmin(np.abs(fine - (BUMPER + 5.0))))
    verdict = judge(P, along_path, *blob(cx[k], cy[k]), 4.0)
    assert verdict.band in ("slow", "stop") and verdict.nearest_m == pytest.approx(4.8, abs=0.3)


@pytest.mark.parametrize("mode, yaw_std", [("odometry", 0.01), ("rrc", 0.01), ("odometry", 0.3)])
def test_the_node_lays_the_area_along_the_path_only_while_a_path_follower_drives_on_a_sure_heading(
    run_config, mode, yaw_std
):
    from ares.core.clock import ManualClock
    from ares.core.membus import MemoryNetwork
    from ares.core.messages import CarState, ControllerStatus, DriveMode, OccupancyGrid, PathMatch, Pose
    from managers.obstacle_node import ObstacleManager

    clock, network = ManualClock(), MemoryNetwork()
    node = ObstacleManager(run_config, clock=clock, bus=network.bus("obstacle_manager", clock))
    node.setup()
    bus = network.bus("test", clock)
    states = bus.subscribe("obstacle/state")
    t = 0.1
    clock.set(t)
    # the shuttle at (100, 50) facing north (local frame); the path ahead turns left (west) on 15 m
    a = np.arange(0.0, 30.0, 0.5) / 15.0
    ahead_x, ahead_y = 100.0 - 15.0 * (1 - np.cos(a)), 50.0 + 15.0 * np.sin(a)
    bus.publish(
        "perception/grid",
        OccupancyGrid(
            t=t,
            frame="vehicle",
            resolution_m=0.2,
            origin_x=-8.6,
            origin_y=-10.0,
            cells=np.zeros((100, 100), dtype=np.uint8),
        ),
    )
    bus.publish(
        "dbw/car_state",
        CarState(
            t=t,
            mode=DriveMode.AUTOMATIC,
            engaged=True,
            watchdog_tripped=False,
            setpoint_age_s=0.05,
            v_command=3.0,
            kappa_command=0.0,
            speed_mps=3.0,
            steering_wheel_deg=0.0,
            reason="",
        ),
    )
    bus.publish(
        "localization/pose",
        Pose(
            t=t,
            x=100.0,
            y=50.0,
            z=0.0,
            yaw=math.pi / 2,
            v=3.0,
            yaw_rate=0.0,
            cov_xx=1e-4,
            cov_xy=0.0,
            cov_yy=1e-4,
            var_yaw=yaw_std**2,
            var_v=1e-4,
            position_std_m=0.01,
            rtk=True,
            gnss_age_s=0.1,
        ),
    )
    bus.publish(
        "path/match",
        PathMatch(
            t=t,
            index=0,
            s=0.0,
            lap=0,
            xte=0.0,
            heading_error=0.0,
            zones=[],
            force_odometry=False,
            distance_to_end_m=None,
            ahead_x=ahead_x.tolist(),
            ahead_y=ahead_y.tolist(),
            ahead_yaw=[0.0] * len(a),
            ahead_curvature=[0.0] * len(a),
            ahead_speed=[3.0] * len(a),
            ahead_s=(a * 15.0).tolist(),
        ),
    )
    bus.publish(
        "control/status",
        ControllerStatus(
            t=t,
            controller="mpc" if mode == "odometry" else "rrc",
            mode=mode,
            reason="",
            s=0.0,
            xte=0.0,
            heading_error=0.0,
            target_speed=3.0,
        ),
    )
    node.step_once(t)
    area = states.latest
    far_end_y = (area.area_y[len(area.area_y) // 2 - 1] + area.area_y[len(area.area_y) // 2]) / 2
    if mode == "odometry" and yaw_std < 0.03:  # bent to the left with the path (its far end well left)
        assert far_end_y > 1.5
    else:  # along the arc, and the wheels are straight: straight ahead
        assert abs(far_end_y) < 1e-6


def test_the_bench_counts_each_area_and_layout_in_the_narrow_lane():
    from ares.tools.bench.obstacle_zone import run_obstacle_zone_bench

    out = run_obstacle_zone_bench(step_m=35.0)  # 4 frames of the 70 the README's figures come from
    assert out["frames"] == 4 and out["area_length_m"] == 10.0
    for name in ("trapezoid", "rectangle", "trapezoid_arc", "rectangle_arc"):
        assert sum(out[f"{name}_bands"].values()) == 4
    assert out["trapezoid_false_stops"] == out["trapezoid_false_slows"] == 0
