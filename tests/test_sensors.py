"""Simulated GNSS (NMEA GGA + GST), IMU and CAN readings."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pynmea2
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ares.core.config import UtmOrigin
from ares.core.geodesy import LocalFrame
from ares.core.nmea_framing import checksum
from ares.core.route import Route
from simulator.actuators import GRAVITY
from simulator.params import SimParams
from simulator.sensors import CanSensor, GnssSensor, ImuSensor, SensorSuite
from simulator.vehicle import VehicleState

SIM = SimParams()
FRAME = LocalFrame(UtmOrigin())
ROUTE = Route.from_tour("default")
RTK_LOSS = next(z for z in ROUTE.zones if z.kind == "rtk_loss")


def parse(sentence: str):
    return pynmea2.parse(sentence, check=True)  # raises on a wrong checksum


def gga_of(out: dict):
    return parse(out["sentences"][0])


def gst_of(out: dict):
    return parse(out["sentences"][1])


def gga_to_local(gga, gnss: GnssSensor) -> tuple[float, float, float]:
    """What the receiver side will do: GGA lat/lon -> UTM -> local metres."""
    x, y = gnss.latlon_to_local(gga.latitude, gga.longitude)
    return x, y, float(gga.altitude) - gnss.altitude0


# ---- NMEA ---------------------------------------------------------------------------------------


@settings(max_examples=150, deadline=None)
@given(x=st.floats(-5000, 5000), y=st.floats(-5000, 5000), z=st.floats(-50, 300), t=st.floats(0, 86400 * 2))
def test_gga_round_trips_to_the_same_position_within_a_millimetre(x, y, z, t):
    gnss = GnssSensor(ROUTE, SIM.gnss, FRAME, noise=False)
    state = VehicleState(t=t, x=x, y=y, z=z, s=0.0)
    out = gnss.measure(state)
    gga = gga_of(out)
    assert gga.sentence_type == "GGA" and gga.gps_qual == 4
    xr, yr, zr = gga_to_local(gga, gnss)
    assert math.hypot(xr - x, yr - y) < 1e-3
    assert abs(zr - z) < 1e-3
    for sentence in out["sentences"]:
        body, cs = sentence[1:].split("*")
        assert sentence.startswith("$GP") and cs == checksum(body)


def test_gga_fields_are_well_formed():
    gnss = GnssSensor(ROUTE, SIM.gnss, FRAME, noise=False)
    gga = gga_of(gnss.measure(VehicleState(t=3723.25, x=12.0, y=-7.0, z=3.0, s=0.0)))
    assert str(gga.timestamp) == "11:02:03.250000+00:00"  # 10:00:00 + 3723.25 s
    assert gga.lat_dir == "N" and gga.lon_dir == "W"  # Madrid, UTM zone 30 N
    assert len(gga.lat.split(".")[1]) == 7 and len(gga.lon.split(".")[1]) == 7
    assert int(gga.num_sats) == SIM.gnss.rtk_satellites
    assert float(gga.horizontal_dil) == SIM.gnss.rtk_hdop
    assert gga.altitude_units == "M" and float(gga.age_gps_data) >= 0 and gga.ref_station_id == "0001"


def test_southern_hemisphere_origin_round_trips():
    southern = LocalFrame(UtmOrigin(zone=19, hemisphere="S", easting=350000.0, northing=6300000.0, altitude_m=520.0))
    gnss = GnssSensor(ROUTE, SIM.gnss, southern, noise=False)
    gga = gga_of(gnss.measure(VehicleState(x=-40.0, y=25.0, z=1.0)))
    assert gga.lat_dir == "S" and gga.latitude < 0
    xr, yr, zr = gga_to_local(gga, gnss)
    assert math.hypot(xr + 40.0, yr - 25.0) < 1e-3 and abs(zr - 1.0) < 1e-3


def test_a_4g_outage_degrades_the_fix_as_its_corrections_age_and_it_recovers_after():
    """Through the tour's no_4g zone at 2.5 m/s: RTK fixed while the last correction is fresh, then
    float, then DGPS; out of it, float for refix_s, then fixed. The GGA tells the corrections' age."""
    zone = next(z for z in ROUTE.zones if z.kind == "no_4g")
    c = SIM.gnss.corrections
    gnss = GnssSensor(ROUTE, SIM.gnss, FRAME, noise=False)
    entered = None
    seen = []
    for k in range(int((zone.s_end - zone.s_start + 40.0) / 2.5 * 5)):  # 5 Hz from 20 m before
        t = k * 0.2
        s = zone.s_start - 20.0 + 2.5 * t
        gga = gga_of(gnss.measure(VehicleState(t=t, s=s)))
        if entered is None and s >= zone.s_start:
            entered = t
        seen.append((t, s, int(gga.gps_qual), gga.age_gps_data))
    inside = [(t - entered, q, age) for t, s, q, age in seen if zone.s_start <= s <= zone.s_end]
    assert {q for dt, q, _ in inside if dt < c.fixed_max_age_s - 1.0} == {4}
    assert {q for dt, q, _ in inside if c.fixed_max_age_s + 1.0 < dt < c.float_max_age_s - 1.0} == {5}
    assert {q for dt, q, _ in inside if dt > c.float_max_age_s + 1.0} == {2}
    assert max(float(age) for _, _, age in inside) > c.float_max_age_s
    after = [(t, q) for t, s, q, _ in seen if s > zone.s_end]
    left = after[0][0]
    assert {q for t, q in after if t - left < c.refix_s - 1.0} == {5}
    assert {q for t, q in after if t - left > c.refix_s + 1.5} == {4}


def test_fix_quality_and_gst_follow_the_rtk_loss_zones():
    gnss = GnssSensor(ROUTE, SIM.gnss, FRAME, noise=False)
    inside = (RTK_LOSS.s_start + RTK_LOSS.s_end) / 2
    rtk, lost = (gnss.measure(VehicleState(s=s)) for s in (RTK_LOSS.s_start - 5.0, inside))
    assert gga_of(rtk).gps_qual == 4
    assert gga_of(lost).gps_qual == SIM.gnss.no_rtk_fix_quality in (1, 2)
    assert gga_of(lost).age_gps_data == ""  # no corrections arriving
    g = gst_of(rtk)
    assert g.sentence_type == "GST"
    assert (g.std_dev_latitude, g.std_dev_longitude, g.std_dev_altitude) == pytest.approx(
        (SIM.gnss.rtk_sigma_m, SIM.gnss.rtk_sigma_m, SIM.gnss.rtk_sigma_alt_m), abs=5e-4
    )
    g = gst_of(lost)
    assert (g.std_dev_latitude, g.std_dev_longitude, g.std_dev_altitude) == pytest.approx(
        (SIM.gnss.float_sigma_m, SIM.gnss.float_sigma_m, SIM.gnss.float_sigma_alt_m), abs=5e-4
    )
    # The receiver-side covariance of the ARES paper: ~5e-5 m^2 with RTK, ~0.5 m^2 without.
    assert gst_of(rtk).std_dev_latitude ** 2 < 1e-4
    assert 0.3 < gst_of(lost).std_dev_latitude ** 2 < 0.7


# ---- GNSS noise ------------------------------------------------------------------------------------


def _errors(gnss: GnssSensor, s: float, n: int, dt: float) -> np.ndarray:
    out = []
    for k in range(n):
        gga = gga_of(gnss.measure(VehicleState(t=k * dt, x=0.0, y=0.0, z=0.0, s=s)))
        out.append(gga_to_local(gga, gnss))
    return np.array(out)


def test_rtk_noise_matches_the_configured_sigma():
    gnss = GnssSensor(ROUTE, SIM.gnss, FRAME, np.random.default_rng(3))
    err = _errors(gnss, s=10.0, n=3000, dt=0.2)
    sigma = SIM.gnss.rtk_sigma_m
    assert np.std(err[:, 0]) == pytest.approx(sigma, rel=0.08)
    assert np.std(err[:, 1]) == pytest.approx(sigma, rel=0.08)
    assert np.std(err[:, 2]) == pytest.approx(SIM.gnss.rtk_sigma_alt_m, rel=0.08)
    assert np.all(np.abs(np.mean(err, axis=0)) < 3 * sigma / math.sqrt(len(err)) * np.array([1, 1, 3]))


def test_uncorrected_error_wanders_with_the_configured_sigma():
    gnss = GnssSensor(ROUTE, SIM.gnss, FRAME, np.random.default_rng(4))
    inside = (RTK_LOSS.s_start + RTK_LOSS.s_end) / 2
    sigma = SIM.gnss.float_sigma_m
    # Spread over ~400 bias time constants, so the sample sigma is a fair estimate.
    err = _errors(gnss, s=inside, n=4000, dt=SIM.gnss.float_bias_tau_s * 4)
    assert np.std(err[:, 0]) == pytest.approx(sigma, rel=0.1)
    assert np.std(err[:, 1]) == pytest.approx(sigma, rel=0.1)
    assert np.std(err[:, 2]) == pytest.approx(SIM.gnss.float_sigma_alt_m, rel=0.1)
    # At the receiver's 5 Hz the error wanders: consecutive fixes are strongly correlated and
    # differ by far less than the error itself.
    fast = _errors(GnssSensor(ROUTE, SIM.gnss, FRAME, np.random.default_rng(5)), s=inside, n=3000, dt=0.2)
    e = fast[:, 0] - fast[:, 0].mean()
    lag1 = float(np.dot(e[1:], e[:-1]) / np.dot(e, e))
    assert lag1 > 0.8
    assert np.std(np.diff(fast[:, 0])) < 0.5 * sigma


def test_gnss_is_repeatable_with_a_seed():
    a = SensorSuite(ROUTE, SIM, FRAME, 0.28, seed=11)
    b = SensorSuite(ROUTE, SIM, FRAME, 0.28, seed=11)
    c = SensorSuite(ROUTE, SIM, FRAME, 0.28, seed=12)
    state = VehicleState(t=1.0, x=5.0, y=5.0, s=620.0)
    assert a.gnss.measure(state) == b.gnss.measure(state)
    assert a.gnss.measure(state) != c.gnss.measure(state)


# ---- IMU ----------------------------------------------------------------------------------------------


def test_imu_yaw_carries_the_configured_offset_and_noise():
    imu = ImuSensor(SIM.imu, np.random.default_rng(6))
    true_yaw = 3.1  # near +-pi: the offset must wrap
    yaws = np.array([imu.measure(VehicleState(yaw=true_yaw))["yaw"] for _ in range(4000)])
    assert np.all(np.abs(yaws) <= math.pi)
    diff = np.angle(np.exp(1j * (yaws - true_yaw)))
    assert np.mean(diff) == pytest.approx(SIM.imu.yaw_offset_rad, abs=0.002)
    assert np.std(diff) == pytest.approx(SIM.imu.yaw_sigma_rad, rel=0.08)


def test_imu_noise_matches_the_configured_sigmas():
    imu = ImuSensor(SIM.imu, np.random.default_rng(7))
    state = VehicleState(yaw_rate=0.2, accel=0.5, v=3.0, lateral_accel=0.6)
    r = [imu.measure(state) for _ in range(4000)]
    gz = np.array([m["gyro_z"] for m in r])
    ax = np.array([m["accel_x"] for m in r])
    assert np.mean(gz) == pytest.approx(0.2, abs=3e-4)
    assert np.std(gz) == pytest.approx(SIM.imu.gyro_sigma_rad_s, rel=0.08)
    assert np.std(ax) == pytest.approx(SIM.imu.accel_sigma_mps2, rel=0.08)
    assert np.mean([m["accel_y"] for m in r]) == pytest.approx(0.6, abs=0.005)


def test_imu_feels_gravity_along_the_pitch():
    imu = ImuSensor(SIM.imu, noise=False)
    grade = 0.14
    pitch = -math.atan(grade)  # standing on a climb, REP-103: nose up is negative
    m = imu.measure(VehicleState(pitch=pitch, grade=grade))
    assert m["pitch"] == pitch
    assert m["accel_x"] == pytest.approx(GRAVITY * math.sin(math.atan(grade)))  # > 0: the climb
    assert m["accel_z"] == pytest.approx(GRAVITY * math.cos(math.atan(grade)))
    assert math.hypot(m["accel_x"], m["accel_z"]) == pytest.approx(GRAVITY)
    assert m["yaw"] == pytest.approx(SIM.imu.yaw_offset_rad)
    assert set(m) == {"yaw", "roll", "pitch", "gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z"}


def test_imu_feels_the_road_roughness_while_driving():
    """Through the plant: a moving vehicle shakes the accelerometer's z axis."""
    from simulator.vehicle import VehiclePlant

    plant = VehiclePlant(ROUTE, "ares_shuttle", SIM, s0=20.0)
    imu = ImuSensor(SIM.imu, noise=False)
    az_still = [imu.measure(plant.step(0.0, 0.0))["accel_z"] for _ in range(50)]
    assert np.ptp(az_still) == pytest.approx(0.0, abs=1e-9)
    az = []
    for _ in range(1500):
        st = plant.step(0.0, 0.3)
        az.append(imu.measure(st)["accel_z"])
    assert np.std(az[500:]) > 0.05


# ---- CAN ----------------------------------------------------------------------------------------------


def test_can_noise_matches_the_configured_sigmas_and_reads_zero_when_stopped():
    r = 0.28
    can = CanSensor(SIM.can, r, np.random.default_rng(8))
    moving = VehicleState(v=3.0, wheel_speed_rad_s=3.0 / r, steering_wheel_deg=100.0)
    m = [can.measure(moving) for _ in range(4000)]
    speed = np.array([x["speed_mps"] for x in m])
    steer = np.array([x["steering_wheel_deg"] for x in m])
    assert np.mean(speed) == pytest.approx(3.0, abs=0.002)
    assert np.std(speed) == pytest.approx(SIM.can.speed_sigma_mps, rel=0.08)
    assert np.std([x["wheel_speed_rad_s"] for x in m]) == pytest.approx(SIM.can.speed_sigma_mps / r, rel=0.08)
    assert np.std(steer) == pytest.approx(SIM.can.steer_sigma_deg, rel=0.08)
    stopped = can.measure(VehicleState())
    assert stopped["wheel_speed_rad_s"] == 0.0 and stopped["speed_mps"] == 0.0


def test_can_speed_is_the_rear_axle_speed_in_a_turn():
    r, delta = 0.28, 0.3
    can = CanSensor(SIM.can, r, noise=False)
    v = 2.0
    m = can.measure(VehicleState(v=v, wheel_angle_rad=delta, wheel_speed_rad_s=v / (math.cos(delta) * r)))
    assert m["speed_mps"] == pytest.approx(v)
    assert m["wheel_speed_rad_s"] == pytest.approx(v / (math.cos(delta) * r))  # DBW eq. 14


def test_can_reports_the_driver():
    can = CanSensor(SIM.can, 0.28, noise=False)
    m = can.measure(replace(VehicleState(), throttle_pedal=0.4, brake_pedal=0.0, steering_torque=True))
    assert m == {
        "wheel_speed_rad_s": 0.0,
        "speed_mps": 0.0,
        "steering_wheel_deg": 0.0,
        "throttle_pedal": 0.4,
        "brake_pedal": 0.0,
        "steering_torque": True,
    }
