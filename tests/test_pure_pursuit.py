import math
import time

import numpy as np
import pytest

from ares import config
from ares.route import Route
from control.pure_pursuit import PurePursuit, goal_point, speed_profile
from control.speed_profile import speed_limits
from control.speed_profile import speed_profile as speed_profile_here
from managers.path import PathIndex

CFG = config.build_run_config()
PARAMS = CFG["path_manager"]


@pytest.fixture(scope="module")
def tour():
    return Route.from_tour("default")


@pytest.fixture(scope="module")
def tour_index(tour):
    return PathIndex.from_config(tour, PARAMS, speed_limits(tour, CFG["controller"], CFG["vehicle_profile"]))


def pursue(pp, index, x, y, yaw, v, hint=None):
    """What the path manager and the controller do together, without the bus."""
    m = index.match(x, y, yaw, s_hint=hint)
    ahead = index.ahead(m.index, PARAMS["ahead_length_m"], PARAMS["ahead_step_m"], s=m.s)
    distance_to_end = None if index.route.closed else max(index.route.length - m.s, 0.0)
    return m, pp.command(x, y, yaw, v, ahead.x, ahead.y, ahead.speed, distance_to_end)


def test_speed_profile_respects_curves_braking_and_vehicle_limits(tour):
    assert speed_profile is speed_profile_here          # moved, still importable from here
    p = CFG["controller"]
    v = speed_profile(tour, p["cruise_speed_mps"], p["lateral_accel_mps2"], p["decel_mps2"],
                      p["accel_mps2"], p["narrow_speed_mps"])
    assert v.max() <= p["cruise_speed_mps"] + 1e-9
    lateral = v ** 2 * np.abs(tour.curvature)
    assert lateral.max() <= p["lateral_accel_mps2"] * 1.05
    ds = np.diff(tour.s)
    dv2 = np.diff(v ** 2) / (2 * ds)
    assert dv2.min() >= -p["decel_mps2"] - 1e-6 and dv2.max() <= p["accel_mps2"] + 1e-6
    narrow = (tour.s >= 60) & (tour.s <= 200)
    assert v[narrow].max() <= p["narrow_speed_mps"] + 1e-9
    assert np.array_equal(speed_limits(tour, p, CFG["vehicle_profile"]), v)   # cruise under the vehicle's max


def test_open_route_profile_stops_at_the_end(tmp_path):
    path = tmp_path / "line.csv"
    path.write_text("0,0\n100,0\n")
    route = Route.from_csv(path)
    v = speed_profile(route, 3.0, 0.5, 0.5, 0.5)
    assert v[-1] == 0.0 and v[len(v) // 2] == pytest.approx(3.0)


def test_curvature_points_the_vehicle_back_to_the_route(tour, tour_index):
    pp = PurePursuit(CFG["controller"], CFG["vehicle_profile"])
    x, y, _, yaw = tour.point_at(400.0)                  # a straight
    m_left, left = pursue(pp, tour_index, x - math.sin(yaw) * 0.5, y + math.cos(yaw) * 0.5, yaw, 2.0)
    m_right, right = pursue(pp, tour_index, x + math.sin(yaw) * 0.5, y - math.cos(yaw) * 0.5, yaw, 2.0)
    assert left.kappa < 0 < right.kappa                  # steer right when left of the path
    assert m_left.xte > 0 > m_right.xte
    # the speed target is the limit at the match
    assert left.v == pytest.approx(np.interp(m_left.s, tour.s, tour_index.speed_limit), abs=1e-3)
    params = CFG["controller"]
    assert left.lookahead_m == pytest.approx(params["lookahead_min_m"] + params["lookahead_gain_s"] * 2.0)


def test_on_a_circle_pure_pursuit_commands_its_curvature():
    r = 40.0
    a = np.linspace(0, 2 * math.pi, 2000, endpoint=False)
    route = Route("circle", r * np.cos(a), r * np.sin(a), np.zeros_like(a), True, np.full(a.shape, 6.0))
    index = PathIndex.from_config(route, PARAMS, np.full(len(route), 2.0))
    pp = PurePursuit(CFG["controller"], CFG["vehicle_profile"])
    _, cmd = pursue(pp, index, r, 0.0, math.pi / 2, 2.0)
    assert cmd.kappa == pytest.approx(1 / r, rel=0.02)
    assert cmd.v == pytest.approx(2.0)


def test_curvature_is_clamped_to_the_vehicle(tour, tour_index):
    pp = PurePursuit(CFG["controller"], CFG["vehicle_profile"])
    x, y, _, yaw = tour.point_at(400.0)
    ahead = tour_index.ahead(tour.index_at(400.0), 30.0, 0.5, s=400.0)
    cmd = pp.command(x, y, yaw + math.pi / 2, 1.0, ahead.x, ahead.y, ahead.speed)   # facing across the road
    vp = CFG["vehicle_profile"]
    assert abs(cmd.kappa) == pytest.approx(math.tan(vp["max_wheel_angle_rad"]) / vp["wheelbase_m"])


def test_with_an_uncertain_heading_it_creeps_along_the_paths_curvature(tour, tour_index):
    """At start-up the heading is the magnetometer's offset guess: steering from it would turn a
    phantom heading error into a real one. The controller follows the path's curvature, slowly."""
    pp = PurePursuit(CFG["controller"], CFG["vehicle_profile"])
    x, y, _, yaw = tour.point_at(400.0)
    ahead = tour_index.ahead(tour.index_at(400.0), 30.0, 0.5, s=400.0)
    guessed_yaw = yaw + 0.12                                   # the paper's calibration offset
    unsure = pp.command(x, y, guessed_yaw, 0.0, ahead.x, ahead.y, ahead.speed,
                        heading_sigma=pp.max_heading_sigma * 2, ahead_curvature=ahead.curvature)
    assert unsure.kappa == pytest.approx(ahead.curvature[0])
    assert unsure.v == pytest.approx(min(ahead.speed[0], pp.creep_speed))
    sure = pp.command(x, y, guessed_yaw, 0.0, ahead.x, ahead.y, ahead.speed,
                      heading_sigma=pp.max_heading_sigma / 2, ahead_curvature=ahead.curvature)
    assert sure.kappa < ahead.curvature[0] - 0.02               # it steers back against the believed error
    assert sure.v == pytest.approx(ahead.speed[0])


def test_the_goal_point_is_interpolated_along_the_path_ahead():
    xs, ys = [0.0, 1.0, 1.0, 1.0], [0.0, 0.0, 1.0, 2.0]      # an L: 1 m east, then north
    assert goal_point(xs, ys, 0.5) == pytest.approx((0.5, 0.0))
    assert goal_point(xs, ys, 1.75) == pytest.approx((1.0, 0.75))
    assert goal_point(xs, ys, 10.0) == (1.0, 2.0)             # beyond the end: the end itself
    assert goal_point([3.0], [4.0], 2.0) == (3.0, 4.0)


def test_an_open_route_is_finished_half_a_metre_before_its_end(tmp_path):
    path = tmp_path / "line.csv"
    path.write_text("0,0\n50,0\n")
    route = Route.from_csv(path)
    index = PathIndex.from_config(route, PARAMS, speed_limits(route, CFG["controller"], CFG["vehicle_profile"]))
    pp = PurePursuit(CFG["controller"], CFG["vehicle_profile"])
    _, near = pursue(pp, index, 49.0, 0.1, 0.0, 0.5)
    assert not near.finished and near.kappa < 0             # still steering onto the line, aiming at the end
    _, done = pursue(pp, index, 49.6, 0.1, 0.0, 0.3)
    assert done.finished and done.v == 0.0 and done.kappa == 0.0


@pytest.mark.stack
def test_controller_follows_the_path_manager_and_stops_without_fresh_input(router, spawn_node, tour):
    """Path manager + controller as real processes: a pose gives a setpoint; no fresh pose
    (so no fresh path match either) gives no setpoint at all."""
    from ares.bus import Bus
    from ares.clock import Clock
    from ares.messages import Pose
    bus = Bus(router, "test", Clock())
    setpoints = bus.subscribe("control/setpoint", queue=500)
    status = bus.subscribe("control/status")
    spawn_node("managers.path", "path_manager")
    spawn_node("control.pure_pursuit", "controller")
    deadline = time.monotonic() + 20.0
    while not bus.alive_processes(0.3) >= {"path_manager", "controller"}:
        assert time.monotonic() < deadline, "the nodes did not come up"
        time.sleep(0.1)
    x, y, _, yaw = tour.point_at(400.0)
    ox, oy = x - math.sin(yaw) * 0.5, y + math.cos(yaw) * 0.5    # half a metre left of the path
    try:
        until = time.monotonic() + 1.5
        while time.monotonic() < until:
            bus.publish("localization/pose", Pose(
                t=bus.clock.now(), x=ox, y=oy, z=0.0, yaw=yaw, v=2.0, yaw_rate=0.0, cov_xx=1e-4, cov_xy=0.0,
                cov_yy=1e-4, var_yaw=1e-4, var_v=1e-4, position_std_m=0.01, rtk=True, gnss_age_s=0.1))
            time.sleep(0.05)
        got = [m for _, m in setpoints.drain()]
        assert len(got) >= 5
        assert all(sp.kappa < 0 and sp.v > 0 for sp in got)
        assert status.latest.s == pytest.approx(400.0, abs=0.1) and status.latest.xte == pytest.approx(0.5, abs=0.01)
        time.sleep(1.0)                                       # pose, then path match go stale
        setpoints.drain()
        time.sleep(0.6)
        assert setpoints.drain() == []
    finally:
        bus.close()
