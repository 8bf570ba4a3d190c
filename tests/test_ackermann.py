"""Ackermann conversions against the DBW paper's equations (9)-(14).

Expected numbers were worked out by hand for the Techs4AgeCar (Table 1 of the paper):
S = 2.36 m, L = 1.315 m, r = 0.28 m, steering ratio 40, max wheel angle 20° (0.349 rad).
"""

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from ares.core import config
from ares.core.config import ConfigError, VehicleProfile
from control import ackermann as ack

S, L, R_WHEEL = 2.36, 1.315, 0.28
TECHS4AGECAR = config.load_vehicle("techs4agecar")  # Table 1's car: the geometry above

# Turning radius 5 m (the car's figure in Table 1): κ = 1/5 = 0.2 1/m.
#   θ  = atan(2.36 / 5)               = atan(0.472)   = 0.44100 rad = 25.267°
#   θi = atan(2.36 / (5 − 0.6575))    = atan(0.54346) = 0.49781 rad = 28.523°
#   θd = atan(2.36 / (5 + 0.6575))    = atan(0.41714) = 0.39520 rad = 22.643°
#   α  = 40 · 0.44100                 = 17.640 rad   = 1010.69°
#   ω_w at 2 m/s = 2 / (cos 0.44100 · 0.28) = 2 / (0.90435 · 0.28) = 7.8985 rad/s = 452.55 °/s
KAPPA_5M = 0.2
THETA_5M = 0.44100
THETA_INNER_5M = 0.49781
THETA_OUTER_5M = 0.39520
ALPHA_5M = 17.640
OMEGA_W_5M_2MPS = 7.8985

curvatures = st.floats(min_value=-2.0, max_value=2.0, allow_nan=False)
speeds = st.floats(min_value=-10.0, max_value=40.0, allow_nan=False)
wheel_angles = st.floats(min_value=-1.4, max_value=1.4, allow_nan=False)


# --- eq. (9) and R = 1/κ ---------------------------------------------------------------------


def test_angular_speed_is_v_times_kappa():
    assert ack.angular_speed(2.0, KAPPA_5M) == pytest.approx(0.4)  # 2 m/s on a 5 m circle
    assert ack.angular_speed(2.0, -KAPPA_5M) == pytest.approx(-0.4)  # right turn
    assert ack.angular_speed(3.0, 0.0) == 0.0


def test_turning_radius_is_inverse_curvature_and_straight_is_infinite():
    assert ack.turning_radius(KAPPA_5M) == pytest.approx(5.0)
    assert ack.turning_radius(-KAPPA_5M) == pytest.approx(-5.0)
    assert ack.turning_radius(0.0) == math.inf
    assert ack.curvature_from_radius(5.0) == pytest.approx(KAPPA_5M)
    assert ack.curvature_from_radius(math.inf) == 0.0


# --- eq. (10)-(12) ---------------------------------------------------------------------------


def test_front_wheel_angle_for_5m_turn():
    assert ack.curvature_to_wheel_angle(KAPPA_5M, S) == pytest.approx(THETA_5M, abs=1e-5)
    assert math.degrees(ack.curvature_to_wheel_angle(KAPPA_5M, S)) == pytest.approx(25.267, abs=1e-3)
    assert ack.curvature_to_wheel_angle(-KAPPA_5M, S) == pytest.approx(-THETA_5M, abs=1e-5)
    assert ack.curvature_to_wheel_angle(0.0, S) == 0.0


def test_inner_and_outer_wheel_angles_for_5m_left_turn():
    inner, outer = ack.inner_outer_wheel_angles(KAPPA_5M, S, L)
    assert inner == pytest.approx(THETA_INNER_5M, abs=1e-5)
    assert outer == pytest.approx(THETA_OUTER_5M, abs=1e-5)
    # In a left turn the left wheel is the inner one (eq. 11 is the left wheel).
    assert ack.left_right_wheel_angles(KAPPA_5M, S, L) == pytest.approx((inner, outer))


def test_right_turn_mirrors_left_turn():
    inner, outer = ack.inner_outer_wheel_angles(-KAPPA_5M, S, L)
    assert inner == pytest.approx(-THETA_INNER_5M, abs=1e-5)
    assert outer == pytest.approx(-THETA_OUTER_5M, abs=1e-5)
    left, right = ack.left_right_wheel_angles(-KAPPA_5M, S, L)
    assert right == pytest.approx(inner) and left == pytest.approx(outer)


def test_straight_line_has_all_wheels_straight():
    assert ack.inner_outer_wheel_angles(0.0, S, L) == (0.0, 0.0)
    assert ack.left_right_wheel_angles(0.0, S, L) == (0.0, 0.0)


@given(st.floats(min_value=1e-4, max_value=1.0))
def test_inner_wheel_turns_more_than_centre_more_than_outer(k):
    for kappa in (k, -k):
        inner, outer = ack.inner_outer_wheel_angles(kappa, S, L)
        centre = ack.curvature_to_wheel_angle(kappa, S)
        assert abs(inner) > abs(centre) > abs(outer) > 0
        # All three point the same way as the turn.
        assert math.copysign(1, inner) == math.copysign(1, outer) == math.copysign(1, kappa)


@given(curvatures)
def test_wheel_angles_symmetric_left_right(kappa):
    left, right = ack.left_right_wheel_angles(kappa, S, L)
    mirror_left, mirror_right = ack.left_right_wheel_angles(-kappa, S, L)
    assert mirror_left == pytest.approx(-right, abs=1e-12)
    assert mirror_right == pytest.approx(-left, abs=1e-12)
    inner, outer = ack.inner_outer_wheel_angles(kappa, S, L)
    m_inner, m_outer = ack.inner_outer_wheel_angles(-kappa, S, L)
    assert m_inner == pytest.approx(-inner, abs=1e-12)
    assert m_outer == pytest.approx(-outer, abs=1e-12)


@given(st.floats(min_value=0.01, max_value=1.0))
def test_wheel_angles_match_paper_radius_form(kappa):
    # Eqs. (11)-(12) written with R, for radii outside the track.
    radius = 1.0 / kappa
    inner, outer = ack.inner_outer_wheel_angles(kappa, S, L)
    assert math.tan(inner) == pytest.approx(S / (radius - L / 2), rel=1e-9)
    assert math.tan(outer) == pytest.approx(S / (radius + L / 2), rel=1e-9)


# --- eq. (13) --------------------------------------------------------------------------------


def test_the_techs4agecar_profile_is_table_1s_car():
    car = TECHS4AGECAR
    assert (car.wheelbase_m, car.track_m, car.wheel_radius_m, car.steering_ratio, car.max_wheel_angle_rad) == (
        S,
        L,
        R_WHEEL,
        40,
        0.349,
    )


def test_steering_wheel_angle_is_40_times_wheel_angle():
    car = TECHS4AGECAR
    assert car.steering_wheel_angle(THETA_5M) == pytest.approx(math.degrees(40 * THETA_5M))
    alpha_deg = car.steering_wheel_angle(ack.curvature_to_wheel_angle(KAPPA_5M, S))
    assert math.radians(alpha_deg) == pytest.approx(ALPHA_5M, abs=1e-3)
    assert alpha_deg == pytest.approx(1010.69, abs=1e-2)
    geared_16 = car.model_copy(update={"steering_ratio": 16.0})
    assert math.radians(geared_16.steering_wheel_angle(0.349)) == pytest.approx(5.584)


def test_paper_steering_range_to_curvature():
    # The rack allows α = ±9.25 rad: θ = 9.25/40 = 0.23125 rad, κ = tan(0.23125)/2.36 = 0.09977.
    car = TECHS4AGECAR
    assert car.curvature_of(math.degrees(9.25)) == pytest.approx(0.09977, abs=1e-5)
    assert car.curvature_of(math.degrees(-9.25)) == pytest.approx(-0.09977, abs=1e-5)
    assert car.road_wheel_angle(math.degrees(9.25)) == pytest.approx(0.23125)


@given(curvatures)
def test_round_trip_curvature_steering_wheel_curvature(kappa):
    alpha_deg = TECHS4AGECAR.steering_wheel_angle(ack.curvature_to_wheel_angle(kappa, S))
    assert TECHS4AGECAR.curvature_of(alpha_deg) == pytest.approx(kappa, rel=1e-9, abs=1e-12)


@given(wheel_angles)
def test_round_trip_wheel_angle_curvature_wheel_angle(theta):
    kappa = ack.wheel_angle_to_curvature(theta, S)
    assert ack.curvature_to_wheel_angle(kappa, S) == pytest.approx(theta, rel=1e-9, abs=1e-12)


# --- eq. (14) --------------------------------------------------------------------------------


def test_wheel_speed_for_5m_turn_at_2mps():
    theta = ack.curvature_to_wheel_angle(KAPPA_5M, S)
    assert ack.wheel_speed(2.0, theta, R_WHEEL) == pytest.approx(OMEGA_W_5M_2MPS, abs=1e-4)
    assert ack.wheel_speed_deg(2.0, theta, R_WHEEL) == pytest.approx(452.55, abs=1e-2)


def test_wheel_speed_straight_is_v_over_r():
    # 2 / 0.28 = 7.142857 rad/s = 409.256 °/s
    assert ack.wheel_speed(2.0, 0.0, R_WHEEL) == pytest.approx(7.142857, abs=1e-6)
    assert ack.wheel_speed_deg(2.0, 0.0, R_WHEEL) == pytest.approx(409.256, abs=1e-3)
    assert ack.wheel_speed(0.0, 0.3, R_WHEEL) == 0.0


@given(speeds, wheel_angles)
def test_round_trip_speed_wheel_speed_speed(v, theta):
    omega_w = ack.wheel_speed(v, theta, R_WHEEL)
    back = ack.wheel_speed_to_linear_speed(omega_w, theta, R_WHEEL)
    assert back == pytest.approx(v, rel=1e-9, abs=1e-12)


@given(st.floats(min_value=0.0, max_value=40.0), st.floats(min_value=0.0, max_value=1.4))
def test_steered_front_wheels_turn_at_least_as_fast_as_straight(v, theta):
    assert ack.wheel_speed(v, theta, R_WHEEL) >= ack.wheel_speed(v, 0.0, R_WHEEL) * (1 - 1e-12)


# --- limits ----------------------------------------------------------------------------------


def test_max_curvature_from_max_wheel_angle():
    # tan(0.349) / 2.36 = 0.36389 / 2.36 = 0.15419 1/m: a 6.49 m minimum radius.
    assert ack.max_curvature(S, 0.349) == pytest.approx(0.15419, abs=1e-5)
    assert ack.max_curvature(S, -0.349) == pytest.approx(0.15419, abs=1e-5)


@pytest.mark.parametrize(
    "theta, expected",
    [
        (0.0, 0.0),
        (0.2, 0.2),
        (-0.2, -0.2),
        (0.349, 0.349),
        (0.5, 0.349),
        (-0.5, -0.349),
        (10.0, 0.349),
        (-math.inf, -0.349),
    ],
)
def test_limit_wheel_angle(theta, expected):
    assert ack.limit_wheel_angle(theta, 0.349) == expected


@given(st.floats(allow_nan=False), st.floats(min_value=0.0, max_value=1.5))
def test_limit_wheel_angle_never_exceeds_and_keeps_sign(theta, limit):
    out = ack.limit_wheel_angle(theta, limit)
    assert abs(out) <= limit
    assert out == theta or abs(out) == limit
    assert out == 0 or (out > 0) == (theta > 0)


# --- SetpointConversion ----------------------------------------------------------------------


def techs4agecar() -> ack.SetpointConversion:
    return ack.SetpointConversion(TECHS4AGECAR)


def test_conversion_within_limits_follows_equations():
    conv = techs4agecar()
    # κ = 0.1 (R = 10 m): θ = atan(0.236) = 0.231759 rad, α = 40 · θ = 9.27038 rad = 531.15°,
    # ω_w at 3 m/s = 3 / (cos 0.231759 · 0.28) = 3 / (0.97326 · 0.28) = 11.0086 rad/s.
    out = conv.to_actuators(3.0, 0.1)
    assert out.wheel_angle_rad == pytest.approx(0.231759, abs=1e-6)
    assert out.steering_wheel_angle_rad == pytest.approx(9.27038, abs=1e-5)
    assert out.steering_wheel_angle_deg == pytest.approx(531.15, abs=1e-2)
    assert out.wheel_speed_rad_s == pytest.approx(11.0086, abs=1e-3)
    assert out.wheel_speed_deg_s == pytest.approx(math.degrees(out.wheel_speed_rad_s))
    assert out.angular_speed_rad_s == pytest.approx(0.3)
    assert not out.wheel_angle_limited


def test_conversion_clamps_a_too_tight_turn_to_the_max_wheel_angle():
    conv = techs4agecar()
    for sign in (1, -1):
        out = conv.to_actuators(2.0, sign * KAPPA_5M)  # 25.3° asked, 20° allowed
        assert out.wheel_angle_limited
        assert out.wheel_angle_rad == pytest.approx(sign * 0.349)
        assert out.steering_wheel_angle_rad == pytest.approx(sign * 40 * 0.349)
        assert out.wheel_speed_rad_s == pytest.approx(2.0 / (math.cos(0.349) * R_WHEEL))
        assert out.angular_speed_rad_s == pytest.approx(sign * 2.0 * conv.max_curvature)


def test_conversion_straight_and_stopped():
    out = techs4agecar().to_actuators(0.0, 0.0)
    assert out.wheel_angle_rad == 0.0
    assert out.steering_wheel_angle_rad == 0.0
    assert out.wheel_speed_rad_s == 0.0


def test_conversion_measurement_back_to_speed_and_curvature():
    conv = techs4agecar()
    # α = 9.25 rad, ω_w = 10 rad/s: κ = 0.09977, v = 10 · 0.28 · cos(0.23125) = 2.7254 m/s.
    measured = conv.to_speed_curvature(9.25, 10.0)
    assert measured.kappa == pytest.approx(0.09977, abs=1e-5)
    assert measured.v == pytest.approx(2.7254, abs=1e-4)
    in_degrees = conv.to_speed_curvature_deg(math.degrees(9.25), math.degrees(10.0))
    assert in_degrees.v == pytest.approx(measured.v)
    assert in_degrees.kappa == pytest.approx(measured.kappa)


@given(st.floats(min_value=0.0, max_value=10.0), st.floats(min_value=-0.15, max_value=0.15))
def test_conversion_round_trip_within_limits(v, kappa):
    conv = techs4agecar()
    out = conv.to_actuators(v, kappa)
    assert not out.wheel_angle_limited
    back = conv.to_speed_curvature(out.steering_wheel_angle_rad, out.wheel_speed_rad_s)
    assert back.v == pytest.approx(v, rel=1e-9, abs=1e-12)
    assert back.kappa == pytest.approx(kappa, rel=1e-9, abs=1e-12)
    back_deg = conv.to_speed_curvature_deg(out.steering_wheel_angle_deg, out.wheel_speed_deg_s)
    assert back_deg.v == pytest.approx(v, rel=1e-9, abs=1e-12)
    assert back_deg.kappa == pytest.approx(kappa, rel=1e-9, abs=1e-12)


@given(st.floats(min_value=0.0, max_value=10.0), st.floats(min_value=-50.0, max_value=50.0))
def test_conversion_never_exceeds_the_steering_limit(v, kappa):
    conv = techs4agecar()
    out = conv.to_actuators(v, kappa)
    assert abs(out.wheel_angle_rad) <= 0.349
    assert abs(out.steering_wheel_angle_rad) <= 40 * 0.349 + 1e-12
    inner, outer = conv.wheel_angles(kappa)
    assert abs(outer) <= abs(inner)


def test_conversion_wheel_angles_for_a_feasible_turn():
    inner, outer = techs4agecar().wheel_angles(-0.1)
    expected_inner, expected_outer = ack.inner_outer_wheel_angles(-0.1, S, L)
    assert (inner, outer) == pytest.approx((expected_inner, expected_outer))


@pytest.mark.parametrize(
    "name",
    [
        "techs4agecar",
        "ares_shuttle",
    ],
)
def test_conversion_reads_the_shipped_vehicle_profiles(name):
    profile = config.load_vehicle(name)
    conv = ack.SetpointConversion(profile)
    assert conv.max_curvature == pytest.approx(math.tan(profile.max_wheel_angle_rad) / profile.wheelbase_m)
    assert (conv.wheelbase_m, conv.track_m, conv.wheel_radius_m, conv.max_wheel_angle_rad) == (
        profile.wheelbase_m,
        profile.track_m,
        profile.wheel_radius_m,
        profile.max_wheel_angle_rad,
    )
    assert conv.to_actuators(1.0, 0.01).steering_wheel_angle_deg == pytest.approx(
        profile.steering_wheel_angle(math.atan(0.01 * profile.wheelbase_m))
    )


def shuttle_profile_data() -> dict:
    return config.load_vehicle("ares_shuttle").model_dump()


@pytest.mark.parametrize(
    "change, message",
    [
        ({"wheelbase_m": None}, "wheelbase_m: Input should be a valid number"),
        ({"track_m": -1.0}, "track_m: Input should be greater than 0"),
        ({"wheel_radius_m": 0}, "wheel_radius_m: Input should be greater than 0"),
        ({"steering_ratio": "forty"}, "steering_ratio: Input should be a valid number"),
        ({"steering_ratio": -40.0}, "steering_ratio: Input should be greater than 0"),
        ({"wheelbase_m": math.inf}, "wheelbase_m: Input should be a finite number"),
        ({"max_wheel_angle_rad": math.nan}, "max_wheel_angle_rad: Input should be a finite number"),
        ({"max_wheel_angle_rad": 1.6}, "max_wheel_angle_rad: Input should be less than 1.5"),
    ],
)
def test_a_profile_with_bad_geometry_is_refused_naming_the_key(change, message):
    # the conversion takes typed numbers: a profile that would break it never gets that far
    with pytest.raises(ConfigError, match=message):
        config.validated(VehicleProfile, {**shuttle_profile_data(), **change}, "test profile")


def test_a_profile_missing_geometry_names_every_missing_key():
    data = {k: v for k, v in shuttle_profile_data().items() if k not in ("track_m", "wheel_radius_m")}
    with pytest.raises(ConfigError) as refused:
        config.validated(VehicleProfile, data, "test profile")
    message = str(refused.value)
    assert message.startswith("test profile:")
    assert "track_m: required, missing" in message and "wheel_radius_m: required, missing" in message
