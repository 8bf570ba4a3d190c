"""Localization (ARES §3.1): yaw from poses (eqs. 1-2), wheel odometry (eqs. 3-5), the UKF,
the localization pipeline, the in-process closed loop, and the localization and odometry
manager nodes on the in-memory bus."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ares.app import run_config
from ares.core import config
from ares.core.clock import ManualClock
from ares.core.config import ConfigError, CoreConfig
from ares.core.membus import MemoryNetwork
from ares.core.messages import CanFrame, GnssFix, Imu
from ares.core.route import Route
from ares.tools.harness import closed_loop
from managers.odometry_node import OdometryManager
from perception.localization import LocalizationParams, Localizer
from perception.localization_node import LocalizationNode
from perception.ukf import PoseUKF, residual_angle, unscented_transform
from perception.wheel_odometry import WheelOdometry, increments, slip_angle
from perception.yaw_from_poses import PoseFix, YawFromPoses, YawFromPosesParams, yaw_from_poses, yaw_variance

PARAMS = LocalizationParams()
PROFILE = config.load_vehicle(CoreConfig().vehicle)  # the stack's default vehicle
RTK_VAR = 0.007**2


def wrap(a):
    return (a + math.pi) % (2 * math.pi) - math.pi


# ---- eq. 1 and eq. 2 ------------------------------------------------------------------------


def test_eq1_chord_direction_in_every_quadrant():
    assert yaw_from_poses(0, 0, 1, 1) == pytest.approx(math.pi / 4)
    assert yaw_from_poses(0, 0, -1, 1) == pytest.approx(3 * math.pi / 4)
    assert yaw_from_poses(0, 0, -1, -1) == pytest.approx(-3 * math.pi / 4)
    assert yaw_from_poses(2, 3, 2, 5) == pytest.approx(math.pi / 2)  # due north: ΔX = 0


def test_eq1_yaw_rate_correction_puts_the_heading_at_the_end_of_the_chord():
    # an arc of radius 10 m from heading 0 turning left by 0.3 rad: the chord points at 0.15
    r, turned = 10.0, 0.3
    x1, y1 = r * math.sin(turned), r * (1 - math.cos(turned))
    assert yaw_from_poses(0, 0, x1, y1) == pytest.approx(0.15)
    assert yaw_from_poses(0, 0, x1, y1, heading_change=turned) == pytest.approx(turned)


def test_eq2_hand_computed_value():
    # ΔX = 3, ΔY = 4, r² = 25: (16·(0.01 + 0.02) + 9·(0.03 + 0.04)) / 625 = 1.11 / 625
    assert yaw_variance(3, 4, 0.01, 0.03, 0.02, 0.04) == pytest.approx(1.11 / 625)


def test_eq2_equals_the_papers_form_with_its_typo_fixed_and_the_jacobian():
    dx, dy, vx0, vy0, vx, vy = 1.3, -0.4, 2e-5, 3e-5, 4e-5, 5e-5
    q = dy / dx
    papers = (1 + q * q) ** -2 * ((dy / dx**2) ** 2 * (vx0 + vx) + (1 / dx) ** 2 * (vy0 + vy))
    assert yaw_variance(dx, dy, vx0, vy0, vx, vy) == pytest.approx(papers, rel=1e-12)
    # first-order propagation through atan2, by finite differences
    h = 1e-7
    d_dx = (math.atan2(dy, dx + h) - math.atan2(dy, dx - h)) / (2 * h)
    d_dy = (math.atan2(dy + h, dx) - math.atan2(dy - h, dx)) / (2 * h)
    assert yaw_variance(dx, dy, vx0, vy0, vx, vy) == pytest.approx(
        d_dx**2 * (vx0 + vx) + d_dy**2 * (vy0 + vy), rel=1e-6
    )
    # driving due north: the printed form divides by ΔX = 0, this one does not
    assert yaw_variance(0.0, 2.0, 1e-4, 1e-4, 1e-4, 1e-4) == pytest.approx(2e-4 / 4)


def test_eq2_matches_monte_carlo_with_rtk_noise():
    rng = np.random.default_rng(1)
    n, sigma, d = 200_000, 0.007, 1.5
    p0 = rng.normal(0, sigma, (n, 2))
    p1 = np.array([d * math.cos(0.7), d * math.sin(0.7)]) + rng.normal(0, sigma, (n, 2))
    yaws = np.arctan2(p1[:, 1] - p0[:, 1], p1[:, 0] - p0[:, 0])
    predicted = yaw_variance(d * math.cos(0.7), d * math.sin(0.7), sigma**2, sigma**2, sigma**2, sigma**2)
    assert np.var(yaws) == pytest.approx(predicted, rel=0.02)


def fix(t, x, y, rtk=True, heading=0.0, var=RTK_VAR):
    return PoseFix(t, x, y, var, var, rtk, heading)


def test_yaw_from_poses_waits_for_d_metres_and_uses_the_latest_fix_that_far():
    yp = YawFromPoses(distance_m=1.5, min_speed_mps=0.5, max_chord_s=5.0)
    assert yp.add(fix(0.0, 0.0, 0.0), 2.0) is None
    assert yp.add(fix(0.2, 0.4, 0.0), 2.0) is None
    assert yp.add(fix(0.4, 0.8, 0.0), 2.0) is None
    m = yp.add(fix(0.8, 1.6, 0.0), 2.0)  # 1.6 m from the first, 1.2 from the second
    assert m is not None and m.chord_m == pytest.approx(1.6) and m.yaw == pytest.approx(0.0)
    m = yp.add(fix(1.0, 2.0, 0.2), 2.0)  # the latest fix >= 1.5 m behind is (0.4, 0)
    assert m.chord_m == pytest.approx(math.hypot(1.6, 0.2))
    assert m.variance == pytest.approx(
        yaw_variance(1.6, 0.2, RTK_VAR, RTK_VAR, RTK_VAR, RTK_VAR) + 0.25 * yp.heading_change_var_per_s * 0.8
    )


def test_yaw_from_poses_needs_motion_compatible_quality_and_a_quick_chord():
    yp = YawFromPoses(distance_m=1.5, min_speed_mps=0.5, max_chord_s=5.0)
    yp.add(fix(0.0, 0.0, 0.0), 0.0)
    assert yp.add(fix(1.0, 2.0, 0.0), 0.2) is None  # too slow to be "moving"
    yp.reset()
    yp.add(fix(0.0, 0.0, 0.0, rtk=True), 2.0)
    assert yp.add(fix(1.0, 2.0, 0.0, rtk=False, var=0.49), 2.0) is None  # RTK -> no RTK: no chord
    assert yp.add(fix(2.0, 4.0, 0.0, rtk=False, var=0.49), 2.0) is not None  # both without: compatible
    yp.reset()
    yp.add(fix(0.0, 0.0, 0.0), 2.0)
    assert yp.add(fix(6.0, 2.0, 0.0), 2.0) is None  # took longer than max_chord_s


def test_yaw_from_poses_reversing_points_the_yaw_against_the_chord():
    yp = YawFromPoses(distance_m=1.0, min_speed_mps=0.3)
    yp.add(fix(0.0, 0.0, 0.0), -1.0)
    m = yp.add(fix(1.0, -1.2, 0.0), -1.0)  # moving west, facing east
    assert abs(wrap(m.yaw - 0.0)) < 1e-9


# ---- wheel odometry, eqs. 3-5 ----------------------------------------------------------------


def test_increments_hand_computed():
    v, yaw, delta, dt, k, wb = 2.0, 0.3, 0.1, 0.1, 0.5, 2.8
    beta = math.atan(0.5 * math.tan(0.1))
    dx, dy, dyaw = increments(v, yaw, delta, dt, k, wb)
    assert dx == pytest.approx(2.0 * math.cos(0.3 + beta) * 0.1)
    assert dy == pytest.approx(2.0 * math.sin(0.3 + beta) * 0.1)
    assert dyaw == pytest.approx(2.0 * math.cos(beta) * math.tan(0.1) / 2.8 * 0.1)
    assert slip_angle(0.0, 0.5) == 0.0 and slip_angle(0.2, 0.0) == 0.0


def test_wheel_odometry_on_a_straight():
    wo = WheelOdometry(PROFILE)
    wo.reset(0.0, 0.0, math.radians(30))
    for k in range(101):
        wo.integrate(k * 0.05, 2.0, 0.0)
    assert wo.x == pytest.approx(10 * math.cos(math.radians(30)), abs=1e-9)
    assert wo.y == pytest.approx(10 * math.sin(math.radians(30)), abs=1e-9)
    assert wo.yaw == pytest.approx(math.radians(30))


def test_wheel_odometry_closes_a_circle_and_reports_the_rear_axle_yaw_rate():
    wo = WheelOdometry(PROFILE)
    wb, k = PROFILE.wheelbase_m, PROFILE.k_cg
    steer_deg = 400.0  # 10 degrees at the wheels
    delta = math.radians(steer_deg) / PROFILE.steering_ratio
    v_rear = 2.0
    reading = wo.reading(0.0, v_rear, steer_deg)
    assert reading.yaw_rate == pytest.approx(v_rear * math.tan(delta) / wb)  # the rear-axle bicycle's
    period = 2 * math.pi / reading.yaw_rate
    n = 4000
    dt = period / n
    wo.reset()
    xs, ys = [], []
    for i in range(n + 1):
        x, y, yaw = wo.integrate(i * dt, v_rear, steer_deg)
        xs.append(x)
        ys.append(y)
    assert math.hypot(wo.x, wo.y) < 1e-6 and abs(wrap(wo.yaw)) < 1e-9  # back where it started
    # the reference point (k_cg along the wheelbase) runs on the circle sqrt(R² + (k·wb)²)
    r_rear = wb / math.tan(delta)
    radius = (max(xs) - min(xs)) / 2
    assert radius == pytest.approx(math.hypot(r_rear, k * wb), rel=1e-4)


def test_wheel_speed_is_made_horizontal_with_the_pitch():
    wo = WheelOdometry(PROFILE)
    assert wo.reading(0.0, 3.0, 0.0, pitch=-math.atan(0.12)).v == pytest.approx(3.0 / math.hypot(1, 0.12))


# ---- the UKF ---------------------------------------------------------------------------------


def test_unscented_transform_averages_angles_across_pi():
    # three sigma points either side of ±π; a plain weighted mean would give ≈ 0.62 rad
    sig = np.array([[math.pi - 0.01], [-math.pi + 0.03], [math.pi - 0.05]])
    w = np.array([0.2, 0.4, 0.4])
    mean, cov = unscented_transform(sig, w, w, np.zeros((1, 1)), None, residual_angle)
    # offsets from π: 0.2·(−0.01) + 0.4·(+0.03) + 0.4·(−0.05) = −0.01
    assert abs(wrap(mean[0] - (math.pi - 0.01))) < 1e-9  # not ~0
    assert -math.pi <= mean[0] < math.pi
    assert cov[0, 0] < 0.01


def drive(
    t_end,
    speed=3.0,
    yaw_rate=0.0,
    yaw0=0.0,
    imu_yaw_offset=0.0,
    rtk=lambda t: True,
    fix_error=lambda t: (0, 0),
    seed=0,
    dt=0.01,
):
    """Messages of a vehicle on a circle/straight from the origin: (kind, msg, truth) in time order."""
    rng = np.random.default_rng(seed)
    x = y = 0.0
    yaw = yaw0
    wb, ratio = PROFILE.wheelbase_m, PROFILE.steering_ratio
    steer_deg = math.degrees(math.atan(yaw_rate * wb / speed) * ratio) if speed else 0.0
    out = []
    n = int(round(t_end / dt))
    for i in range(n + 1):
        t = i * dt
        truth = (x, y, yaw)
        if i % 2 == 0:
            out.append(
                (
                    "imu",
                    Imu(
                        t=t,
                        yaw=wrap(yaw + imu_yaw_offset),
                        roll=0.0,
                        pitch=0.0,
                        gyro_x=0.0,
                        gyro_y=0.0,
                        gyro_z=yaw_rate + 0.002 * rng.standard_normal(),
                        accel_x=0.0,
                        accel_y=0.0,
                        accel_z=9.81,
                    ),
                    truth,
                )
            )
        if i % 5 == 0:
            out.append(
                (
                    "can",
                    CanFrame(
                        t=t,
                        wheel_speed_rad_s=speed / 0.28,
                        speed_mps=speed + 0.01 * rng.standard_normal(),
                        steering_wheel_deg=steer_deg,
                        throttle_pedal=0.0,
                        brake_pedal=0.0,
                        steering_torque=False,
                    ),
                    truth,
                )
            )
        if i % 20 == 0:
            ok = rtk(t)
            sigma = 0.007 if ok else 0.7
            ex, ey = fix_error(t)
            noise = rng.normal(0, 0.007, 2) if ok else np.zeros(2)
            out.append(
                (
                    "gnss",
                    GnssFix(
                        t=t,
                        x=x + ex + noise[0],
                        y=y + ey + noise[1],
                        z=0.0,
                        lat=40.0,
                        lon=-3.7,
                        easting=440000.0 + x,
                        northing=4474000.0 + y,
                        zone=30,
                        hemisphere="N",
                        quality=4 if ok else 1,
                        rtk=ok,
                        satellites=12,
                        hdop=0.8,
                        var_x=sigma**2,
                        var_y=sigma**2,
                        var_z=4 * sigma**2,
                    ),
                    truth,
                )
            )
        yaw_next = yaw + yaw_rate * dt
        mid = yaw + 0.5 * yaw_rate * dt
        x += speed * math.cos(mid) * dt
        y += speed * math.sin(mid) * dt
        yaw = wrap(yaw_next)
    return out


def run_localizer(messages, params=None):
    loc = Localizer(params or PARAMS, PROFILE)
    errors = []
    for kind, msg, truth in messages:
        loc.push(kind, msg)
        loc.process_until(msg.t)
        pose = loc.pose(msg.t)
        if pose is not None:
            errors.append((msg.t, pose.x - truth[0], pose.y - truth[1], wrap(pose.yaw - truth[2]), pose))
    return loc, errors


def test_nothing_is_published_before_the_first_gnss_fix():
    loc = Localizer(PARAMS, PROFILE)
    for kind, msg, _ in drive(1.0):
        if kind != "gnss":
            loc.push(kind, msg)
    loc.process_until(1.0)
    assert loc.pose(1.0) is None
    fix0 = next(m for k, m, _ in drive(0.0) if k == "gnss")
    loc.push("gnss", fix0.model_copy(update={"t": 1.0}))
    loc.process_until(1.0)
    assert loc.pose(1.0) is not None


def test_ukf_converges_from_a_wrong_initial_yaw():
    # the magnetometer is 0.8 rad off, so the filter starts 0.8 rad wrong (σ 0.3: over-confident)
    loc, errors = run_localizer(drive(12.0, speed=3.0, yaw_rate=0.05, yaw0=1.0, imu_yaw_offset=0.8))
    start_err = errors[0][3]
    assert abs(start_err) > 0.7
    late = [abs(e[3]) for e in errors if e[0] > 6.0]
    assert max(late) < math.radians(0.5)
    assert max(math.hypot(e[1], e[2]) for e in errors if e[0] > 6.0) < 0.03


def test_yaw_stays_continuous_driving_west_across_pi():
    msgs = drive(15.0, speed=3.0, yaw_rate=0.02, yaw0=math.pi - 0.1)  # crosses +π into −π
    _, errors = run_localizer(msgs)
    assert max(abs(e[3]) for e in errors if e[0] > 4.0) < math.radians(0.5)
    assert all(-math.pi <= e[4].yaw < math.pi for e in errors)


def test_a_wandering_uncorrected_fix_does_not_drag_a_good_estimate():
    # RTK for 10 s, then 20 s of fixes without corrections whose error is a steady 0.7 m offset
    # to the left of the road (the worst a slow Gauss-Markov bias does over a dead zone)
    msgs = drive(30.0, speed=3.0, rtk=lambda t: t < 10.0, fix_error=lambda t: (0.0, 0.7) if t >= 10.0 else (0.0, 0.0))
    loc, errors = run_localizer(msgs)
    dead = [math.hypot(e[1], e[2]) for e in errors if e[0] >= 10.0]
    assert max(dead) < 0.1  # the fixes alone would be 0.7 m off
    assert loc.counts["gnss"] == 151
    poses = [e[4] for e in errors]
    assert poses[-1].position_std_m > 0.1  # but the filter knows it is dead reckoning


def standing(t0: float, t1: float, where: tuple, gyro_z=lambda t: 0.0, frozen: Imu | None = None, dt=0.01):
    """Messages of a vehicle standing at where = (x, y, yaw) from t0 to t1 (RTK fixes, the wheels at
    nought); the gyro reads gyro_z(t) plus noise, or `frozen` repeats one reading (t aside)."""
    rng = np.random.default_rng(5)
    x, y, yaw = where
    out = []
    for i in range(int(round((t1 - t0) / dt))):
        t = round(t0 + i * dt, 6)
        if i % 2 == 0:
            imu = (
                frozen.model_copy(update={"t": t})
                if frozen is not None
                else Imu(
                    t=t, yaw=yaw, roll=0.0, pitch=0.0, gyro_x=0.0, gyro_y=0.0,
                    gyro_z=gyro_z(t) + 0.002 * rng.standard_normal(), accel_x=0.0, accel_y=0.0, accel_z=9.81,
                )
            )  # fmt: skip
            out.append(("imu", imu, where))
        if i % 5 == 0:
            can = CanFrame(
                t=t, wheel_speed_rad_s=0.0, speed_mps=0.0, steering_wheel_deg=0.0, throttle_pedal=0.0,
                brake_pedal=0.0, steering_torque=False,
            )  # fmt: skip
            out.append(("can", can, where))
        if i % 20 == 0:
            noise = rng.normal(0, 0.007, 2)
            fix = GnssFix(
                t=t, x=x + noise[0], y=y + noise[1], z=0.0, lat=40.0, lon=-3.7, easting=440000.0 + x,
                northing=4474000.0 + y, zone=30, hemisphere="N", quality=4, rtk=True, satellites=12, hdop=0.8,
                var_x=0.007**2, var_y=0.007**2, var_z=2e-4,
            )  # fmt: skip
            out.append(("gnss", fix, where))
    return out


def test_a_standing_vehicle_s_heading_does_not_turn_with_a_gyro_bias():
    # GNSS cannot see a heading at a standstill: a gyro biased 0.01 rad/s for a minute would turn
    # it by 34 degrees; the wheels' nought is trusted instead
    moving = drive(5.0, speed=3.0)
    where = moving[-1][2]
    loc, errors = run_localizer(moving + standing(5.01, 65.0, where, gyro_z=lambda t: 0.01))
    assert abs(math.degrees(errors[-1][3])) < 0.2
    assert abs(errors[-1][1]) < 0.05 and abs(errors[-1][2]) < 0.05


def test_a_frozen_imu_in_a_bend_does_not_turn_the_heading_of_the_shuttle_it_stopped():
    """The soak's 100 s standstill: the IMU froze in the west hairpin, its last yaw rate repeated
    for 6.5 s while the shuttle stopped; the heading ended 20 degrees off and stayed so while it
    stood (the path ahead pointed into the verge). Identical readings in a row are a frozen IMU,
    not used; standing, the gyro is not used at all."""
    turning = drive(8.0, speed=2.5, yaw_rate=-0.08)
    last_imu = next(msg for kind, msg, _ in reversed(turning) if kind == "imu")
    where = turning[-1][2]
    frozen = standing(8.01, 14.5, where, frozen=last_imu)  # (stopping at once: the worst case is the standing)
    loc, errors = run_localizer(turning + frozen + standing(14.51, 40.0, where))
    assert loc.counts["imu_frozen"] >= 300  # all but the first two repeats of 6.5 s at 50 Hz, fused or not
    assert abs(math.degrees(errors[-1][3])) < 0.5
    # each guard alone is enough here; without either, the heading turns by the frozen rate
    for guards, off_by_deg in (((True, False), (0, 0.5)), ((False, True), (0, 0.5)), ((False, False), (20, 40))):
        frozen_guard, standstill_guard = guards
        params = PARAMS.model_copy(
            update={
                "imu_frozen_readings": 3 if frozen_guard else 10**9,
                "standstill_speed_mps": 0.02 if standstill_guard else 0.0,
            }
        )
        _, errors = run_localizer(turning + frozen + standing(14.51, 40.0, where), params)
        assert off_by_deg[0] <= abs(math.degrees(errors[-1][3])) < off_by_deg[1], guards


def test_an_outlier_without_corrections_is_gated():
    msgs = drive(
        12.0, speed=3.0, rtk=lambda t: t < 10.0, fix_error=lambda t: (60.0, 0.0) if 11.0 <= t < 11.1 else (0.0, 0.0)
    )
    loc, errors = run_localizer(msgs)
    assert loc.counts["gated"] == 1
    assert max(math.hypot(e[1], e[2]) for e in errors if e[0] >= 10.0) < 0.05


def test_a_late_fix_is_carried_forward_not_applied_in_the_past():
    msgs = drive(8.0, speed=3.0, yaw_rate=0.05)
    # deliver every fix 0.08 s late, after the IMU and CAN messages that follow it
    delayed = sorted(msgs, key=lambda m: m[1].t + (0.08 if m[0] == "gnss" else 0.0))
    params = PARAMS.model_copy(update={"hold_back_s": 0.0})
    loc = Localizer(params, PROFILE)
    for kind, msg, _ in delayed:
        loc.push(kind, msg)
        now = msg.t + (0.08 if kind == "gnss" else 0.0)
        loc.process_until(now)
    assert loc.counts["late"] > 30
    _, errors = run_localizer(msgs)
    final = loc.pose(8.0)
    ref = next(e[4] for e in reversed(errors) if e[0] <= 8.0)
    assert math.hypot(final.x - ref.x, final.y - ref.y) < 0.02


def test_pose_is_carried_forward_and_withheld_when_sensors_fall_silent():
    loc, errors = run_localizer(drive(5.0, speed=3.0))
    p0, p1 = loc.pose(5.0), loc.pose(5.5)
    assert p1.x - p0.x == pytest.approx(1.5, abs=0.02)
    assert p1.cov_xx > p0.cov_xx
    assert loc.pose(5.0 + loc.max_extrapolation_s + 0.01) is None


def test_ukf_state_and_covariance_stay_sane_under_a_long_dead_reckoning():
    f = PoseUKF(PARAMS.sigma_points, PARAMS.process_noise, PARAMS.gnss)
    f.initialize(0.0, 0.0, 0.0, 3.1, 3.0, 0.2, (1e-4, 1e-4, 1e-4, 1e-2, 1e-2))
    for k in range(1, 3001):
        f.update_yaw_rate(k * 0.02, 0.2, 4e-6)
    assert np.all(np.linalg.eigvalsh(f.P) > 0)
    assert -math.pi <= f.x[2] < math.pi


# ---- the closed loop --------------------------------------------------------------------------


def test_imu_yaw_offset_does_not_bias_the_estimate():
    means = []
    for offset in (0.12, -0.35):
        r = closed_loop.run(seconds=40.0, overrides={"sim": {"imu": {"yaw_offset_rad": offset}}})
        late = r["t"] > 10.0
        err = np.degrees(wrap(r["est_yaw"][late] - r["yaw"][late]))
        means.append(float(np.mean(err)))
        assert np.sqrt(np.mean(err**2)) < 0.3
    assert all(abs(m) < 0.1 for m in means)
    assert abs(means[0] - means[1]) < 0.05


def test_dead_zone_covariance_grows_error_stays_bounded_and_the_score_drops():
    route_zone = next(z for z in Route.from_tour("default").zones if z.kind == "rtk_loss")
    r = closed_loop.run(seconds=36.0, s0=route_zone.s_start - 25.0)
    inside = ~r["rtk_available"] & r["has_pose"]
    assert inside.sum() > 100
    # a fix taken just before the zone may still be fused within its period (0.2 s) after it
    cov = r["cov"][inside & (r["t"] >= r["t"][inside][0] + 0.3)]
    assert cov[-1] > 20 * cov[0] and np.all(np.diff(cov) > -1e-9)  # grows all the way through
    err = np.hypot(r["est_x"] - r["x"], r["est_y"] - r["y"])
    assert err[inside].max() < 0.5
    rtk_ok, lost_ok = closed_loop.settled_masks(r["t"], r["rtk_available"])
    assert r["score"][rtk_ok & r["has_pose"]].min() >= 0.9
    assert r["score"][lost_ok].max() <= 0.3
    assert r["summary"]["xte_max_m"] < 0.85


# ---- configuration ---------------------------------------------------------------------------


def test_yaw_from_poses_takes_its_parameters_from_the_localization_section():
    params = config.section(
        {"localization": {"yaw_from_poses": {"distance_m": 2.5, "min_speed_mps": 0.8}}},
        "localization",
        LocalizationParams,
    )
    yp = YawFromPoses.from_params(params.yaw_from_poses)
    assert (yp.distance_m, yp.min_speed_mps, yp.max_chord_s) == (2.5, 0.8, YawFromPosesParams().max_chord_s)


def test_a_bad_localization_setting_is_refused_naming_the_key():
    with pytest.raises(ConfigError, match=r"section 'localization': yaw_from_poses\.distance_m: .*greater than 0"):
        config.section({"localization": {"yaw_from_poses": {"distance_m": 0.0}}}, "localization", LocalizationParams)
    with pytest.raises(ConfigError, match=r"process_noise\.pos_m2: unknown key \(did you mean 'pos_m2_per_s'\?\)"):
        config.section({"localization": {"process_noise": {"pos_m2": 1e-3}}}, "localization", LocalizationParams)


# ---- the localization and odometry manager nodes, on the in-memory bus -------------------------

TICK_S = 0.01  # the test's time step: IMU every 2 ticks, CAN every 4, fixes every 20


class DrivingEast:
    """Two nodes on a MemoryNetwork driven by a ManualClock, fed by a vehicle driving east at
    2 m/s from x = 0 at t = 0: IMU 50 Hz (its magnetometer 0.12 rad off), CAN 25 Hz, RTK fixes
    5 Hz; the localization node steps at 50 Hz, the odometry manager at 20 Hz."""

    def __init__(self):
        cfg = run_config.build()
        network, self.clock = MemoryNetwork(), ManualClock()
        self.localization = LocalizationNode(cfg, clock=self.clock, bus=network.bus("localization", self.clock))
        self.odometry = OdometryManager(cfg, clock=self.clock, bus=network.bus("odometry_manager", self.clock))
        self.localization.setup()
        self.odometry.setup()
        self.sensors = network.bus("test", self.clock)
        self.poses = self.sensors.subscribe("localization/pose", queue=10_000)
        self.scores = self.sensors.subscribe("odometry/score", queue=10_000)
        self.tick = 0
        self.localization_step_times: list[float] = []

    @property
    def now(self) -> float:
        return round(self.tick * TICK_S, 9)

    def run_until(self, t_end: float, imu_can=True, fixes=True) -> None:
        while self.now < t_end - 1e-9:
            self.tick += 1
            t, k = self.now, self.tick
            x = 2.0 * t
            if imu_can and k % 2 == 0:
                self.sensors.publish(
                    "sensors/imu",
                    Imu(
                        t=t,
                        yaw=0.12,
                        roll=0.0,
                        pitch=0.0,
                        gyro_x=0.0,
                        gyro_y=0.0,
                        gyro_z=0.0,
                        accel_x=0.0,
                        accel_y=0.0,
                        accel_z=9.81,
                    ),
                )
            if imu_can and k % 4 == 0:
                self.sensors.publish(
                    "sensors/can",
                    CanFrame(
                        t=t,
                        wheel_speed_rad_s=2.0 / 0.28,
                        speed_mps=2.0,
                        steering_wheel_deg=0.0,
                        throttle_pedal=0.0,
                        brake_pedal=0.0,
                        steering_torque=False,
                    ),
                )
            if fixes and k % 20 == 0:
                self.sensors.publish(
                    "gnss/fix",
                    GnssFix(
                        t=t,
                        x=x,
                        y=0.0,
                        z=0.0,
                        lat=40.0,
                        lon=-3.7,
                        easting=440000.0 + x,
                        northing=4474000.0,
                        zone=30,
                        hemisphere="N",
                        quality=4,
                        rtk=True,
                        satellites=16,
                        hdop=0.7,
                        var_x=RTK_VAR,
                        var_y=RTK_VAR,
                        var_z=2e-4,
                    ),
                )
            self.clock.set(t)
            if k % 2 == 0:
                self.localization.step_once(t)
                self.localization_step_times.append(t)
            if k % 5 == 0:
                self.odometry.step_once(t)


def test_localization_and_odometry_manager_nodes():
    loop = DrivingEast()
    loop.odometry.step_once(0.0)
    ((_, first_score),) = loop.scores.drain()
    assert first_score.score == 0.0  # no pose yet: no trust

    loop.run_until(1.0 - TICK_S, fixes=False)
    assert loop.poses.drain() == []  # IMU and CAN alone: nothing published
    loop.run_until(4.0)  # the first fix is stamped 1.0
    received = [m for _, m in loop.poses.drain()]
    # the fix is applied hold_back_s late, at the node's next loop; from then on, a pose every loop
    assert 1.0 + PARAMS.hold_back_s <= received[0].t <= 1.0 + PARAMS.hold_back_s + 2 * TICK_S
    assert [p.t for p in received] == [t for t in loop.localization_step_times if t >= received[0].t]
    last = received[-1]
    assert last.x == pytest.approx(2.0 * last.t, abs=0.1) and abs(last.y) < 0.05
    assert abs(wrap(last.yaw)) < math.radians(1.0)  # the magnetometer's 0.12 rad is gone
    assert last.rtk and last.gnss_age_s < 0.5
    assert loop.scores.latest.score >= 0.9

    # the sensors fall silent: localization stops publishing, the pose goes stale, score 0
    silent_from = loop.now
    loop.poses.drain()
    loop.run_until(silent_from + 2.5, imu_can=False, fixes=False)
    last_pose_t = max(m.t for _, m in loop.poses.drain())
    assert last_pose_t <= silent_from + PARAMS.max_extrapolation_s
    assert loop.scores.latest.score == 0.0 and loop.scores.latest.pose_age_s > 0.5


def test_fixes_without_altitude_track_the_position_and_leave_the_height_alone():
    """A receiver that sends no altitude (GGA's altitude empty): x, y as usual; z starts unknown
    and is taken from the first fix that has one."""
    messages = drive(20.0, yaw0=0.2)
    no_z = [
        (k, m.model_copy(update={"z": None, "var_z": None}) if k == "gnss" and m.t < 10.0 else m, truth)
        for k, m, truth in messages
    ]
    early, early_errors = run_localizer([m for m in no_z if m[1].t < 10.0])
    assert max(math.hypot(e[1], e[2]) for e in early_errors if e[0] > 5.0) < 0.05
    assert early.altitude.var >= 1e5  # still unknown: no fix has given a height
    assert early_errors[-1][4].var_z >= 1e5  # and the pose says so (the path manager leaves it out)
    loc, errors = run_localizer(no_z)
    assert loc.altitude.var < 1.0 and abs(errors[-1][4].z) < 0.05  # the fixes from 10 s on said z = 0
    assert errors[-1][4].var_z < 1.0
