"""Pure pursuit (control/pure_pursuit.py) on the path manager's path ahead, the speed profile it
carries, and the two nodes together on the in-memory bus."""

import math

import numpy as np
import pytest

from ares.core import config
from ares.core.clock import ManualClock
from ares.core.config import load_vehicle
from ares.core.membus import MemoryNetwork
from ares.core.messages import Pose
from ares.core.route import Route
from control.pure_pursuit import ControllerParams, PurePursuit, goal_point
from control.pure_pursuit_node import PurePursuitNode
from managers.path import PathIndex, PathManagerParams
from managers.path_node import PathManager
from managers.speed import SpeedProfileParams, cruise_speed, speed_limits, speed_profile

PARAMS = PathManagerParams()
CONTROLLER = ControllerParams()
SPEED = SpeedProfileParams()
VEHICLE = config.load_vehicle("ares_shuttle")


@pytest.fixture(scope="module")
def tour():
    return Route.from_tour("default")


@pytest.fixture(scope="module")
def tour_index(tour):
    return PathIndex(tour, PARAMS, speed_limits(tour, SPEED, VEHICLE))


def pursue(pp, index, x, y, yaw, v, hint=None):
    """What the path manager and the controller do together, without the bus."""
    m = index.match(x, y, yaw, s_hint=hint)
    ahead = index.ahead(m.index, PARAMS.ahead_length_m, PARAMS.ahead_step_m, s=m.s)
    distance_to_end = None if index.route.closed else max(index.route.length - m.s, 0.0)
    return m, pp.command(x, y, yaw, v, ahead.x, ahead.y, ahead.speed, distance_to_end)


def test_speed_profile_respects_curves_braking_and_vehicle_limits(tour):
    p = SPEED
    cruise = cruise_speed(p, VEHICLE, tour)
    assert cruise == tour.speed_limit_mps == 3.5  # the tour's limit, under the vehicle's 4 m/s
    v = speed_profile(tour, cruise, p.lateral_accel_mps2, p.decel_mps2, p.accel_mps2, p.narrow_speed_mps)
    assert v.max() <= cruise + 1e-9
    lateral = v**2 * np.abs(tour.curvature)
    assert lateral.max() <= p.lateral_accel_mps2 * 1.05
    ds = np.diff(tour.s)
    dv2 = np.diff(v**2) / (2 * ds)
    assert dv2.min() >= -p.decel_mps2 - 1e-6 and dv2.max() <= p.accel_mps2 + 1e-6
    narrow = (tour.s >= 60) & (tour.s <= 200)
    assert v[narrow].max() <= p.narrow_speed_mps + 1e-9
    assert np.array_equal(speed_limits(tour, p, VEHICLE), v)


def test_the_top_speed_is_the_lowest_of_road_limit_configured_cap_and_vehicle_maximum(tour):
    assert speed_limits(tour, SPEED.model_copy(update={"cruise_speed_mps": 2.0}), VEHICLE).max() == pytest.approx(2.0)
    campus = Route.from_tour("campus")
    assert campus.speed_limit_mps == pytest.approx(6.94)
    assert speed_limits(campus, SPEED, VEHICLE).max() == pytest.approx(VEHICLE.max_speed_mps)  # 4 m/s
    assert speed_limits(campus, SPEED, load_vehicle("techs4agecar")).max() == pytest.approx(6.94)  # 25 km/h


def test_open_route_profile_stops_at_the_end(tmp_path):
    path = tmp_path / "line.csv"
    path.write_text("0,0\n100,0\n")
    route = Route.from_csv(path)
    v = speed_profile(route, 3.0, 0.5, 0.5, 0.5)
    assert v[-1] == 0.0 and v[len(v) // 2] == pytest.approx(3.0)


def test_curvature_points_the_vehicle_back_to_the_route(tour, tour_index):
    pp = PurePursuit(CONTROLLER, VEHICLE)
    x, y, _, yaw = tour.point_at(400.0)  # a straight
    m_left, left = pursue(pp, tour_index, x - math.sin(yaw) * 0.5, y + math.cos(yaw) * 0.5, yaw, 2.0)
    m_right, right = pursue(pp, tour_index, x + math.sin(yaw) * 0.5, y - math.cos(yaw) * 0.5, yaw, 2.0)
    assert left.kappa < 0 < right.kappa  # steer right when left of the path
    assert m_left.xte > 0 > m_right.xte
    # the speed target is the limit at the match
    assert left.v == pytest.approx(np.interp(m_left.s, tour.s, tour_index.speed_limit), abs=1e-3)
    assert left.lookahead_m == pytest.approx(CONTROLLER.lookahead_min_m + CONTROLLER.lookahead_gain_s * 2.0)


def test_on_a_circle_pure_pursuit_commands_its_curvature():
    r = 40.0
    a = np.linspace(0, 2 * math.pi, 2000, endpoint=False)
    route = Route("circle", r * np.cos(a), r * np.sin(a), np.zeros_like(a), True, np.full(a.shape, 6.0))
    index = PathIndex(route, PARAMS, np.full(len(route), 2.0))
    pp = PurePursuit(CONTROLLER, VEHICLE)
    _, cmd = pursue(pp, index, r, 0.0, math.pi / 2, 2.0)
    assert cmd.kappa == pytest.approx(1 / r, rel=0.02)
    assert cmd.v == pytest.approx(2.0)


def test_curvature_is_clamped_to_the_vehicle(tour, tour_index):
    pp = PurePursuit(CONTROLLER, VEHICLE)
    x, y, _, yaw = tour.point_at(400.0)
    ahead = tour_index.ahead(tour.index_at(400.0), 30.0, 0.5, s=400.0)
    cmd = pp.command(x, y, yaw + math.pi / 2, 1.0, ahead.x, ahead.y, ahead.speed)  # facing across the road
    assert abs(cmd.kappa) == pytest.approx(math.tan(VEHICLE.max_wheel_angle_rad) / VEHICLE.wheelbase_m)


def test_with_an_uncertain_heading_it_creeps_along_the_paths_curvature(tour, tour_index):
    """At start-up the heading is the magnetometer's offset guess: steering from it would turn a
    phantom heading error into a real one. The controller follows the path's curvature, slowly."""
    pp = PurePursuit(CONTROLLER, VEHICLE)
    x, y, _, yaw = tour.point_at(400.0)
    ahead = tour_index.ahead(tour.index_at(400.0), 30.0, 0.5, s=400.0)
    guessed_yaw = yaw + 0.12  # the paper's calibration offset
    unsure = pp.command(
        x,
        y,
        guessed_yaw,
        0.0,
        ahead.x,
        ahead.y,
        ahead.speed,
        heading_sigma=pp.max_heading_sigma * 2,
        ahead_curvature=ahead.curvature,
    )
    assert unsure.kappa == pytest.approx(ahead.curvature[0])
    assert unsure.v == pytest.approx(min(ahead.speed[0], pp.creep_speed))
    sure = pp.command(
        x,
        y,
        guessed_yaw,
        0.0,
        ahead.x,
        ahead.y,
        ahead.speed,
        heading_sigma=pp.max_heading_sigma / 2,
        ahead_curvature=ahead.curvature,
    )
    assert sure.kappa < ahead.curvature[0] - 0.02  # it steers back against the believed error
    assert sure.v == pytest.approx(ahead.speed[0])


def test_the_goal_point_is_interpolated_along_the_path_ahead():
    xs, ys = [0.0, 1.0, 1.0, 1.0], [0.0, 0.0, 1.0, 2.0]  # an L: 1 m east, then north
    assert goal_point(xs, ys, 0.5) == pytest.approx((0.5, 0.0))
    assert goal_point(xs, ys, 1.75) == pytest.approx((1.0, 0.75))
    assert goal_point(xs, ys, 10.0) == (1.0, 2.0)  # beyond the end: the end itself
    assert goal_point([3.0], [4.0], 2.0) == (3.0, 4.0)


def test_an_open_route_is_finished_half_a_metre_before_its_end(tmp_path):
    path = tmp_path / "line.csv"
    path.write_text("0,0\n50,0\n")
    route = Route.from_csv(path)
    index = PathIndex(route, PARAMS, speed_limits(route, SPEED, VEHICLE))
    pp = PurePursuit(CONTROLLER, VEHICLE)
    _, near = pursue(pp, index, 49.0, 0.1, 0.0, 0.5)
    assert not near.finished and near.kappa < 0  # still steering onto the line, aiming at the end
    _, done = pursue(pp, index, 49.6, 0.1, 0.0, 0.3)
    assert done.finished and done.v == 0.0 and done.kappa == 0.0


def test_the_finish_distance_is_a_parameter(tmp_path):
    path = tmp_path / "line.csv"
    path.write_text("0,0\n50,0\n")
    route = Route.from_csv(path)
    index = PathIndex(route, PARAMS, speed_limits(route, SPEED, VEHICLE))
    pp = PurePursuit(CONTROLLER.model_copy(update={"finish_distance_m": 2.0}), VEHICLE)
    _, done = pursue(pp, index, 48.5, 0.1, 0.0, 0.5)
    assert done.finished and done.v == 0.0


# ---- the path manager and the controller as nodes ----------------------------------------------


def pose_at(x, y, yaw, t, v=2.0, var_yaw=1e-4) -> Pose:
    return Pose(
        t=t,
        x=x,
        y=y,
        z=0.0,
        yaw=yaw,
        v=v,
        yaw_rate=0.0,
        cov_xx=1e-4,
        cov_xy=0.0,
        cov_yy=1e-4,
        var_yaw=var_yaw,
        var_v=1e-4,
        position_std_m=0.01,
        rtk=True,
        gnss_age_s=0.1,
    )


class PathAndController:
    """The path manager and the controller on one in-memory network, a test process feeding
    them poses; each period steps the path manager, then the controller."""

    PERIOD = 0.05

    def __init__(self, cfg):
        self.clock = ManualClock()
        self.network = MemoryNetwork()
        self.path = PathManager(cfg, clock=self.clock, bus=self.network.bus("path_manager", self.clock))
        self.controller = PurePursuitNode(cfg, clock=self.clock, bus=self.network.bus("pure_pursuit", self.clock))
        self.path.setup()
        self.controller.setup()
        self.bus = self.network.bus("test", self.clock)
        self.setpoints = self.bus.subscribe("control/candidate/pure_pursuit", queue=1000)

    def step(self, t, pose: Pose | None = None):
        self.clock.set(t)
        if pose is not None:
            self.bus.publish("localization/pose", pose)
        self.path.step_once(t)
        self.controller.step_once(t)

    def new_setpoints(self):
        return [sp for _, sp in self.setpoints.drain()]


def test_controller_follows_the_path_manager_and_stops_without_fresh_input(run_config, tour):
    """A pose gives a candidate; no fresh pose (so no fresh path match either) gives no candidate
    at all, which the control manager never forwards."""
    nodes = PathAndController(run_config)
    x, y, _, yaw = tour.point_at(400.0)
    ox, oy = x - math.sin(yaw) * 0.5, y + math.cos(yaw) * 0.5  # half a metre left of the path
    times = [round(k * nodes.PERIOD, 9) for k in range(30)]
    for t in times:
        nodes.step(t, pose_at(ox, oy, yaw, t))
    got = nodes.new_setpoints()
    assert len(got) == len(times)  # one setpoint a period
    assert all(sp.kappa < 0 and sp.v > 0 and sp.controller == "pure_pursuit" for sp in got)
    assert got[-1].cross_track_m == pytest.approx(0.5, abs=0.01) and got[-1].fresh and not got[-1].handover
    # the same command the geometry gives without the bus
    _, alone = pursue(
        PurePursuit(CONTROLLER, VEHICLE),
        PathIndex(tour, PARAMS, speed_limits(tour, SPEED, VEHICLE)),
        ox,
        oy,
        yaw,
        2.0,
        hint=400.0,
    )
    assert (got[-1].v, got[-1].kappa) == pytest.approx((alone.v, alone.kappa), rel=1e-6)
    # the poses stop: within input_timeout_s of the last one the controller still steers ...
    last = times[-1]
    nodes.step(round(last + CONTROLLER.input_timeout_s - nodes.PERIOD, 9))
    assert len(nodes.new_setpoints()) == 1
    # ... then the pose, and with it the path match, is stale: silence
    for k in range(1, 12):
        nodes.step(round(last + CONTROLLER.input_timeout_s + k * nodes.PERIOD, 9))
    assert nodes.new_setpoints() == []


def test_controller_is_silent_without_a_path_match(run_config, tour):
    nodes = PathAndController(run_config)
    far_x, far_y, _, yaw = tour.point_at(400.0)
    for k in range(5):  # 80 m beside the road: the path manager finds nothing to match
        t = round(k * nodes.PERIOD, 9)
        nodes.step(t, pose_at(far_x - math.sin(yaw) * 80.0, far_y + math.cos(yaw) * 80.0, yaw, t))
    assert nodes.new_setpoints() == []
