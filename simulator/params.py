"""The `sim` section: rates, noise, passengers and the hardware's own behaviour of the simulated shuttle."""

from __future__ import annotations

from ares.core.config import Params, param


class SimCorrectionsParams(Params):
    """The simulated receiver's corrections (sim.corrections) and its fix as they age."""

    rate_hz: float = param(1.0, "corrections a second from the base station (RTCM epochs)", unit="Hz", gt=0)
    fixed_max_age_s: float = param(
        5.0, "RTK fixed (GGA quality 4) while the newest correction is at most this old", unit="s", gt=0
    )
    float_max_age_s: float = param(15.0, "... RTK float (quality 5) up to this age", unit="s", gt=0)
    dgps_max_age_s: float = param(
        60.0, "... DGPS (quality 2) up to this, then an autonomous fix (quality 1)", unit="s", gt=0
    )
    refix_s: float = param(3.0, "corrections back after a loss: RTK float this long before fixed again", unit="s", ge=0)
    rtk_float_sigma_m: float = param(0.25, "horizontal error of an RTK float fix", unit="m", gt=0)
    dgps_sigma_m: float = param(0.5, "horizontal error of a DGPS fix (the paper's ~0.5 m without RTK)", unit="m", gt=0)


class SimGnssParams(Params):
    """The simulated RTK receiver (ARES §3.1)."""

    rtk_sigma_m: float = param(0.007, "horizontal noise with RTK corrections (~5e-5 m^2 covariance)", unit="m", gt=0)
    float_sigma_m: float = param(0.7, "horizontal error without corrections (~0.5 m^2 covariance)", unit="m", gt=0)
    rtk_sigma_alt_m: float = param(0.015, "vertical noise with RTK corrections", unit="m", gt=0)
    float_sigma_alt_m: float = param(1.2, "vertical error without corrections", unit="m", gt=0)
    float_bias_tau_s: float = param(
        40.0, "uncorrected error wanders: first-order Gauss-Markov bias ...", unit="s", gt=0
    )
    float_white_fraction: float = param(0.3, "... plus white noise with this share of float_sigma_m", ge=0, le=1)
    no_rtk_fix_quality: int = param(1, "GGA fix quality without corrections (1 GPS, 2 DGPS); 4 with RTK", ge=1, le=8)
    rtk_hdop: float = param(0.7, "HDOP with RTK corrections", gt=0)
    float_hdop: float = param(1.3, "HDOP without corrections", gt=0)
    rtk_satellites: int = param(16, "satellites in use with RTK corrections", ge=0)
    float_satellites: int = param(10, "satellites in use without corrections", ge=0)
    start_time_of_day_s: float = param(36000.0, "UTC time of day at sim t = 0 (10:00:00)", unit="s", ge=0, lt=86400)
    corrections: SimCorrectionsParams = param(
        doc="its RTK corrections: their rate, and the fix as they age", factory=SimCorrectionsParams
    )


class SimImuParams(Params):
    yaw_offset_rad: float = param(0.12, "the badly calibrated magnetometer yaw of the ARES paper", unit="rad")
    gyro_sigma_rad_s: float = param(0.002, "gyro white noise", unit="rad/s", ge=0)
    accel_sigma_mps2: float = param(0.05, "accelerometer white noise", unit="m/s^2", ge=0)
    yaw_sigma_rad: float = param(0.01, "white noise on the magnetometer yaw (on top of the offset)", unit="rad", ge=0)
    attitude_sigma_rad: float = param(0.003, "roll / pitch noise", unit="rad", ge=0)


class SimCanParams(Params):
    speed_sigma_mps: float = param(0.01, "wheel-speed noise while the wheels turn", unit="m/s", ge=0)
    steer_sigma_deg: float = param(0.5, "steering-wheel angle noise", unit="deg", ge=0)


class SuspensionParams(Params):
    natural_hz: float = param(1.5, "body bounce over the roughness: natural frequency", unit="Hz", gt=0)
    damping_ratio: float = param(0.35, "... and damping", gt=0)


class DriverParams(Params):
    """The human of VehiclePlant.step_manual."""

    steering_time_constant_s: float = param(
        0.3, "how fast the hand approaches the wheel angle it wants", unit="s", gt=0
    )
    steering_max_rate_deg_s: float = param(360.0, "fastest turn of the wheel by hand", unit="deg/s", gt=0)
    torque_threshold_deg: float = param(
        2.0, "the column's torque sensor fires while the hand leads the wheel by more", unit="deg", gt=0
    )


class SimBodyParams(Params):
    """Doors, ramp and the people passing them (simulator/body.py)."""

    rate_hz: float = param(10.0, "the body's sensors report this often", unit="Hz", gt=0)
    door_travel_s: float = param(2.5, "doors: closed to open (or back)", unit="s", gt=0)
    ramp_travel_s: float = param(6.0, "ramp: stowed to deployed (or back)", unit="s", gt=0)
    per_person_s: float = param(2.0, "one person through the entrance", unit="s", gt=0)
    at_poi_m: float = param(
        3.0, "standing this close to a POI's stop point, the shuttle is at it (for its people)", unit="m", gt=0
    )


class SimParams(Params):
    physics_hz: float = param(100.0, "physics steps per stack second (the simulator's loop rate)", unit="Hz", gt=0)
    gnss_hz: float = param(5.0, "NMEA GGA + GST rate", unit="Hz", gt=0)
    imu_hz: float = param(50.0, "IMU rate", unit="Hz", gt=0)
    can_hz: float = param(20.0, "CAN frame rate", unit="Hz", gt=0)
    truth_hz: float = param(20.0, "ground-truth rate (for evaluation)", unit="Hz", gt=0)
    passengers: int = param(2, "passengers on board", ge=0)
    seed: int = param(7, "seed of every random stream of the simulation", ge=0)
    start_s_m: float = param(0.0, "where along the route the shuttle stands at start", unit="m", ge=0)
    gnss: SimGnssParams = param(doc="the receiver", factory=SimGnssParams)
    imu: SimImuParams = param(doc="the IMU", factory=SimImuParams)
    can: SimCanParams = param(doc="the CAN bus", factory=SimCanParams)
    road_roughness_m: float = param(0.02, "RMS height of the road surface's undulations", unit="m", ge=0)
    roughness_wavelength_m: tuple[float, float] = param(
        (1.5, 15.0), "road undulations between these wavelengths", unit="m"
    )
    suspension: SuspensionParams = param(doc="body bounce over the roughness", factory=SuspensionParams)
    driver: DriverParams = param(doc="the simulated human driver", factory=DriverParams)
    body: SimBodyParams = param(doc="doors, ramp and passengers", factory=SimBodyParams)
    actuator_timeout_s: float = param(0.5, "the DBW board brakes if the bridge goes quiet this long", unit="s", gt=0)
    parking_brake_effort: float = param(0.3, "a vehicle left in Manual with nobody driving is parked", ge=0, le=1)
    max_catch_up_steps: int = param(
        50, "after a stall, jump ahead rather than replay more physics steps than this", ge=1
    )
