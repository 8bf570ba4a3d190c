"""Sensor models fed from the plant's state: GNSS (NMEA), IMU and the CAN bus.

Each model turns a `VehicleState` (simulator/vehicle.py) into the plain dict its message carries:

    gnss -> {"sentences": ["$GPGGA,...*CS", "$GPGST,...*CS"]}
    imu  -> {"yaw", "roll", "pitch", "gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z"}
    can  -> {"wheel_speed_rad_s", "speed_mps", "steering_wheel_deg",
             "throttle_pedal", "brake_pedal", "steering_torque"}

Noise comes from a seeded numpy Generator per sensor, so a run is repeatable; `noise=False`
gives exact readings (for tests). The figures (sigmas, offsets) are the `sim` section
(simulator/params.py).

GNSS (ARES paper §3.1): with fresh RTK corrections the fix is "RTK fixed" (GGA quality 4) with
a few millimetres of white noise. The corrections come over a 4G link (simulator/corrections.py):
inside a `no_4g` zone none arrive and the fix degrades as they age (RTK float, DGPS, then an
autonomous fix); inside an `rtk_loss` zone (the sky blocked) there is no RTK whatever the
corrections. Without RTK the error wanders: a first-order Gauss-Markov bias with a time constant
of tens of seconds plus some white noise, so that consecutive positions drift together rather
than jump; its size is that of the fix kind. The local (x, y) is a UTM offset from the stack's
`origin_utm` (ares.core.geodesy.LocalFrame converts to latitude/longitude). A GST sentence
carries the receiver's own error estimate (standard deviations of lat/lon/alt), which is
where a real receiver reports its covariance.

IMU: body frame x forward, y left, z up (REP-103); pitch positive nose down, so on a climb
pitch < 0 and the accelerometer's x axis reads +g·|sin(pitch)|. The yaw carries the constant
offset of a badly calibrated magnetometer (the reason the ARES odometry computes yaw from
consecutive GNSS positions instead).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ares.core import nmea_framing as nmea
from ares.core.geodesy import LocalFrame
from ares.core.geometry import wrap_angle
from ares.core.route import Route
from simulator.actuators import GRAVITY
from simulator.corrections import CorrectionsLink, FixKind, ReceiverCorrections
from simulator.params import SimCanParams, SimGnssParams, SimImuParams, SimParams
from simulator.scenario import ScenarioFault
from simulator.vehicle import VehicleState

# ---- NMEA fields ----------------------------------------------------------------------------


def _nmea_time(time_of_day_s: float) -> str:
    t = time_of_day_s % 86400.0
    hours = int(t // 3600)
    minutes = int((t - hours * 3600) // 60)
    seconds = t - hours * 3600 - minutes * 60
    text = f"{hours:02d}{minutes:02d}{seconds:05.2f}"
    return text if not text.endswith("60.00") else f"{hours:02d}{minutes:02d}59.99"


def _nmea_angle(value_deg: float, degree_digits: int) -> tuple[str, bool]:
    """(d)ddmm.mmmmmmm and whether the value is non-negative.

    Seven decimals of a minute are 0.19 mm of latitude: enough for millimetre RTK fixes.
    """
    a = abs(value_deg)
    degrees = int(a)
    minutes = round((a - degrees) * 60.0, 7)
    if minutes >= 60.0:
        degrees, minutes = degrees + 1, 0.0
    return f"{degrees:0{degree_digits}d}{minutes:010.7f}", value_deg >= 0.0


# ---- GNSS -----------------------------------------------------------------------------------


class GnssSensor:
    """A dual-frequency RTK receiver at the vehicle's reference point (rear-axle centre)."""

    faults: Sequence[ScenarioFault] = ()  # the scenario's sensor errors (SensorSuite sets them)

    def __init__(
        self,
        route: Route,
        params: SimGnssParams,
        frame: LocalFrame,
        rng: np.random.Generator | None = None,
        noise: bool = True,
    ):
        g = params
        self.route = route
        self.frame = frame
        self.noise = noise
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.altitude0 = frame.origin.altitude_m
        self.rtk_sigma = g.rtk_sigma_m
        self.float_sigma = g.float_sigma_m
        self.rtk_sigma_alt = g.rtk_sigma_alt_m
        self.float_sigma_alt = g.float_sigma_alt_m
        self.bias_tau_s = g.float_bias_tau_s
        # Split the uncorrected variance between the wandering bias and the white part.
        self.white_share = g.float_white_fraction
        self.bias_share = math.sqrt(max(1.0 - g.float_white_fraction**2, 0.0))
        self.no_rtk_quality = g.no_rtk_fix_quality
        self.hdop = {"rtk": g.rtk_hdop, "float": g.float_hdop}
        self.satellites = {"rtk": g.rtk_satellites, "float": g.float_satellites}
        self.time_of_day0 = g.start_time_of_day_s
        self.corrections = g.corrections
        self.receiver = ReceiverCorrections(g.corrections)
        # plain simulation's 4G link; with --wire the corrections come as RTCM (link None)
        self.link: CorrectionsLink | None = CorrectionsLink(route, g.corrections)
        # Bias state (east, north, up) in units of the float sigmas, running all the time so
        # that entering a dead zone picks up a wander already in progress.
        self._bias = self.rng.standard_normal(3) if noise else np.zeros(3)
        self._t_last: float | None = None

    # -- geometry --
    def local_to_latlon(self, x: float, y: float) -> tuple[float, float]:
        return self.frame.to_latlon(x, y)

    def latlon_to_local(self, lat: float, lon: float) -> tuple[float, float]:
        return self.frame.from_latlon_forced(lat, lon)

    def fix_kind(self, s: float, t: float) -> FixKind:
        """What the receiver's fix is at t: by its corrections' age, and no RTK where the sky is
        blocked (an `rtk_loss` zone) or in a gnss_outage."""
        if self.receiver.last is None and self.link is not None and self.link.up(s, t):
            self.receiver.received(t)  # asked before any fix was measured: the shuttle starts with them
        kind = self.receiver.kind(t)
        blocked = self.route.in_zone(s, "rtk_loss") or any(
            f.kind == "gnss_outage" and f.active(t, s) for f in self.faults
        )
        if blocked and kind.quality in (4, 5):
            return FixKind("single", self.no_rtk_quality, kind.age_s)
        return kind

    def rtk_available(self, s: float, t: float | None = None) -> bool:
        """The receiver is RTK fixed at t: its corrections fresh, the sky open."""
        return self.fix_kind(s, t if t is not None else 0.0).quality == 4

    def take_corrections(self, s: float, t: float) -> None:
        """Plain simulation: a correction arrives over the 4G link when one is due and it is up."""
        if self.link is None:
            return
        self.link.faults = self.faults
        if self.link.due(s, t):
            self.receiver.received(t)

    def fix_available(self, s: float, t: float) -> bool:
        """The receiver has a fix at all (not inside a scenario's gnss_outage)."""
        return not any(f.kind == "gnss_outage" and f.active(t, s) for f in self.faults)

    def _advance_bias(self, t: float) -> None:
        if self._t_last is not None and self.noise:
            dt = max(t - self._t_last, 0.0)
            phi = math.exp(-dt / self.bias_tau_s)
            self._bias = phi * self._bias + math.sqrt(1.0 - phi * phi) * self.rng.standard_normal(3)
        self._t_last = t

    def sigmas(self, kind: FixKind) -> tuple[float, float]:
        """(horizontal, vertical) 1-sigma error of a fix of this kind."""
        if kind.quality == 4:
            return self.rtk_sigma, self.rtk_sigma_alt
        horizontal = {5: self.corrections.rtk_float_sigma_m, 2: self.corrections.dgps_sigma_m}.get(
            kind.quality, self.float_sigma
        )
        return horizontal, self.float_sigma_alt * horizontal / self.float_sigma

    def error(self, state: VehicleState) -> tuple[np.ndarray, FixKind]:
        """Position error (east, north, up) in metres for this fix, and the fix's kind."""
        self._advance_bias(state.t)
        self.take_corrections(state.s, state.t)
        kind = self.fix_kind(state.s, state.t)
        if not self.noise:
            return np.zeros(3), kind
        horizontal, vertical = self.sigmas(kind)
        sig = np.array([horizontal, horizontal, vertical])
        if kind.quality == 4:
            return sig * self.rng.standard_normal(3), kind
        return sig * (self.bias_share * self._bias + self.white_share * self.rng.standard_normal(3)), kind

    def measure(self, state: VehicleState) -> dict:
        err, fix = self.error(state)
        lat, lon = self.local_to_latlon(state.x + err[0], state.y + err[1])
        alt = self.altitude0 + state.z + err[2]
        rtk = fix.quality == 4
        kind = "rtk" if rtk else "float"
        quality = fix.quality
        hhmmss = _nmea_time(self.time_of_day0 + state.t)
        lat_txt, north = _nmea_angle(lat, 2)
        lon_txt, east = _nmea_angle(lon, 3)
        corrected = quality in (2, 4, 5) and fix.age_s is not None
        age, station = (f"{min(fix.age_s or 0.0, 999.0):.1f}", "0001") if corrected else ("", "")
        gga = (
            f"GPGGA,{hhmmss},{lat_txt},{'N' if north else 'S'},{lon_txt},{'E' if east else 'W'},"
            f"{quality},{int(self.satellites[kind]):02d},{float(self.hdop[kind]):.1f},"
            f"{alt:.3f},M,0.000,M,{age},{station}"
        )
        sig_h, sig_v = self.sigmas(fix)
        # GST: RMS of range residuals, error ellipse (semi-major, semi-minor, orientation),
        # then the 1-sigma errors of latitude, longitude and altitude in metres.
        gst = f"GPGST,{hhmmss},{sig_h:.3f},{sig_h:.3f},{sig_h:.3f},0.0,{sig_h:.3f},{sig_h:.3f},{sig_v:.3f}"
        return {"sentences": [nmea.sentence(gga), nmea.sentence(gst)]}


# ---- IMU ------------------------------------------------------------------------------------


class ImuSensor:
    """An IMU with a magnetometer yaw: attitude, angular rates and specific force."""

    faults: Sequence[ScenarioFault] = ()  # the scenario's sensor errors (SensorSuite sets them)

    def __init__(self, params: SimImuParams, rng: np.random.Generator | None = None, noise: bool = True):
        self._last: dict | None = None
        self.noise = noise
        self.rng = rng if rng is not None else np.random.default_rng(1)
        self.yaw_offset = params.yaw_offset_rad
        self.yaw_sigma = params.yaw_sigma_rad
        self.attitude_sigma = params.attitude_sigma_rad
        self.gyro_sigma = params.gyro_sigma_rad_s
        self.accel_sigma = params.accel_sigma_mps2

    def _n(self, sigma: float, size: int | None = None):
        if not self.noise:
            return 0.0 if size is None else np.zeros(size)
        return sigma * self.rng.standard_normal(size)

    def bias_rad_s(self, t: float) -> float:
        """The scenario's gyro_bias faults active at t."""
        return sum(math.radians(f.bias_deg_s) for f in self.faults if f.kind == "gyro_bias" and f.active(t))

    def measure(self, state: VehicleState) -> dict:
        frozen = any(f.kind == "freeze_imu" and f.active(state.t) for f in self.faults)
        if frozen and self._last is not None:
            return dict(self._last)  # a stuck driver repeats its last reading
        self._last = self._measure(state)
        return dict(self._last)

    def _measure(self, state: VehicleState) -> dict:
        pitch, roll = state.pitch, state.roll
        # Specific force (what an accelerometer feels) = kinematic acceleration - gravity,
        # expressed in the body frame; with REP-103 pitch (nose down positive) gravity shows
        # as -g·sin(pitch) along x and g·cos(pitch)·cos(roll) along z.
        accel_x = state.accel - GRAVITY * math.sin(pitch)
        accel_y = state.lateral_accel + GRAVITY * math.cos(pitch) * math.sin(roll)
        accel_z = GRAVITY * math.cos(pitch) * math.cos(roll) + state.vertical_accel
        gyro = self._n(self.gyro_sigma, 3)
        acc = self._n(self.accel_sigma, 3)
        yaw = state.yaw + self.yaw_offset + self._n(self.yaw_sigma)
        return {
            "yaw": wrap_angle(yaw),
            "roll": float(roll + self._n(self.attitude_sigma)),
            "pitch": float(pitch + self._n(self.attitude_sigma)),
            "gyro_x": float(gyro[0]),  # roll rate: the model has no roll
            "gyro_y": float(state.pitch_rate + gyro[1]),
            "gyro_z": float(state.yaw_rate + gyro[2] + self.bias_rad_s(state.t)),
            "accel_x": float(accel_x + acc[0]),
            "accel_y": float(accel_y + acc[1]),
            "accel_z": float(accel_z + acc[2]),
        }


# ---- CAN ------------------------------------------------------------------------------------


class CanSensor:
    """What the vehicle's CAN bus reports: encoder wheel speed, steering angle, pedals."""

    faults: Sequence[ScenarioFault] = ()  # the scenario's sensor errors (SensorSuite sets them)

    def __init__(
        self, params: SimCanParams, wheel_radius_m: float, rng: np.random.Generator | None = None, noise: bool = True
    ):
        self.noise = noise
        self.rng = rng if rng is not None else np.random.default_rng(2)
        self.wheel_radius_m = float(wheel_radius_m)
        self.speed_sigma = params.speed_sigma_mps
        self.steer_sigma = params.steer_sigma_deg

    def measure(self, state: VehicleState) -> dict:
        omega = state.wheel_speed_rad_s * (
            1.0 + sum(f.scale for f in self.faults if f.kind == "wheel_speed_scale" and f.active(state.t))
        )
        # An encoder that sees no pulses reads exactly zero: noise only while the wheels turn.
        if self.noise and omega != 0.0:
            omega += (self.speed_sigma / self.wheel_radius_m) * self.rng.standard_normal()
        steer = state.steering_wheel_deg + (self.steer_sigma * self.rng.standard_normal() if self.noise else 0.0)
        return {
            "wheel_speed_rad_s": float(omega),
            # The rear-axle speed the odometry wants, from the driven front wheel (DBW eq. 14).
            "speed_mps": float(omega * self.wheel_radius_m * math.cos(state.wheel_angle_rad)),
            "steering_wheel_deg": float(steer),
            "throttle_pedal": float(state.throttle_pedal),
            "brake_pedal": float(state.brake_pedal),
            "steering_torque": bool(state.steering_torque),
        }


# ---- all three --------------------------------------------------------------------------------


class SensorSuite:
    """The three sensors of one vehicle, each with its own random stream from one seed."""

    def __init__(
        self,
        route: Route,
        sim: SimParams,
        frame: LocalFrame,
        wheel_radius_m: float,
        seed: int | None = None,
        noise: bool = True,
        faults: Sequence[ScenarioFault] = (),
    ):
        base = sim.seed if seed is None else int(seed)
        gnss_rng, imu_rng, can_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(base).spawn(3))
        self.gnss = GnssSensor(route, sim.gnss, frame, gnss_rng, noise)
        self.imu = ImuSensor(sim.imu, imu_rng, noise)
        self.can = CanSensor(sim.can, wheel_radius_m, can_rng, noise)
        # a scenario's sensor errors (simulator.scenario.ScenarioFault): each sensor reads the kinds it has
        for sensor in (self.gnss, self.imu, self.can):
            sensor.faults = list(faults)
