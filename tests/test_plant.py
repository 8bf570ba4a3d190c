"""Vehicle simulator physics and the drive-by-wire inner PID.

The step-response figures are the DBW paper's (§5.1). Tolerances: times within 20 % of the
paper, overshoot within 35 % (the paper reports 4.73 % for both loads; in a physical plant
the overshoot moves with the load, see the report in ares/core/config/vehicles/*.yaml).
"""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from ares.app import run_config
from ares.core import config
from ares.core.config import ConfigError, VehicleProfile
from ares.core.messages import CanFrame
from ares.core.route import SAMPLE_SPACING_M, Route
from ares.tools.harness.step_response import PID_PERIOD_S, measure_step, step_response
from control.dbw_bridge import BridgeLoop, DbwBridgeParams
from control.dbw_bridge import Event as BridgeEvent
from control.pid import PID
from simulator.actuators import GRAVITY, TractionActuator
from simulator.params import SimParams
from simulator.vehicle import (
    BLEND_HIGH_MPS,
    BLEND_LOW_MPS,
    PHYSICS_DT,
    LateralParams,
    VehiclePlant,
    VehicleState,
    lateral_step,
    start_pose,
)

VEHICLES = ["techs4agecar", "ares_shuttle"]
TICKS = round(PID_PERIOD_S / PHYSICS_DT)
SMOOTH_ROAD = SimParams(road_roughness_m=0.0)


def _close(value: float, target: float, rel: float) -> bool:
    return abs(value - target) <= rel * abs(target)


def straight_route(length_m: float = 400.0, grade: float = 0.0) -> Route:
    """An open straight road along x that climbs at a constant grade."""
    x = np.arange(0.0, length_m + SAMPLE_SPACING_M / 2, SAMPLE_SPACING_M)
    return Route(name="straight", x=x, y=np.zeros_like(x), z=grade * x, closed=False, width=np.full(len(x), 6.0))


class SpeedLoop:
    """The board's throttle loop as the DBW paper tuned it: 10 Hz PID on the drive-wheel speed (the
    bridge adds the command's steady effort to it: the feed-forward's tests are at the end)."""

    def __init__(self, plant: VehiclePlant):
        self.plant = plant
        self.pid = PID.from_gains(plant.profile.dbw_pid.throttle)
        self.k = 0
        self.effort = 0.0

    def step(self, v_ref: float, steer_effort: float = 0.0):
        if self.k % TICKS == 0:
            st = self.plant.state
            ref = v_ref / (math.cos(st.wheel_angle_rad) * self.plant.wheel_radius_m)
            self.effort = self.pid.step(ref, st.wheel_speed_rad_s, PID_PERIOD_S)
        self.k += 1
        return self.plant.step(steer_effort, self.effort)


# ---- PID ---------------------------------------------------------------------------------------


def test_pid_is_the_papers_equations():
    pid = PID(kp=2.0, ki=0.5, kd=0.0, out_min=-100, out_max=100)
    assert pid.step(10.0, 4.0, 0.1) == pytest.approx(2.0 * 6 + 0.5 * 6 * 0.1)  # eqs. 4-8
    assert pid.step(10.0, 6.0, 0.1) == pytest.approx(2.0 * 4 + 0.5 * (6 + 4) * 0.1)


def test_pid_output_is_clamped_and_integral_does_not_wind_up():
    pid = PID(kp=0.1, ki=1.0)
    for _ in range(200):  # 20 s saturated at full effort
        assert pid.step(100.0, 0.0, 0.1) == 1.0
    assert pid.integral <= 1.0
    # Once the error reverses the output must leave saturation at once, not after the
    # integral has unwound 20 s worth of error.
    assert pid.step(0.0, 5.0, 0.1) < 1.0
    assert pid.step(0.0, 5.0, 0.1) < 0.9


def test_pid_derivative_on_measurement_does_not_kick_on_reference_steps():
    pid = PID(kp=0.0, ki=0.0, kd=1.0, out_min=-1e9, out_max=1e9)
    pid.step(0.0, 0.0, 0.1)
    assert pid.step(50.0, 0.0, 0.1) == 0.0  # reference jump: no kick
    assert pid.step(50.0, 1.0, 0.1) == pytest.approx(-10.0)  # measurement moved up 1 in 0.1 s
    on_error = PID(kp=0.0, kd=1.0, out_min=-1e9, out_max=1e9, derivative_on_measurement=False)
    on_error.step(0.0, 0.0, 0.1)
    assert on_error.step(50.0, 0.0, 0.1) == pytest.approx(500.0)


def test_pid_reset_forgets_the_integral():
    pid = PID(kp=0.0, ki=1.0)
    pid.step(1.0, 0.0, 0.1)
    pid.reset()
    assert pid.integral == 0.0 and pid.step(0.0, 0.0, 0.1) == 0.0


def test_pid_reset_can_start_the_integral_within_its_limit():
    pid = PID(kp=0.0, ki=1.0, integral_limit=0.5)
    pid.reset(integral=0.2)
    assert pid.step(0.0, 0.0, 0.1) == pytest.approx(0.2)
    pid.reset(integral=0.9)
    assert pid.integral == 0.5


def test_pid_rejects_bad_arguments():
    with pytest.raises(ValueError):
        PID(1.0, out_min=1.0, out_max=-1.0)
    with pytest.raises(ValueError):
        PID(1.0).step(1.0, 0.0, 0.0)


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.tuples(st.floats(-1e3, 1e3), st.floats(-1e3, 1e3)), min_size=1, max_size=40),
    st.floats(0.0, 5.0),
    st.floats(0.0, 5.0),
)
def test_pid_output_always_within_limits(samples, kp, ki):
    pid = PID(kp, ki, out_min=-0.5, out_max=0.8)
    for ref, meas in samples:
        u = pid.step(ref, meas, 0.1)
        assert -0.5 <= u <= 0.8
        assert abs(pid.integral) <= pid.integral_limit


# ---- step responses (DBW paper §5.1) --------------------------------------------------------------


@pytest.mark.parametrize("vehicle", VEHICLES)
def test_steering_step_matches_paper(vehicle):
    for step in (200.0, -200.0):  # the paper shows both directions of rotation
        r = step_response("steering", vehicle, step=step)
        assert _close(r.dead_time_s, 0.100, 0.20), r.summary()
        assert _close(r.rise_time_s, 0.650, 0.20), r.summary()
        assert _close(r.overshoot_pct, 3.92, 0.35), r.summary()
        assert abs(r.steady_state_error) <= 4.0, r.summary()
        assert r.steady_state_error != 0.0  # static friction leaves a real error


@pytest.mark.parametrize("vehicle", VEHICLES)
@pytest.mark.parametrize("passengers, rise, settling", [(2, 2.20, 4.80), (4, 2.39, 5.45)])
def test_throttle_step_matches_paper(vehicle, passengers, rise, settling):
    r = step_response("throttle", vehicle, passengers=passengers, step=3.0)
    assert _close(r.dead_time_s, 0.320, 0.20), r.summary()
    assert _close(r.rise_time_s, rise, 0.20), r.summary()
    assert _close(r.overshoot_pct, 4.73, 0.35), r.summary()
    assert _close(r.settling_time_s, settling, 0.20), r.summary()
    # The paper's steady-state error is +-20 deg/s of wheel speed (0.36 rad/s).
    assert abs(r.steady_state_error) < 0.35, r.summary()


@pytest.mark.parametrize("vehicle", VEHICLES)
def test_more_passengers_respond_slower(vehicle):
    two = step_response("throttle", vehicle, passengers=2)
    four = step_response("throttle", vehicle, passengers=4)
    assert four.rise_time_s > two.rise_time_s
    assert four.settling_time_s > two.settling_time_s


def test_step_response_loop_follows_the_dead_time_of_the_actuator():
    """The measured dead time is the plant's transport delay, not a property of the gains."""
    profile = config.load_vehicle("techs4agecar")
    slow = profile.actuators.traction.model_copy(update={"dead_time_s": 0.6})
    r = step_response("throttle", profile, actuator_params=slow, duration_s=14.0)
    assert 0.6 <= r.dead_time_s < 0.7


def test_measure_step_on_a_known_curve():
    t = np.arange(0.0, 20.0, 0.01)
    tau = 1.0
    y = np.where(t < 0.5, 0.0, 1.0 - np.exp(-(t - 0.5) / tau))  # first order + 0.5 s dead time
    m = measure_step(t, y, reference=1.0)
    assert m["dead_time_s"] == pytest.approx(0.5 + tau * -math.log(0.99), abs=0.02)
    assert m["rise_time_s"] == pytest.approx(0.5 + tau * math.log(10), abs=0.02)
    assert m["overshoot_pct"] < 1e-3
    assert m["settling_time_s"] == pytest.approx(0.5 + tau * math.log(50), abs=0.05)


# ---- actuators ---------------------------------------------------------------------------------


def test_steering_stops_at_the_rack_limit():
    profile = config.load_vehicle("techs4agecar")
    plant = VehiclePlant(straight_route(), profile, SimParams())
    limit = profile.steering_ratio * math.degrees(profile.max_wheel_angle_rad)
    for _ in range(500):
        plant.step(1.0, 0.0)
    assert plant.state.steering_wheel_deg == pytest.approx(limit)
    assert plant.state.wheel_angle_rad == pytest.approx(profile.max_wheel_angle_rad)
    for _ in range(100):  # and it can come back off the end stop
        plant.step(-1.0, 0.0)
    assert plant.state.steering_wheel_deg < limit - 100


def test_steering_effort_below_stiction_does_not_move_the_wheel():
    profile = config.load_vehicle("techs4agecar")
    plant = VehiclePlant(straight_route(), profile, SimParams())
    small = 0.9 * profile.actuators.steering.stiction_effort
    for _ in range(300):
        plant.step(small, 0.0)
    assert plant.state.steering_wheel_deg == 0.0


def test_traction_dead_time_is_a_pure_delay():
    profile = config.load_vehicle("ares_shuttle")
    act = TractionActuator(profile.actuators.traction, profile.empty_mass_kg, profile.passenger_mass_kg, 2)
    delay_steps = round(profile.actuators.traction.dead_time_s / PHYSICS_DT)
    for _ in range(delay_steps):
        assert act.step(1.0, PHYSICS_DT) == 0.0
    for _ in range(5):
        act.step(1.0, PHYSICS_DT)
    assert act.v > 0.0


@pytest.mark.parametrize("vehicle", VEHICLES)
@pytest.mark.parametrize("grade", [0.0, 0.14, -0.14])
def test_brake_never_drives_the_vehicle_backwards(vehicle, grade):
    plant = VehiclePlant(straight_route(grade=grade), vehicle, SMOOTH_ROAD, s0=10.0)
    loop = SpeedLoop(plant)
    for _ in range(1200):  # get to ~3 m/s
        loop.step(3.0)
    assert plant.state.v > 2.5
    speeds = []
    for _ in range(800):  # full brake for 8 s
        speeds.append(plant.step(0.0, -1.0).v)
    # After the traction dead time and ramp, the brake acts.
    speeds = np.array(speeds[40:])
    assert speeds.min() == 0.0  # it stops ...
    assert np.all(np.diff(speeds) <= 1e-12)  # ... slowing all the way ...
    assert np.all(speeds[np.argmax(speeds == 0.0) :] == 0.0)  # ... and stays stopped


@pytest.mark.parametrize("vehicle", VEHICLES)
def test_holds_on_a_14_percent_grade_with_the_brake_and_rolls_back_with_a_weak_throttle(vehicle):
    profile = config.load_vehicle(vehicle)
    plant = VehiclePlant(straight_route(grade=0.14), profile, SMOOTH_ROAD, passengers=profile.seats, s0=50.0)
    x0 = plant.state.x
    for _ in range(500):  # standing, throttle released: the parking brake holds
        assert plant.step(0.0, 0.0).v == 0.0
    for _ in range(500):  # and so does the service brake
        assert plant.step(0.0, -1.0).v == 0.0
    assert plant.state.x == x0
    for _ in range(300):  # a throttle too weak for the slope: gravity wins
        plant.step(0.0, 0.02)
    assert plant.state.v < -0.5 and plant.state.x < x0
    for _ in range(600):  # the brake stops the roll-back, and no further
        st = plant.step(0.0, -1.0)
        assert st.v <= 0.0
    assert st.v == 0.0


@pytest.mark.parametrize("vehicle", VEHICLES)
def test_climbs_a_14_percent_grade_fully_loaded(vehicle):
    profile = config.load_vehicle(vehicle)
    plant = VehiclePlant(straight_route(grade=0.14), profile, SMOOTH_ROAD, passengers=profile.seats, s0=10.0)
    loop = SpeedLoop(plant)
    for _ in range(2000):  # 20 s at a 3 m/s setpoint
        loop.step(3.0)
    st = plant.state
    assert st.v == pytest.approx(3.0, abs=0.15)
    assert st.grade == pytest.approx(0.14, abs=1e-6)
    assert st.z == pytest.approx(0.14 * st.x, abs=1e-6)  # on the road surface
    assert st.pitch == pytest.approx(-math.atan(0.14), abs=1e-9)  # REP-103: climbing = nose up = negative


# ---- the vehicle ---------------------------------------------------------------------------------


@pytest.mark.parametrize("vehicle", VEHICLES)
def test_every_packaged_vehicle_profile_loads(vehicle):
    profile = config.load_vehicle(vehicle)
    assert isinstance(profile, VehicleProfile) and profile.name == vehicle


def test_a_vehicle_profile_missing_a_key_is_refused_naming_it(tmp_path):
    data = config.load_yaml(config.named_file("vehicles", "ares_shuttle"))
    del data["wheelbase_m"]
    data["wheel_base_m"] = 2.8
    path = tmp_path / "broken_shuttle.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError) as info:
        config.load_vehicle(str(path))
    message = str(info.value)
    assert str(path) in message
    assert "wheelbase_m: required, missing" in message
    assert "wheel_base_m: unknown key (did you mean 'wheelbase_m'?)" in message


def test_a_vehicle_profile_with_a_value_out_of_range_is_refused_naming_it():
    with pytest.raises(ConfigError, match=r"actuators\.steering\.stiction_effort: .*less than 1"):
        config.load_vehicle("ares_shuttle", {"actuators": {"steering": {"stiction_effort": 1.5}}})


def test_an_unknown_sim_key_is_refused_naming_it():
    with pytest.raises(ConfigError, match=r"sim\.road_roughnes: unknown key \(did you mean 'road_roughness_m'\?\)"):
        run_config.build(overrides={"sim": {"road_roughnes": 0.0}})


def test_start_pose_is_on_the_route_facing_along_it():
    route = Route.from_tour("default")
    for s in (0.0, 333.3, 1200.0):
        plant = VehiclePlant(route, "ares_shuttle", SMOOTH_ROAD, s0=s)
        x, y, z, yaw = start_pose(route, s)
        st = plant.state
        assert (st.x, st.y, st.z, st.yaw) == pytest.approx((x, y, z, yaw))
        assert st.s == pytest.approx(s)
        assert st.v == 0.0 and st.steering_wheel_deg == 0.0


@pytest.mark.parametrize("vehicle", VEHICLES)
def test_bicycle_turns_on_a_circle_of_radius_wheelbase_over_tan_delta(vehicle):
    profile = config.load_vehicle(vehicle)
    plant = VehiclePlant(straight_route(), profile, SMOOTH_ROAD, s0=100.0)
    alpha = 300.0  # steering-wheel degrees
    for _ in range(600):  # hand on the wheel, gentle throttle
        plant.step_manual(0.12, 0.0, alpha, PHYSICS_DT)
    delta = math.radians(plant.state.steering_wheel_deg) / profile.steering_ratio
    assert plant.state.steering_wheel_deg == pytest.approx(alpha, abs=0.01)
    xs, ys = [], []
    for _ in range(3000):
        st = plant.step_manual(0.12, 0.0, alpha, PHYSICS_DT)
        xs.append(st.x)
        ys.append(st.y)
        assert st.yaw_rate == pytest.approx(st.v * math.tan(delta) / profile.wheelbase_m, rel=1e-3)
    # Least-squares circle through the rear-axle track: x^2 + y^2 + D x + E y + F = 0.
    xs, ys = np.array(xs), np.array(ys)
    A = np.column_stack([xs, ys, np.ones_like(xs)])
    D, E, F = np.linalg.lstsq(A, -(xs**2 + ys**2), rcond=None)[0]
    radius = math.sqrt(D * D / 4 + E * E / 4 - F)
    assert radius == pytest.approx(profile.wheelbase_m / math.tan(delta), rel=1e-3)
    assert D / -2 + 0 == pytest.approx(100.0, abs=0.5)  # centre to the left of the start
    assert E / -2 > 0


# ---- lateral dynamics: the dynamic bicycle and its blend into the kinematic one ----------


def _steady_yaw_rate(p: LateralParams, v: float, delta: float) -> float:
    """Hand-computed steady cornering of the linear bicycle: r = v δ / (L (1 + K v^2)),
    K = m / L^2 (l_r / C_f - l_f / C_r)."""
    wheelbase = p.l_f + p.l_r
    k = p.mass / wheelbase**2 * (p.l_r / p.c_f - p.l_f / p.c_r)
    return v * delta / (wheelbase * (1 + k * v * v))


@pytest.mark.parametrize("vehicle", VEHICLES)
@pytest.mark.parametrize("v", [3.5, 5.0, 6.9, 12.0])
def test_dynamic_bicycle_settles_on_the_understeer_gradient_yaw_rate(vehicle, v):
    profile = config.load_vehicle(vehicle)
    p = LateralParams.of(profile, profile.empty_mass_kg + 2 * profile.passenger_mass_kg)
    assert p.l_r / p.c_f > p.l_f / p.c_r  # the profiles understeer (K > 0) ...
    delta, v_y, r = 0.04, 0.0, 0.0
    for _ in range(1000):
        v_y, r = lateral_step(p, v_y, r, v, delta, PHYSICS_DT)
    assert r == pytest.approx(_steady_yaw_rate(p, v, delta), rel=1e-4)
    assert r < v * math.tan(delta) / (p.l_f + p.l_r)  # ... so they turn less than the kinematic bicycle
    # The rear tyres' slip angle makes the lateral force that holds the car on its circle.
    alpha_r = -(v_y - p.l_r * r) / v
    alpha_f = delta - (v_y + p.l_f * r) / v
    assert p.c_f * alpha_f + p.c_r * alpha_r == pytest.approx(p.mass * v * r, rel=1e-4)


@pytest.mark.parametrize("vehicle", VEHICLES)
def test_plant_corners_steadily_at_speed_on_the_dynamic_yaw_rate(vehicle):
    profile = config.load_vehicle(vehicle)
    plant = VehiclePlant(straight_route(2000.0), profile, SMOOTH_ROAD, s0=100.0)
    alpha = 100.0  # steering-wheel degrees, throttle held
    for _ in range(1500):
        st = plant.step_manual(0.45, 0.0, alpha, PHYSICS_DT)
    assert st.v > BLEND_HIGH_MPS + 1.0 and abs(st.accel) < 1e-3
    p = LateralParams.of(profile, plant.traction.mass_kg)
    delta = math.radians(alpha) / profile.steering_ratio
    assert st.yaw_rate == pytest.approx(_steady_yaw_rate(p, st.v, delta), rel=1e-3)
    assert st.lateral_velocity != pytest.approx(p.l_r * st.yaw_rate, rel=0.05)  # the rear axle slips
    assert st.lateral_accel == pytest.approx(st.v * st.yaw_rate, rel=1e-3)


@pytest.mark.parametrize("vehicle", VEHICLES)
def test_the_blend_into_the_kinematic_bicycle_is_continuous(vehicle):
    profile = config.load_vehicle(vehicle)
    p = LateralParams.of(profile, profile.empty_mass_kg)
    delta, v_y, r = 0.1, 0.0, 0.0
    # Below the blend: exactly the kinematic bicycle (rear axle without slip).
    v_y, r = lateral_step(p, v_y, r, 1.0, delta, PHYSICS_DT)
    assert r == pytest.approx(1.0 * math.tan(delta) / profile.wheelbase_m) and v_y == pytest.approx(p.l_r * r)
    # Speed ramping at 1 m/s^2 through the blend, steering held: no state jumps from one step
    # to the next, only the change the acceleration and the tyres' lag make.
    speeds = np.arange(BLEND_LOW_MPS - 0.5, BLEND_HIGH_MPS + 0.5, 1.0 * PHYSICS_DT)
    rs, v_ys = [], []
    for v in speeds:
        v_y, r = lateral_step(p, v_y, r, v, delta, PHYSICS_DT)
        rs.append(r)
        v_ys.append(v_y)
    step_r = np.abs(np.diff(rs))
    kinematic_step = PHYSICS_DT * math.tan(delta) / profile.wheelbase_m  # dr at 1 m/s^2, kinematic
    assert step_r.max() < 3 * kinematic_step
    assert np.abs(np.diff(v_ys)).max() < 3 * p.l_r * kinematic_step


@pytest.mark.parametrize("vehicle", VEHICLES)
def test_plant_accelerating_through_the_blend_has_no_jump(vehicle):
    profile = config.load_vehicle(vehicle)
    plant = VehiclePlant(straight_route(2000.0), profile, SMOOTH_ROAD, s0=100.0)
    rs, v_ys, vs = [], [], []
    for _ in range(1500):
        st = plant.step_manual(0.45, 0.0, 100.0, PHYSICS_DT)
        rs.append(st.yaw_rate)
        v_ys.append(st.lateral_velocity)
        vs.append(st.v)
    assert min(vs) < BLEND_LOW_MPS and max(vs) > BLEND_HIGH_MPS
    assert np.abs(np.diff(rs)).max() < 1e-3 and np.abs(np.diff(v_ys)).max() < 1e-3


@pytest.mark.parametrize("vehicle", VEHICLES)
def test_at_standstill_a_turned_steering_wheel_moves_nothing(vehicle):
    profile = config.load_vehicle(vehicle)
    p = LateralParams.of(profile, profile.empty_mass_kg)
    assert lateral_step(p, 0.0, 0.0, 0.0, 0.3, PHYSICS_DT) == (0.0, 0.0)
    plant = VehiclePlant(straight_route(), profile, SMOOTH_ROAD, s0=100.0)
    x0, y0, yaw0 = plant.state.x, plant.state.y, plant.state.yaw
    for _ in range(300):
        st = plant.step_manual(0.0, 1.0, 400.0, PHYSICS_DT)  # brake held, wheel turned
    assert st.steering_wheel_deg > 300 and st.v == 0.0
    assert (st.x, st.y, st.yaw) == pytest.approx((x0, y0, yaw0), abs=1e-12)
    assert st.yaw_rate == 0.0 and st.lateral_velocity == 0.0 and st.lateral_accel == 0.0


def test_route_progress_follows_the_pass_being_driven_through_the_crossing():
    """The tour crosses itself: s must run on through the intersection, not jump."""
    route = Route.from_tour("default")
    profile = config.load_vehicle("ares_shuttle")
    plant = VehiclePlant(route, profile, SMOOTH_ROAD, s0=460.0)
    L, ratio = profile.wheelbase_m, profile.steering_ratio
    s_track = [plant.state.s]
    for _ in range(3000):  # ~110 m at ~3.7 m/s, through s = 502..532
        st = plant.state
        gx, gy, _, _ = route.point_at(st.s + 5.0)  # pure pursuit by hand
        ang = math.atan2(gy - st.y, gx - st.x) - st.yaw
        ld = math.hypot(gx - st.x, gy - st.y)
        wheel = math.atan2(2.0 * L * math.sin(ang), ld)
        throttle = min(max(0.5 * (3.7 - st.v) + 0.35, 0.0), 1.0)
        plant.step_manual(throttle, 0.0, math.degrees(wheel) * ratio)
        s_track.append(plant.state.s)
        _, xte, _ = route.project(plant.state.x, plant.state.y, s_hint=plant.state.s)
        assert abs(xte) < 0.5
    s_track = np.array(s_track)
    assert s_track[-1] > 545.0
    assert np.all(np.diff(s_track) > -1e-6)
    assert np.all(np.diff(s_track) < 0.1)  # never jumps to the other pass
    assert plant.state.odometer == pytest.approx(s_track[-1] - 460.0, rel=0.01)


def test_elevation_and_grade_come_from_the_route():
    route = Route.from_tour("default")
    plant = VehiclePlant(route, "ares_shuttle", SMOOTH_ROAD, s0=200.0)
    loop = SpeedLoop(plant)
    for _ in range(500):
        loop.step(2.0)
    st = plant.state
    _, _, z_road, _ = route.point_at(st.s)
    assert st.z == pytest.approx(z_road, abs=1e-6)
    assert st.grade > 0.05  # on the climb from s=150 to 260
    # The accelerometer-free check of the pitch: standing on a climb pitches the nose up.
    assert st.pitch == pytest.approx(-math.atan(st.grade), abs=1e-9)


def test_manual_driving_pedals_and_steering_torque():
    plant = VehiclePlant(straight_route(), "techs4agecar", SimParams(), s0=10.0)
    st = plant.step_manual(0.5, 0.0, 90.0)
    assert st.manual and st.throttle_pedal == 0.5 and st.brake_pedal == 0.0
    assert st.steering_torque  # the hand leads the wheel
    for _ in range(400):
        st = plant.step_manual(0.5, 0.0, 90.0)
    assert st.steering_wheel_deg == pytest.approx(90.0, abs=0.1)
    assert not st.steering_torque  # holding the wheel still needs no torque
    assert st.v > 1.0
    for _ in range(800):  # brake pedal wins over the throttle pedal
        st = plant.step_manual(0.5, 1.0, 90.0)
    assert st.v == 0.0 and st.drive_effort == -1.0
    st = plant.step(0.0, 0.0)  # the board takes over again
    assert not st.manual and st.throttle_pedal == 0.0 and not st.steering_torque


def test_road_roughness_is_seeded_and_still_at_standstill():
    route = straight_route()

    def run(seed):
        plant = VehiclePlant(route, "ares_shuttle", SimParams(), seed=seed, s0=10.0)
        still = [plant.step(0.0, 0.0).vertical_accel for _ in range(100)]
        loop = SpeedLoop(plant)
        moving = [loop.step(3.0).vertical_accel for _ in range(1500)]
        return np.array(still), np.array(moving), plant.state

    still, moving, a = run(1)
    _, moving_again, b = run(1)
    _, moving_other, _ = run(2)
    assert np.all(still == 0.0)
    assert np.array_equal(moving, moving_again) and a == b
    assert not np.array_equal(moving, moving_other)
    rms = float(np.std(moving[500:]))
    assert 0.05 < rms < 1.0  # felt, but a small roughness


def test_plant_from_run_config():
    cfg = run_config.build(overrides={"vehicle": "techs4agecar", "sim": {"passengers": 3}})
    plant = VehiclePlant(straight_route(), config.core(cfg).vehicle_profile, config.section(cfg, "sim", SimParams))
    assert plant.passengers == 3
    assert plant.traction.mass_kg == pytest.approx(730 + 3 * 75)
    plant.passengers = 4
    assert plant.traction.mass_kg == pytest.approx(730 + 4 * 75)


def test_a_field_of_the_vehicle_profile_can_be_overridden_in_the_run_configuration():
    cfg = run_config.build(overrides={"sim": {"passengers": 0}, "vehicle_profile": {"empty_mass_kg": 3000.0}})
    plant = VehiclePlant(straight_route(), config.core(cfg).vehicle_profile, config.section(cfg, "sim", SimParams))
    assert plant.traction.mass_kg == pytest.approx(3000.0)


def test_released_throttle_regenerates_gently_down_to_a_stop():
    profile = config.load_vehicle("techs4agecar")
    traction = profile.actuators.traction
    plant = VehiclePlant(straight_route(), profile, SMOOTH_ROAD, s0=10.0)
    loop = SpeedLoop(plant)
    for _ in range(1200):
        loop.step(3.0)
    m = plant.traction.mass_kg
    decel_limit = (
        traction.max_regen_force_n
        + traction.rolling_resistance * m * GRAVITY
        + 0.5 * 1.2 * traction.drag_area_m2 * 3.2**2
    ) / m
    speeds = []
    for _ in range(2000):
        st = plant.step(0.0, 0.0)
        speeds.append(st.v)
        assert -decel_limit - 1e-9 <= st.accel <= 1e-9
    assert min(speeds) == 0.0 and speeds[-1] == 0.0
    assert min(a for a in np.diff(speeds) / PHYSICS_DT) < -0.9 * decel_limit  # regen does bite


def test_grade_is_felt_along_the_heading():
    plant = VehiclePlant(straight_route(grade=0.14), "techs4agecar", SMOOTH_ROAD, s0=100.0)
    assert plant.step(0.0, 0.0).grade == pytest.approx(0.14)
    plant.state.yaw = math.pi  # turned round: the same road now goes downhill
    st = plant.step(0.0, 0.0)
    assert st.grade == pytest.approx(-0.14)
    assert st.pitch == pytest.approx(math.atan(0.14))


def test_a_profile_without_tyre_figures_drives_the_kinematic_bicycle():
    """A profile (or a recorded run) from before the tyre figures: the kinematic bicycle at any speed."""
    from ares.core.config import load_vehicle
    from simulator.vehicle import LateralParams, lateral_step

    bare = load_vehicle(
        "ares_shuttle",
        {
            "yaw_inertia_kgm2": None,
            "cornering_stiffness_front_n_per_rad": None,
            "cornering_stiffness_rear_n_per_rad": None,
        },
    )
    p = LateralParams.of(bare, bare.empty_mass_kg)
    assert not p.dynamic
    v_y, r = lateral_step(p, 0.0, 0.0, 8.0, 0.1, 0.01)
    assert r == pytest.approx(8.0 * math.tan(0.1) / bare.wheelbase_m) and v_y == pytest.approx(p.l_r * r)


# ---- the bridge's speed loop on the plant ---------------------------------------------------------


def engaged_loop(profile, params: DbwBridgeParams) -> BridgeLoop:
    """The bridge's loop just switched to automatic, as after a start or a restart."""
    loop = BridgeLoop(profile, params)
    for event in (BridgeEvent.button(0.0), BridgeEvent.set_automatic(0.0)):
        loop.handle(event)
    return loop


def can_frame(t: float, st) -> CanFrame:
    """What the bridge reads of the plant's state on the CAN bus, no driver acting."""
    return CanFrame(
        t=t, wheel_speed_rad_s=st.wheel_speed_rad_s, speed_mps=st.v, steering_wheel_deg=st.steering_wheel_deg,
        throttle_pedal=0.0, brake_pedal=0.0, steering_torque=False,
    )  # fmt: skip


def drive_through_the_bridge(vehicle: str, feedforward: bool, seconds: float, v_of_t) -> tuple[list, list]:
    """The bridge's loop (control.dbw_bridge.BridgeLoop, 10 Hz) engaged on the plant, commanded
    v_of_t(t) straight ahead: the commanded and the measured speeds at each period."""
    profile = config.load_vehicle(vehicle)
    plant = VehiclePlant(straight_route(600.0), profile, SMOOTH_ROAD, s0=10.0)
    loop = engaged_loop(profile, DbwBridgeParams(speed_feedforward=feedforward))
    commanded, measured = [], []
    drive = steer = 0.0
    for k in range(round(seconds / PHYSICS_DT)):
        t = k * PHYSICS_DT
        if k % TICKS == 0:
            loop.handle(BridgeEvent.setpoint(v_of_t(t), 0.0, t))
            st = plant.state
            can = can_frame(t, st)
            out = loop.efforts(t, can, 0.0)  # on the flat
            steer, drive = out.steer_effort, out.drive_effort
            commanded.append(out.command.v)
            measured.append(st.v)
        plant.step(steer, drive)
    return commanded, measured


@pytest.mark.parametrize("vehicle", VEHICLES)
def test_the_speed_feedforward_follows_the_ramps_closer_than_the_pi_alone(vehicle):
    """Up to cruise at the movement manager's largest acceleration, then braking at the MPC's
    1.5 m/s^2 (harder than the stack asks: no jerk limit here). Adding the command's steady effort
    (v / the motor's full-effort speed) to the speed loop, the measured speed lags the ramp up and
    runs over the ramp down less than with the board's PI alone, which must first wind its integral
    up and down: on the car, whose PI is slow, by far (the campus lap's sawtooth, docs/control.md)."""
    cruise = {"techs4agecar": 6.9, "ares_shuttle": 4.0}[vehicle]
    accel = config.load_vehicle(vehicle).max_accel_mps2

    def v_of_t(t: float) -> float:  # up to cruise, brake to 1 m/s from 20 s, hold
        return min(accel * t, cruise) if t < 20.0 else max(cruise - 1.5 * (t - 20.0), 1.0)

    lag, over = {}, {}
    for feedforward in (True, False):
        commanded, measured = drive_through_the_bridge(vehicle, feedforward, 30.0, v_of_t)
        gap = [m - c for m, c in zip(measured, commanded)]
        lag[feedforward] = -min(gap[: round(cruise / accel / PID_PERIOD_S)])  # behind, on the way up
        over[feedforward] = max(gap[round(20.0 / PID_PERIOD_S) :])  # ahead, on the way down
    assert lag[True] < lag[False] and over[True] <= over[False] + 0.01, (lag, over)
    if vehicle == "techs4agecar":
        assert lag[True] < 0.6 * lag[False] and over[True] < 0.7 * over[False], (lag, over)


def start_on_a_grade(vehicle: str, grade: float, pitch_of) -> tuple[float, float, float]:
    """A freshly engaged bridge (as after a restart) on a `grade`, fully loaded, commanded up from
    standstill at the vehicle's largest acceleration; `pitch_of(state)` is what its IMU says. The
    lowest speed (negative: it rolled back), how far back it rolled, and when it first moved
    forwards."""
    profile = config.load_vehicle(vehicle)
    plant = VehiclePlant(straight_route(grade=grade), profile, SMOOTH_ROAD, passengers=profile.seats, s0=50.0)
    loop = engaged_loop(profile, DbwBridgeParams())
    x0 = plant.state.x
    lowest, back, moved_at, drive = 0.0, 0.0, None, 0.0
    for k in range(round(6.0 / PHYSICS_DT)):
        t = k * PHYSICS_DT
        st = plant.state
        if k % TICKS == 0:
            loop.handle(BridgeEvent.setpoint(min(profile.max_accel_mps2 * t, 2.0), 0.0, t))
            can = can_frame(t, st)
            drive = loop.efforts(t, can, pitch_of(st)).drive_effort
        st = plant.step(0.0, drive)
        lowest, back = min(lowest, st.v), max(back, x0 - st.x)
        if moved_at is None and st.v > 0.05:
            moved_at = t
    assert moved_at is not None
    return lowest, back, moved_at


@pytest.mark.parametrize("vehicle", VEHICLES)
def test_the_hill_hold_keeps_a_start_on_a_climb_from_rolling_back(vehicle):
    """After a bridge restart on a 14 % climb (soak, 4,878 s) the speed loop's integral is at
    nought: let go at once, as told the road is flat, the brake releases before the motor holds
    the grade and the shuttle rolls back (0.3-0.37 m/s). With the IMU's pitch, or without one (the
    steepest grade assumed), the board stands on the brake until the loop asks enough of the motor
    to hold the grade. What is left is the motor's ramp through weak efforts once the brake lets
    go (one effort drives both, through the controller's lag): millimetres, at a few cm/s."""
    lowest, back, _ = start_on_a_grade(vehicle, 0.14, lambda st: 0.0)
    assert lowest < -0.25 and back > 0.1  # what the hill-hold is for
    for pitch_of in (lambda st: st.pitch, lambda st: None):
        lowest, back, moved_at = start_on_a_grade(vehicle, 0.14, pitch_of)
        assert lowest > -0.05 and back < 0.01 and moved_at < 2.5, (lowest, back, moved_at)


@pytest.mark.parametrize("vehicle", VEHICLES)
def test_the_hill_hold_does_not_hold_back_a_start_on_the_flat_or_downhill(vehicle):
    for grade in (0.0, -0.14):
        *_, let_go_at_once = start_on_a_grade(vehicle, grade, lambda st: 0.0)
        lowest, back, moved_at = start_on_a_grade(vehicle, grade, lambda st: st.pitch)
        assert lowest == 0.0 and back == 0.0 and moved_at == let_go_at_once, grade


def engage_rolling_up_a_climb(vehicle: str, v0: float, v_cmd: float, pitch_of, full: bool = True) -> float:
    """The vehicle (fully loaded, or empty) driven up a 14 % climb to `v0`, then a freshly engaged
    bridge (as after a restart of a busy one) told to go on at `v_cmd`: the lowest speed in the
    next 8 s."""
    profile = config.load_vehicle(vehicle)
    passengers = profile.seats if full else 0
    plant = VehiclePlant(straight_route(grade=0.14), profile, SMOOTH_ROAD, passengers=passengers, s0=50.0)
    while plant.state.v < v0:
        plant.step(0.0, 1.0)
    loop = engaged_loop(profile, DbwBridgeParams())
    lowest, drive = plant.state.v, 0.0
    for k in range(round(8.0 / PHYSICS_DT)):
        t = k * PHYSICS_DT
        st = plant.state
        if k % TICKS == 0:
            loop.handle(BridgeEvent.setpoint(v_cmd, 0.0, t))
            drive = loop.efforts(t, can_frame(t, st), pitch_of(st)).drive_effort
        lowest = min(lowest, plant.step(0.0, drive).v)
    return lowest


@pytest.mark.parametrize("vehicle", VEHICLES)
def test_a_bridge_engaged_while_rolling_up_a_climb_does_not_let_it_roll_back(vehicle):
    """Soak (segment 6, 3,540 s): a busy bridge was restarted while the shuttle was still rolling,
    and it went backwards at 0.175 m/s for a moment. A fresh loop's integral at nought leaves the
    motor too weak for the climb until it winds up, and the hill-hold does not help, for the
    shuttle is not standing when the loop engages. Engaged with the IMU's pitch, the loop's
    integral starts at the effort that holds the grade. Without a pitch (a silent IMU, itself a
    controlled stop) nothing is known of the climb, and it is left as it was."""
    # rolling: above the hill-hold's standstill speed (0.3 m/s), empty and fully loaded
    cases = [(v0, v_cmd, full) for v0 in (0.4, 0.8) for v_cmd in (0.5, 1.0, 2.0) for full in (True, False)]
    with_pitch = [engage_rolling_up_a_climb(vehicle, *case[:2], lambda st: st.pitch, case[2]) for case in cases]
    # (the empty car told to slow from 0.8 to 0.5 m/s brakes through the controller's lag: -0.035)
    assert min(with_pitch) > -0.05, dict(zip(cases, with_pitch))
    without = [engage_rolling_up_a_climb(vehicle, v0, 0.5, lambda st: None) for v0 in (0.4, 0.8)]
    assert min(without) < -0.3  # as the old loop did with any pitch: what the integral's start is for


def test_a_freshly_engaged_speed_loop_starts_with_the_integral_that_holds_the_climb():
    profile = config.load_vehicle("ares_shuttle")
    can = can_frame(0.0, VehicleState())  # standing
    # the fully loaded shuttle on 14 %: 0.213 of the motor's effort; a bump's pitch no steeper than 15 %
    fourteen, fifteen = 0.213, 0.228
    for pitch, expected in (
        (-math.atan(0.14), fourteen), (-math.atan(0.30), fifteen), (0.0, 0.0), (math.atan(0.14), 0.0), (None, 0.0)
    ):  # fmt: skip
        loop = engaged_loop(profile, DbwBridgeParams())
        loop.handle(BridgeEvent.setpoint(0.0, 0.0, 0.0))
        loop.efforts(0.0, can, pitch)
        assert loop.wheel_speed_pid.integral == pytest.approx(expected, abs=0.002), pitch


@functools.cache
def stop_on_a_grade(
    vehicle: str, grade: float, with_pitch: bool, passengers: int, ramp_mps2: float | None
) -> tuple[float, float, float, float]:
    """The bridge's loop on the plant at 2.6 m/s on a `grade`, then told to stop: the command ramps
    down at `ramp_mps2` (the control manager's controlled stop) or falls to 0 at once (None: an
    obstacle's limit); the IMU's pitch given or not. The speed when the command reached 0, how long
    and how far (signed: back is negative) the shuttle went on from then, and its hardest
    deceleration over a tenth of a second from the stop's start."""
    profile = config.load_vehicle(vehicle)
    plant = VehiclePlant(straight_route(grade=grade), profile, SMOOTH_ROAD, passengers=passengers, s0=20.0)
    loop = engaged_loop(profile, DbwBridgeParams())
    v0, t_stop = 2.6, 6.0
    t_zero = t_stop + (0.0 if ramp_mps2 is None else v0 / ramp_mps2)  # the command is 0 from then
    drive, x_zero, v_zero, stood, hardest, speeds = 0.0, 0.0, 0.0, None, 0.0, []
    for k in range(round((t_zero + 5.0) / PHYSICS_DT)):
        t = k * PHYSICS_DT
        st = plant.state
        if k % TICKS == 0:
            if t < t_stop:
                v = min(profile.max_accel_mps2 * t, v0)
            else:
                v = 0.0 if ramp_mps2 is None else max(0.0, v0 - ramp_mps2 * (t - t_stop))
            loop.handle(BridgeEvent.setpoint(v, 0.0, t))
            can = can_frame(t, st)
            drive = loop.efforts(t, can, st.pitch if with_pitch else None).drive_effort
        if k == round(t_zero / PHYSICS_DT):
            x_zero, v_zero = st.x, st.v
        st = plant.step(0.0, drive)
        if t >= t_stop and k % TICKS == 0:
            speeds.append(st.v)
            if len(speeds) > 1 and stood is None:
                hardest = max(hardest, (speeds[-2] - speeds[-1]) / PID_PERIOD_S)
        if t >= t_zero and stood is None and abs(st.v) < 0.02:
            stood = t - t_zero
    assert stood is not None
    return v_zero, stood, plant.state.x - x_zero, hardest


@pytest.mark.parametrize("vehicle", VEHICLES)
@pytest.mark.parametrize("grade", [0.0, -0.12, -0.15, 0.12])
def test_a_stop_on_a_descent_ends_once_the_command_is_nought(vehicle, grade):
    """The 10-hour soak, second segment, stack time 2,142 s: a controlled stop on a 12 % descent
    before a cart rolled on at about 0.5 m/s for 4 s after the command had reached 0, from 2.6 m
    to 0.7 m of the cart. The speed loop's PI alone held the shuttle at the brake assist's
    deadband until its integral wound up (the ramp below on a 12 % descent, empty: 3.6 s and
    1.7 m on after the command reached 0; docs/safety.md, "A stop on a descent"). A
    zero command now has no deadband, and downhill the brake also takes the grade's pull. With
    the IMU's pitch or without one (the steepest descent assumed), empty or full, after a ramp or
    a fall to 0, the shuttle now stands as if braking at 1.5 m/s^2 on average from whatever speed
    the loop was at when the command reached 0 (1 m/s^2 without a pitch: the assumed descent is
    braked within the assist's 3 m/s^2, which a full shuttle on a real 15 % descent feels as less),
    give or take 0.6 s and 0.3 m of the loop's lag, and never rolls back. On the flat, the
    steepest descent that a stop without a pitch assumes brakes at most 1 m/s^2 harder than the
    same stop with the IMU's pitch."""
    for passengers in (0, config.load_vehicle(vehicle).seats):
        for ramp in (1.0, None):
            hardest = {}
            for with_pitch in (True, False):
                v_zero, stood, went, hardest[with_pitch] = stop_on_a_grade(vehicle, grade, with_pitch, passengers, ramp)
                case = (with_pitch, passengers, ramp, v_zero, stood, went, hardest[with_pitch])
                mean = 1.5 if with_pitch else 1.0  # the assumed descent is braked within the assist's 3 m/s^2
                assert stood < 0.6 + v_zero / mean and -0.01 < went < 0.3 + v_zero**2 / (2 * mean), case
            if grade == 0.0:
                assert hardest[False] <= hardest[True] + 1.0, (passengers, ramp, hardest)


def test_the_brake_assist_has_no_deadband_for_a_stop_and_takes_the_descents_pull():
    loop = BridgeLoop(config.load_vehicle("ares_shuttle"), DbwBridgeParams())
    per = loop.brake_effort_per_mps2
    assert loop.assist_effort(2.0, 2.4, 0.0) == 1.0  # within the deadband: the PI's alone
    assert loop.assist_effort(2.0, 2.7, 0.0) == pytest.approx(-0.2 / 0.5 * per)
    assert loop.assist_effort(0.0, 0.4, 0.0) == pytest.approx(-0.4 / 0.5 * per)  # a stop: no deadband
    assert loop.assist_effort(1e-17, 0.4, 0.0) == loop.assist_effort(0.0, 0.4, 0.0)  # the gate's ramp's 0
    assert loop.assist_effort(0.0, 0.0, 0.0) == 1.0
    descent = math.atan(0.12)
    pull = (2450 + 12 * 75) * GRAVITY * math.sin(descent) / 10000.0  # fully loaded, on the brake's force
    assert loop.assist_effort(0.0, 0.4, descent) == pytest.approx(-(0.8 * per + pull))
    assert loop.assist_effort(0.0, 0.4, -descent) == loop.assist_effort(0.0, 0.4, 0.0)  # a climb helps
    assert loop.assist_effort(2.0, 2.7, descent) == loop.assist_effort(2.0, 2.7, 0.0)  # moving: as before
    steepest = GRAVITY * math.sin(math.atan(0.15))
    assert loop.assist_effort(0.0, 0.4, None) == pytest.approx(-(0.8 + steepest) * per)  # no pitch: assumed
    assert loop.assist_effort(0.0, 2.0, None) == pytest.approx(-3.0 * per)  # ... within the largest deceleration
    assert loop.assist_effort(2.0, 2.7, None) == loop.assist_effort(2.0, 2.7, 0.0)  # ... for a stop only
    assert loop.assist_effort(0.0, 9.0, math.atan(0.3)) == -1.0
