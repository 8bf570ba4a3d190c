import math

import numpy as np
import pytest

from ares import config
from ares.route import Route
from control.pure_pursuit import PurePursuit, speed_profile

CFG = config.build_run_config()


@pytest.fixture(scope="module")
def tour():
    return Route.from_tour("default")


def test_speed_profile_respects_curves_braking_and_vehicle_limits(tour):
    p = CFG["controller"]
    v = speed_profile(tour, p["cruise_speed_mps"], p["lateral_accel_mps2"], p["decel_mps2"],
                      p["accel_mps2"], p["narrow_speed_mps"])
    assert v.max() <= p["cruise_speed_mps"] + 1e-9
    lateral = v ** 2 * np.abs(tour.curvature)
    assert lateral.max() <= p["lateral_accel_mps2"] * 1.05
    ds = np.diff(tour.s)
    dv2 = np.diff(v ** 2) / (2 * ds)
    assert dv2.min() >= -p["decel_mps2"] - 1e-6 and dv2.max() <= p["accel_mps2"] + 1e-6


def test_open_route_profile_stops_at_the_end(tmp_path):
    path = tmp_path / "line.csv"
    path.write_text("0,0\n100,0\n")
    route = Route.from_csv(path)
    v = speed_profile(route, 3.0, 0.5, 0.5, 0.5)
    assert v[-1] == 0.0 and v[len(v) // 2] == pytest.approx(3.0)


def test_curvature_points_the_vehicle_back_to_the_route(tour):
    pp = PurePursuit(tour, CFG["controller"], CFG["vehicle_profile"])
    x, y, _, yaw = tour.point_at(400.0)                  # a straight
    left = pp.command(x - math.sin(yaw) * 0.5, y + math.cos(yaw) * 0.5, yaw, 2.0)
    pp.s_hint = None
    right = pp.command(x + math.sin(yaw) * 0.5, y - math.cos(yaw) * 0.5, yaw, 2.0)
    assert left.kappa < 0 < right.kappa                  # steer right when left of the path
    assert left.xte > 0 > right.xte


def test_on_a_circle_pure_pursuit_commands_its_curvature():
    r = 40.0
    a = np.linspace(0, 2 * math.pi, 2000, endpoint=False)
    route = Route("circle", r * np.cos(a), r * np.sin(a), np.zeros_like(a), True, np.full(a.shape, 6.0))
    pp = PurePursuit(route, CFG["controller"], CFG["vehicle_profile"])
    cmd = pp.command(r, 0.0, math.pi / 2, 2.0)
    assert cmd.kappa == pytest.approx(1 / r, rel=0.02)


def test_curvature_is_clamped_to_the_vehicle(tour):
    pp = PurePursuit(tour, CFG["controller"], CFG["vehicle_profile"])
    x, y, _, yaw = tour.point_at(400.0)
    cmd = pp.command(x, y, yaw + math.pi / 2, 1.0)      # facing across the road
    vp = CFG["vehicle_profile"]
    assert abs(cmd.kappa) == pytest.approx(math.tan(vp["max_wheel_angle_rad"]) / vp["wheelbase_m"])
