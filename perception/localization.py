"""Localization: GNSS, IMU gyro and wheel odometry fused by a UKF (ARES paper §3.1).

Inputs:   gnss/fix (GnssFix: local x, y, z, variances, rtk) · sensors/imu (Imu: the gyro's
          yaw rate and the pitch are used; the magnetometer yaw only as the first guess of
          the heading before the vehicle has moved, never afterwards) · sensors/can
          (CanFrame: rear-axle speed, steering-wheel angle)
Outputs:  localization/pose (Pose of the rear-axle centre with its covariance, every loop,
          from the first GNSS fix on; before it nothing is published, so the controller
          stays silent and the bridge's watchdog keeps the vehicle stopped)
Params:   LocalizationParams below; the vehicle profile (wheelbase_m, k_cg, steering_ratio).

Pipeline (the `Localizer` class, also used in-process by ares.tools.harness.closed_loop):

  * every message is applied at its own stack time `t`, in time order: messages are held
    back `hold_back_s` so that a GNSS fix, which reaches this node later than the raw
    sensors (the gnss node parses NMEA first), is not overtaken by them; whatever still
    arrives late is applied at the filter's time (a fix shifted forward by the motion
    estimated since its time), and anything later than `max_late_s` is dropped;
  * GNSS fix -> UKF position update, yaw from poses (eqs. 1-2) -> UKF yaw update, altitude;
  * IMU -> UKF yaw-rate update (gyro z) and the pitch (for the slope), unless the IMU is
    frozen: `imu_frozen_readings` identical readings in a row (a real IMU's noise never
    repeats exactly) are not used until the readings move again;
  * CAN -> wheel odometry (eqs. 3-5) -> UKF speed and yaw-rate update. Standing (the wheels'
    speed below `standstill_speed_mps`) the wheels' yaw rate, nought, is trusted over the gyro
    (`standstill_yaw_rate_var`), and the gyro is not fused: at a standstill GNSS cannot correct
    the heading, so a gyro's bias or a frozen reading would turn it unchecked. (A 6.5 s IMU freeze in the west hairpin,
    the shuttle stopping, used to leave the heading 20 degrees off for as long as it stood: in
    a soak the obstacle manager saw the verge in the path ahead and held it for 100 s.)
  * the published pose is the filter's state carried forward to the loop's time by the
    process model (the covariance grown by the process noise), so a consumer sees where the
    vehicle is now, not where it was at the last message. If no sensor message has been
    applied for `max_extrapolation_s`, nothing is published: a pose from nowhere is worse
    than none (it goes stale, the odometry score drops to 0, the controller stops).
"""

from __future__ import annotations

import heapq
import itertools
import math

import numpy as np

from ares.core.config import Params, VehicleProfile, param
from ares.core.geometry import wrap_angle
from ares.core.messages import CanFrame, GnssFix, Imu, Pose
from perception.ukf import YAW, GnssUpdateParams, PoseUKF, ProcessNoise, SigmaPointParams, V, W, correlated_inflation
from perception.wheel_odometry import WheelOdometry
from perception.yaw_from_poses import PoseFix, YawFromPoses, YawFromPosesParams

KINDS = ("gnss", "imu", "can")
STANDING_FRESH_S = 0.2  # a CAN reading that said "standing" holds for the gyro this long (CAN comes at 20-50 Hz)
UNKNOWN_Z_VAR_M2 = 1.0e6  # the altitude before any fix has given one: the first that does takes over


class InitialHeading(Params):
    yaw_sigma_rad: float = param(
        0.3, "first heading = the IMU's magnetometer yaw (offset and all), until the vehicle moves", unit="rad", gt=0
    )
    yaw_sigma_no_imu_rad: float = param(1.5, "no IMU at the first fix: heading 0, this uncertain", unit="rad", gt=0)


class SensorVariances(Params):
    gyro_var: float = param(4.0e-6, "IMU z rate: 0.002 rad/s white noise", unit="(rad/s)^2", gt=0)
    wheel_speed_var: float = param(1.0e-4, "CAN rear-axle speed", unit="(m/s)^2", gt=0)
    wheel_yaw_rate_var: float = param(
        1.0e-4,
        "eq. 5 yaw rate: kept above the gyro's, tyres slip and the shuttle steers both axles",
        unit="(rad/s)^2",
        gt=0,
    )
    standstill_yaw_rate_var: float = param(
        1.0e-8,
        "standing, the wheels' yaw rate (nought): trusted over the gyro, whose bias or frozen reading "
        "must not turn a heading that GNSS cannot correct at a standstill",
        unit="(rad/s)^2",
        gt=0,
    )


class LocalizationParams(Params):
    """UKF fusion of GNSS, pose yaw, gyro and wheel odometry."""

    rate_hz: float = param(50.0, "a pose is published every loop, from the first GNSS fix on", unit="Hz", gt=0)
    hold_back_s: float = param(
        0.05,
        "messages are applied this late, in time order: a fix (parsed by the gnss "
        "node) is not overtaken by raw sensors",
        unit="s",
        ge=0,
    )
    max_late_s: float = param(
        0.5,
        "a message later than this behind the filter is dropped (later ones: applied at the filter's time)",
        unit="s",
        gt=0,
    )
    max_extrapolation_s: float = param(
        1.0, "no sensor message applied for this long: publish nothing (the pose goes stale)", unit="s", gt=0
    )
    max_buffer: int = param(4000, "messages held for time ordering at most", ge=1)
    standstill_speed_mps: float = param(
        0.02, "the wheels' speed below which the vehicle stands (and does not turn)", unit="m/s", ge=0
    )
    imu_frozen_readings: int = param(
        3, "this many identical IMU readings in a row are a frozen IMU: not used until they move again", ge=2
    )
    initial: InitialHeading = param(doc="the heading before the vehicle has moved", factory=InitialHeading)
    yaw_from_poses: YawFromPosesParams = param(doc="ARES eqs. 1-2", factory=YawFromPosesParams)
    sensors: SensorVariances = param(doc="measurement variances", factory=SensorVariances)
    process_noise: ProcessNoise = param(doc="the UKF's process noise", factory=ProcessNoise)
    gnss: GnssUpdateParams = param(doc="how GNSS fixes are weighed", factory=GnssUpdateParams)
    sigma_points: SigmaPointParams = param(doc="the unscented transform", factory=SigmaPointParams)
    altitude_q_m2_per_s: float = param(0.01, "process noise of the z filter beside the UKF", unit="m^2/s", gt=0)
    queues: int = param(512, "sensor messages buffered per input between two loops", ge=1)


class AltitudeFilter:
    """Scalar Kalman filter for z beside the UKF: climbs at v·tan(−pitch) (REP-103 pitch is
    positive nose down), corrected by the GNSS height."""

    def __init__(self, q_m2_per_s: float = 0.01):
        self.q = float(q_m2_per_s)
        self.z = 0.0
        self.var = 0.0
        self.t: float | None = None

    def initialize(self, t: float, z: float | None, var: float | None) -> None:
        """From the first fix; a fix without altitude starts at the origin's, not yet known."""
        self.t, self.z, self.var = (t, z, var) if z is not None and var is not None else (t, 0.0, UNKNOWN_Z_VAR_M2)

    def predict(self, t: float, climb_rate: float) -> None:
        dt = max(t - self.t, 0.0)
        self.z += climb_rate * dt
        self.var += self.q * dt
        self.t = max(self.t, t)

    def update(self, z: float, var: float) -> None:
        gain = self.var / (self.var + var)
        self.z += gain * (z - self.z)
        self.var *= 1.0 - gain


class Localizer:
    """The localization pipeline without the bus: push messages, process them in time order,
    read the pose."""

    def __init__(self, params: LocalizationParams, vehicle_profile: VehicleProfile):
        self.params = params
        self.ukf = PoseUKF(params.sigma_points, params.process_noise, params.gnss)
        self._yaw_guess_pending = False  # initialised before any IMU message: heading unknown
        self.yaw_poses = YawFromPoses.from_params(params.yaw_from_poses)
        self.use_float_yaw = params.yaw_from_poses.use_without_rtk
        self.wheels = WheelOdometry(vehicle_profile)
        self.gyro_var = params.sensors.gyro_var
        self.wheel_speed_var = params.sensors.wheel_speed_var
        self.wheel_yaw_rate_var = params.sensors.wheel_yaw_rate_var
        self.standstill_yaw_rate_var = params.sensors.standstill_yaw_rate_var
        self.standstill_speed_mps = params.standstill_speed_mps
        self.imu_frozen_readings = params.imu_frozen_readings
        self._last_imu_reading: tuple | None = None
        self._imu_repeats = 0  # identical readings in a row, this one included
        self._standing_at: float | None = None  # the time of the last CAN reading that said the vehicle stands
        self.init_yaw_var_imu = params.initial.yaw_sigma_rad**2
        self.init_yaw_var_none = params.initial.yaw_sigma_no_imu_rad**2
        self.hold_back_s = params.hold_back_s
        self.max_late_s = params.max_late_s
        self.max_extrapolation_s = params.max_extrapolation_s
        self.max_buffer = params.max_buffer
        self.altitude = AltitudeFilter(params.altitude_q_m2_per_s)
        self.float_correlation_s = self.ukf.float_correlation_s
        # latest raw readings (for initialisation and the slope)
        self.pitch = 0.0
        self.imu_yaw: float | None = None
        self.gyro_rate: float | None = None
        self.can_speed: float | None = None
        # the heading integrated from the filter's yaw rate: the chord correction of eq. 1
        self.heading = 0.0
        # bookkeeping
        self.last_fix_t: float | None = None
        self.last_fix_rtk = False
        self._last_float_z_t: float | None = None
        self.counts = {"gnss": 0, "imu": 0, "can": 0, "yaw": 0, "late": 0, "dropped": 0, "gated": 0, "imu_frozen": 0}
        self._buffer: list = []
        self._seq = itertools.count()

    @property
    def initialized(self) -> bool:
        return self.ukf.initialized

    # ---- input ----------------------------------------------------------------------------
    def push(self, kind: str, msg) -> None:
        """Queue one message ("gnss" GnssFix, "imu" Imu, "can" CanFrame) for time-ordered processing."""
        if kind not in KINDS:
            raise ValueError(f"unknown message kind {kind!r}")
        heapq.heappush(self._buffer, (float(msg.t), next(self._seq), kind, msg))
        if len(self._buffer) > self.max_buffer:
            # should never happen in a running stack: lose the oldest rather than all memory
            self._buffer = heapq.nsmallest(self.max_buffer, self._buffer)[1:]
            heapq.heapify(self._buffer)
            self.counts["dropped"] += 1

    def process_until(self, t_cut: float) -> int:
        """Apply every queued message stamped up to t_cut, oldest first."""
        n = 0
        while self._buffer and self._buffer[0][0] <= t_cut:
            _, _, kind, msg = heapq.heappop(self._buffer)
            self.handle(kind, msg)
            n += 1
        return n

    def handle(self, kind: str, msg) -> None:
        """Apply one message now (callers normally go through push/process_until)."""
        if kind == "gnss":
            self._on_fix(msg)
        elif kind == "imu":
            self._on_imu(msg)
        elif kind == "can":
            self._on_can(msg)
        else:
            raise ValueError(f"unknown message kind {kind!r}")

    # ---- handlers --------------------------------------------------------------------------
    def _lateness(self, t: float) -> float | None:
        """How late a message is for the filter (0 if on time); None if too late to use."""
        if not self.ukf.initialized or t >= self.ukf.t:
            return 0.0
        late = self.ukf.t - t
        if late > self.max_late_s:
            self.counts["dropped"] += 1
            return None
        self.counts["late"] += 1
        return late

    def _advance(self, t: float) -> float:
        """Predict the UKF (and the heading integral, the altitude) to t; returns the time used."""
        f = self.ukf
        t_use = max(t, f.t)
        dt = t_use - f.t
        if dt > 0.0:
            # heading integral with the yaw rate over the step (constant, as in the process model)
            self.heading += f.x[W] * dt
            self.altitude.predict(t_use, f.x[V] * math.tan(-self.pitch))
        f.predict_to(t_use)
        return t_use

    def _on_imu(self, imu: Imu) -> None:
        self.counts["imu"] += 1
        reading = (imu.yaw, imu.roll, imu.pitch, imu.gyro_x, imu.gyro_y, imu.gyro_z)
        reading += (imu.accel_x, imu.accel_y, imu.accel_z)
        self._imu_repeats = self._imu_repeats + 1 if reading == self._last_imu_reading else 1
        self._last_imu_reading = reading
        if self._imu_repeats >= self.imu_frozen_readings:
            self.counts["imu_frozen"] += 1  # a frozen IMU says nothing about the motion: neither rate nor pitch
            return
        self.pitch = imu.pitch
        self.imu_yaw = imu.yaw
        self.gyro_rate = imu.gyro_z
        if self.ukf.initialized and self._yaw_guess_pending:
            # the first fix came before any IMU message: take the magnetometer's heading as the
            # first guess now rather than keep "heading unknown" until the vehicle has moved
            self.ukf.reset_yaw(imu.yaw, self.init_yaw_var_imu)
            self._yaw_guess_pending = False
        if not self.ukf.initialized or self._lateness(imu.t) is None:
            return
        if self._standing_at is not None and imu.t - self._standing_at <= STANDING_FRESH_S:
            return  # standing: the wheels' nought says more than the gyro (see the module's docstring)
        t = self._advance(imu.t)
        # the gyro's yaw rate: NOT the magnetometer yaw, which carries the calibration offset
        self.ukf.update_yaw_rate(t, imu.gyro_z, self.gyro_var)

    def _on_can(self, can: CanFrame) -> None:
        self.counts["can"] += 1
        reading = self.wheels.reading(can.t, can.speed_mps, can.steering_wheel_deg, self.pitch)
        self.can_speed = reading.v
        if not self.ukf.initialized or self._lateness(can.t) is None:
            return
        t = self._advance(can.t)
        standing = abs(reading.v) < self.standstill_speed_mps
        self._standing_at = can.t if standing else None
        yaw_rate_var = self.standstill_yaw_rate_var if standing else self.wheel_yaw_rate_var
        self.ukf.update_wheel(t, reading.v, reading.yaw_rate, self.wheel_speed_var, yaw_rate_var)

    def _initialize(self, fix: GnssFix) -> None:
        yaw, yaw_var = (
            (self.imu_yaw, self.init_yaw_var_imu) if self.imu_yaw is not None else (0.0, self.init_yaw_var_none)
        )
        v, v_var = (self.can_speed, 0.01) if self.can_speed is not None else (0.0, 1.0)
        w, w_var = (self.gyro_rate, 0.01) if self.gyro_rate is not None else (0.0, 0.1)
        self.ukf.initialize(fix.t, fix.x, fix.y, yaw, v, w, (fix.var_x, fix.var_y, yaw_var, v_var, w_var))
        self.altitude.initialize(fix.t, fix.z, fix.var_z)
        self.heading = 0.0
        self.yaw_poses.reset()
        self._yaw_guess_pending = self.imu_yaw is None

    def _on_fix(self, fix: GnssFix) -> None:
        self.counts["gnss"] += 1
        if not self.ukf.initialized:
            self._initialize(fix)
            self._fused_fix(fix)
            self.yaw_poses.add(PoseFix(fix.t, fix.x, fix.y, fix.var_x, fix.var_y, fix.rtk, self.heading), 0.0)
            return
        late = self._lateness(fix.t)
        if late is None:
            return
        t = self._advance(fix.t)
        f = self.ukf
        # A late fix: carry it forward by the motion estimated since its time.
        yaw, v = f.x[YAW], f.x[V]
        shift_x, shift_y = v * math.cos(yaw) * late, v * math.sin(yaw) * late
        heading_at_fix = self.heading - f.x[W] * late
        used = f.update_position(t, fix.x + shift_x, fix.y + shift_y, fix.var_x, fix.var_y, fix.rtk)
        if not used:
            self.counts["gated"] += 1
        else:
            self._fused_fix(fix)
        if fix.z is not None and fix.var_z is not None:
            self._altitude_update(fix)
        # Yaw from this fix and the last one d metres behind it (eqs. 1-2).
        m = self.yaw_poses.add(
            PoseFix(fix.t, fix.x, fix.y, fix.var_x, fix.var_y, fix.rtk, heading_at_fix), float(f.x[V])
        )
        if m is not None and (fix.rtk or self.use_float_yaw):
            self.counts["yaw"] += 1
            f.update_yaw(t, m.yaw + f.x[W] * late, m.variance)

    def _altitude_update(self, fix: GnssFix) -> None:
        z_var = fix.var_z
        if not fix.rtk:
            interval = None if self._last_float_z_t is None else fix.t - self._last_float_z_t
            z_var *= correlated_inflation(interval, self.float_correlation_s)
            self._last_float_z_t = fix.t
        else:
            self._last_float_z_t = None
        self.altitude.update(fix.z, z_var)

    def _fused_fix(self, fix: GnssFix) -> None:
        self.last_fix_t = fix.t
        self.last_fix_rtk = fix.rtk

    # ---- output ---------------------------------------------------------------------------
    def pose(self, now: float) -> Pose | None:
        """The estimate carried forward to `now`; None before the first fix or when no
        sensor message has been applied for max_extrapolation_s."""
        f = self.ukf
        if not f.initialized or now - f.t > self.max_extrapolation_s:
            return None
        x, P = f.extrapolate(now)
        z = self.altitude.z + x[V] * math.tan(-self.pitch) * max(now - self.altitude.t, 0.0)
        pos = P[:2, :2]
        std = math.sqrt(max(float(np.linalg.eigvalsh(pos)[-1]), 0.0))
        return Pose(
            t=now,
            x=float(x[0]),
            y=float(x[1]),
            z=float(z),
            yaw=float(wrap_angle(x[YAW])),
            v=float(x[V]),
            yaw_rate=float(x[W]),
            cov_xx=float(P[0, 0]),
            cov_xy=float(P[0, 1]),
            cov_yy=float(P[1, 1]),
            var_yaw=float(P[YAW, YAW]),
            var_v=float(P[V, V]),
            var_z=float(self.altitude.var + self.altitude.q * max(now - self.altitude.t, 0.0)),
            position_std_m=std,
            rtk=self.last_fix_rtk,
            gnss_age_s=None if self.last_fix_t is None else max(now - self.last_fix_t, 0.0),
        )
