"""Typed configuration: one model per section, its defaults in one place, unknown keys refused.

Every section of a run's configuration is a pydantic model (`Params`) whose fields carry their
default, unit, range and meaning (`param(...)`). Core sections (vehicle id, bus, heartbeat,
clock, the local frame's origin, the vehicle profile) are defined here; each node defines its
own section next to its code (`Node.Params`), and the composition layer (ares.run_config)
assembles the whole model from the process table. Nothing else holds defaults: no YAML file of
defaults, no `dict.get(key, default)` in code.

Files: vehicle profiles and tours are data (ares/config/vehicles/*.yaml, tours/*.yaml), typed
by VehicleProfile and TourDescription. A user's run configuration is a YAML file of overrides
(`ares run --config FILE`). Each file is validated on its own, so an error names the file, the
key and what is allowed; `ConfigError` carries that sentence.

A run's effective configuration (validated, every default filled in) is written once by
`ares run` to a JSON file whose path reaches every child process through ARES_RUN_CONFIG, so
all processes of a run agree on it; a node validates its own section again on start.
"""
from __future__ import annotations

import copy
import difflib
import json
import math
import os
from pathlib import Path
from typing import Any, Literal, Mapping

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

CONFIG_DIR = Path(__file__).parent / "config"
RUN_CONFIG_ENV = "ARES_RUN_CONFIG"
VEHICLE_ID_PATTERN = r"^[A-Za-z0-9_.-]{1,64}$"      # one key segment of ares/<vehicle_id>/...


class ConfigError(ValueError):
    """A configuration that cannot be used; the message names the file, the key and why."""


class Params(BaseModel):
    """Base of every configuration section: unknown keys are errors, values are validated,
    instances are read-only (a node's parameters do not change under it)."""
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False, validate_default=True)


def param(default: Any = ..., doc: str = "", *, unit: str | None = None, factory=None, **constraints) -> Any:
    """A configuration field: its default (or `factory` for mutable ones), what it means, its
    unit and its range (ge, gt, le, lt, pattern, ...), as `ares describe` shows them."""
    extra = {"unit": unit} if unit else None
    if factory is not None:
        return Field(default_factory=factory, description=doc, json_schema_extra=extra, **constraints)
    return Field(default, description=doc, json_schema_extra=extra, **constraints)


# ---- core sections ---------------------------------------------------------------------------

class BusSettings(Params):
    mode: Literal["peer", "client"] = param("peer", "how processes join the bus: peer (a direct link between "
                                            "processes, lowest latency) or client (everything through the router)")
    router: str = param("tcp/127.0.0.1:7447", "the router's endpoint; the embedded router listens here",
                        pattern=r"^[a-z][a-z0-9+-]*/\S+$")
    embedded_router: bool = param(True, "the supervisor hosts the router in its own session (no zenohd needed)")
    listen: list[str] = param(doc="where a peer accepts direct links from other peers (loopback by default)",
                              factory=lambda: ["tcp/127.0.0.1:0"])
    lease_ms: int = param(2000, "liveliness lease: a frozen process's token disappears after ~3/4 of it",
                          unit="ms", ge=200)
    service_timeout_s: float = param(2.0, "longest a service call waits for its reply", unit="s", gt=0)


class HeartbeatSettings(Params):
    period_s: float = param(0.2, "heartbeat period, wall clock: it reveals a stuck Python loop, not sim time",
                            unit="s", gt=0)
    stale_after_s: float = param(2.0, "a heartbeat older than this means the process is hung (generous: a "
                                      "loaded 2-core machine can starve a process for ~1 s)", unit="s", gt=0)


class LockstepSettings(Params):
    """`--speed max`: the simulator drives the stack clock (ares.lockstep)."""
    participants: list[str] = param(doc="processes the simulator waits for before advancing the clock; filled "
                                        "in by `ares run` from the topic graph (every process its outputs feed)",
                                    factory=list)
    max_wait_s: float = param(2.0, "wall seconds a participant may hold the clock back before the simulator goes "
                                   "on without it (it rejoins with its next report)", unit="s", gt=0)
    start_wait_s: float = param(60.0, "wall seconds the simulator waits at start for every participant to join",
                                unit="s", gt=0)
    max_step_s: float = param(0.1, "longest clock step while no participant is due", unit="s", gt=0)
    pace: float | None = param(None, "at most this many stack seconds per wall second (`--speed paced`: 1); null: "
                                     "as fast as every participant keeps up (`--speed max`)", gt=0)
    broadcast_period_s: float = param(0.05, "how often the time goes to the processes outside the lockstep "
                                            "(supervisor, API): each participant hears it only when it is due",
                                      unit="s", gt=0)


class ReplaySettings(Params):
    record: list[str] = param(doc="processes that write their inputs and outputs, step by step, for process "
                                  "replay (ares.replay)", factory=list)
    dir: str | None = param(None, "where the recordings go (default: <run dir>/replay)")


class UtmOrigin(Params):
    """The local frame's origin in UTM: x east, y north, z above the origin's altitude."""
    zone: int = param(30, "UTM zone", ge=1, le=60)
    hemisphere: Literal["N", "S"] = param("N", "hemisphere")
    easting: float = param(440000.0, "easting of the origin", unit="m")
    northing: float = param(4474000.0, "northing of the origin", unit="m")
    altitude_m: float = param(650.0, "altitude of the origin above mean sea level", unit="m")
    reach_km: float = param(100.0, "positions farther than this from the origin are refused (a wrong fix or a "
                                   "wrong configuration); nearer ones are projected in the origin's zone, even "
                                   "across a zone boundary", unit="km", gt=0)


# ---- vehicle profiles ------------------------------------------------------------------------

class SteeringActuatorParams(Params):
    dead_time_s: float = param(doc="transport delay of the steering motor", unit="s", ge=0)
    max_rate_deg_s: float = param(doc="steering-wheel speed at full effort", unit="deg/s", gt=0)
    time_constant_s: float = param(doc="motor speed lag", unit="s", ge=0)
    stiction_effort: float = param(doc="static friction: smaller efforts do not turn the column", ge=0, lt=1)


class TractionActuatorParams(Params):
    dead_time_s: float = param(doc="transport delay of the motor controller", unit="s", ge=0)
    time_constant_s: float = param(doc="controller ramp", unit="s", ge=0)
    full_effort_speed_mps: float = param(doc="synchronous speed at full effort", unit="m/s", gt=0)
    slip_stiffness_n_per_mps: float = param(doc="motor force per m/s below synchronous speed", unit="N/(m/s)", gt=0)
    max_drive_force_n: float = param(doc="current limit", unit="N", gt=0)
    max_regen_force_n: float = param(doc="regenerative braking", unit="N", ge=0)
    max_brake_force_n: float = param(doc="friction brake at full effort", unit="N", ge=0)
    parking_hold_force_n: float = param(0.0, "electromagnetic brake at standstill, throttle released", unit="N", ge=0)
    rolling_resistance: float = param(doc="rolling resistance coefficient", ge=0)
    drag_area_m2: float = param(0.0, "Cd times frontal area", unit="m^2", ge=0)


class ActuatorParams(Params):
    steering: SteeringActuatorParams
    traction: TractionActuatorParams


class PidGains(Params):
    kp: float = param(doc="proportional gain")
    ki: float = param(0.0, "integral gain")
    kd: float = param(0.0, "derivative gain")
    out_min: float = param(-1.0, "lowest effort")
    out_max: float = param(1.0, "highest effort")
    integral_limit: float | None = param(None, "bound on the integral alone (default: the output range)")
    derivative_on_measurement: bool = param(True, "derivative of the measurement, not the error (no kick)")


class DbwPidParams(Params):
    steering: PidGains
    throttle: PidGains


class LidarLayers(Params):
    count: int = param(doc="lasers in this block", ge=1)
    top_deg: float = param(doc="elevation of the block's highest laser", unit="deg")
    bottom_deg: float = param(doc="elevation of its lowest laser", unit="deg")


class LidarModel(Params):
    """A spinning LiDAR's datasheet: its lasers, azimuth resolution and range."""
    layers: list[LidarLayers] = param(doc="blocks of evenly spaced lasers, top to bottom", min_length=1)
    azimuth_step_deg: float = param(doc="angle between firings at 10 Hz", unit="deg", gt=0)
    min_range_m: float = param(doc="closer returns are discarded by the sensor", unit="m", ge=0)
    max_range_m: float = param(doc="farthest return (good reflectors)", unit="m", gt=0)
    range_sigma_m: float = param(doc="range noise", unit="m", ge=0)

    def elevations_deg(self) -> list[float]:
        """Every laser's elevation, ring 0 the lowest."""
        out: list[float] = []
        for block in self.layers:
            step = (block.top_deg - block.bottom_deg) / max(block.count - 1, 1)
            out += [block.bottom_deg + i * step for i in range(block.count)]
        return sorted(out)


# The two sensor classes of the ARES shuttle (DESIGN §3): the HDL-64E's two blocks of 32 lasers
# (+2° to −8.33° in 1/3° steps, −8.83° to −24.33° in 1/2° steps) and the VLP-16's ±15° in 2° steps.
LIDAR_MODELS: dict[str, LidarModel] = {
    "hdl64e": LidarModel(layers=[LidarLayers(count=32, top_deg=2.0, bottom_deg=-8.33),
                                 LidarLayers(count=32, top_deg=-8.83, bottom_deg=-24.33)],
                         azimuth_step_deg=0.17, min_range_m=0.9, max_range_m=120.0, range_sigma_m=0.02),
    "vlp16": LidarModel(layers=[LidarLayers(count=16, top_deg=15.0, bottom_deg=-15.0)],
                        azimuth_step_deg=0.2, min_range_m=0.5, max_range_m=100.0, range_sigma_m=0.03),
}
LIDAR_NAMES = ("roof", "front_left", "front_right")


class LidarMount(Params):
    """One LiDAR on the vehicle: its class and its extrinsics in the vehicle frame (origin at the
    rear-axle centre on the road, x forward, y left, z up); rotations roll, pitch, yaw applied
    about z, then y, then x (ZYX). Pitch positive tilts the sensor nose down."""
    model: Literal["hdl64e", "vlp16"] = param(doc="sensor class (config.LIDAR_MODELS)")
    xyz_m: tuple[float, float, float] = param(doc="position", unit="m")
    rpy_deg: tuple[float, float, float] = param((0.0, 0.0, 0.0), "roll, pitch, yaw", unit="deg")

    def datasheet(self) -> LidarModel:
        return LIDAR_MODELS[self.model]


class VehicleProfile(Params):
    """A vehicle: geometry, limits, masses, the raw actuators the simulator models and the gains
    of the drive-by-wire board's inner loops (DBW paper §4-5)."""
    name: str
    wheelbase_m: float = param(doc="wheelbase S", unit="m", gt=0)
    track_m: float = param(doc="track L", unit="m", gt=0)
    wheel_radius_m: float = param(doc="wheel radius r", unit="m", gt=0)
    length_m: float = param(doc="body length", unit="m", gt=0)
    width_m: float = param(doc="body width", unit="m", gt=0)
    height_m: float | None = param(None, "body height (maker's figure; not used by the stack)", unit="m", gt=0)
    turn_radius_m: float | None = param(None, "smallest turning radius (maker's figure)", unit="m", gt=0)
    max_climb_pct: float | None = param(None, "steepest climb (maker's figure)", unit="%", gt=0)
    top_speed_mps: float | None = param(None, "the vehicle's own top speed; max_speed_mps is the stack's limit",
                                        unit="m/s", gt=0)
    k_cg: float = param(doc="centre of gravity: 0 front axle, 1 rear axle (ARES eqs. 3-5)", ge=0, le=1)
    steering_ratio: float = param(doc="steering-wheel angle / front wheel angle", gt=0)
    max_wheel_angle_rad: float = param(doc="largest front wheel angle", unit="rad", gt=0, lt=1.5)
    max_speed_mps: float = param(doc="top speed", unit="m/s", gt=0)
    max_accel_mps2: float = param(doc="largest acceleration", unit="m/s^2", gt=0)
    max_decel_mps2: float = param(doc="largest deceleration", unit="m/s^2", gt=0)
    max_lateral_accel_mps2: float = param(doc="largest lateral acceleration", unit="m/s^2", gt=0)
    empty_mass_kg: float = param(doc="mass without passengers", unit="kg", gt=0)
    passenger_mass_kg: float = param(doc="mass of one passenger", unit="kg", ge=0)
    seats: int = param(doc="passenger seats", ge=0)
    # Lateral dynamics of the simulator's dynamic bicycle (ares/sim/vehicle.py). The centre of
    # gravity along the wheelbase is k_cg above; the figures are for the empty vehicle.
    # Without them (a profile, or a recorded run, from before they existed) the simulator drives the
    # kinematic bicycle.
    yaw_inertia_kgm2: float | None = param(None, "yaw moment of inertia I_z, empty (scaled with the load's mass)",
                                           unit="kg m^2", gt=0)
    cornering_stiffness_front_n_per_rad: float | None = param(None, "front axle cornering stiffness C_f (both "
                                                              "tyres): lateral force per rad of slip", unit="N/rad",
                                                              gt=0)
    cornering_stiffness_rear_n_per_rad: float | None = param(None, "rear axle cornering stiffness C_r (both tyres)",
                                                             unit="N/rad", gt=0)
    actuators: ActuatorParams
    dbw_pid: DbwPidParams
    ground_clearance_m: float = param(0.25, "underside of the body above the road", unit="m", ge=0)
    lidars: dict[Literal["roof", "front_left", "front_right"], LidarMount] = param(
        factory=dict, doc="the LiDARs and their extrinsics (ARES §3.4.1); `ares calibrate lidars` writes them")

    # ---- figures that follow from the above ------------------------------------------------------
    @property
    def max_curvature(self) -> float:
        """1/m: tan(largest wheel angle) / wheelbase."""
        return math.tan(self.max_wheel_angle_rad) / self.wheelbase_m

    @property
    def max_curvature_rate(self) -> float:
        """1/m/s, at least: the steering motor's wheel rate over the wheelbase (d tan δ / dt >= dδ/dt)."""
        return math.radians(self.actuators.steering.max_rate_deg_s) / self.steering_ratio / self.wheelbase_m

    def curvature_of(self, steering_wheel_deg: float) -> float:
        """1/m: the curvature a steering-wheel angle drives (kinematic: tan(wheel angle) / wheelbase)."""
        return math.tan(math.radians(steering_wheel_deg) / self.steering_ratio) / self.wheelbase_m

    @property
    def front_bumper_m(self) -> float:
        """The front bumper ahead of the rear axle: the wheelbase and half the overhangs."""
        return self.wheelbase_m + (self.length_m - self.wheelbase_m) / 2.0


# ---- tours ------------------------------------------------------------------------------------

class TourCorner(Params):
    xy: tuple[float, float]
    radius_m: float = param(doc="radius of the arc that rounds the corner", unit="m", gt=0)


class TourElevation(Params):
    s: float = param(doc="distance along the tour", unit="m", ge=0)
    z: float = param(doc="height", unit="m")


class TourStretch(Params):
    s_start: float = param(unit="m", ge=0)
    s_end: float = param(unit="m", ge=0)
    width_m: float = param(unit="m", gt=0)


class TourPoi(Params):
    name: str
    s: float = param(unit="m", ge=0)
    actions: list[Literal["STOP", "FULL_STOP", "OPENING_DOORS", "TAKEOFF_RAMP", "PICKUP_RAMP",
                          "CLOSING_DOORS", "NEXT_POI", "START_MEDIA"]] = param(factory=list)


class TourZone(Params):
    kind: Literal["rtk_loss", "intersection", "road_opening", "narrow"]
    s_start: float = param(unit="m", ge=0)
    s_end: float = param(unit="m", ge=0)


VergeKind = Literal["grass", "rock_wall", "ravine", "kerb", "open"]
VERGE_KINDS: tuple[str, ...] = ("grass", "rock_wall", "ravine", "kerb", "open")


class TourVerge(Params):
    """What lies beside the road over a stretch, on each side (the simulator's 3-D world)."""
    s_start: float = param(unit="m", ge=0)
    s_end: float = param(unit="m", ge=0)
    left: VergeKind = param(doc="grass shoulder (no step, a gentle change of slope), rock_wall, ravine (a drop, "
                                "no barrier), kerb, or open (no boundary)")
    right: VergeKind = param(doc="as left")


class TourDescription(Params):
    """A closed tour: a polygon whose corners are rounded with arcs, profiles along it."""
    name: str
    default_width_m: float = param(6.0, unit="m", gt=0)
    speed_limit_mps: float | None = param(None, "the road's speed limit: the speed profile's top speed on straights "
                                                "(null: the vehicle's maximum)", unit="m/s", gt=0)
    default_verge: VergeKind = param("kerb", "the verge where `verges` says nothing")
    verges: list[TourVerge] = param(factory=list, doc="verges stretch by stretch; intersections and road "
                                                      "openings are open whatever they say")
    corners: list[TourCorner] = param(min_length=3)
    elevation: list[TourElevation] = param(min_length=1)
    narrow: list[TourStretch] = param(factory=list)
    pois: list[TourPoi] = param(factory=list)
    zones: list[TourZone] = param(factory=list)


# ---- scenarios ----------------------------------------------------------------------------------

class ScenarioPlace(Params):
    """A place beside the route: arc length and lateral offset (left +)."""
    s: float = param(doc="distance along the route", unit="m")
    offset_m: float = param(0.0, "left (+) or right (−) of the route's centre line", unit="m")
    wait_s: float = param(0.0, "a moving obstacle stands here this long before it goes on", unit="s", ge=0)


OBSTACLE_SIZES: dict[str, tuple[float, float, float]] = {     # length, width, height (m)
    "box": (0.4, 0.4, 0.3), "crate": (0.8, 0.6, 0.6), "pedestrian": (0.5, 0.5, 1.75),
    "cart": (1.8, 1.2, 1.5), "vehicle": (4.2, 1.8, 1.5)}


class ScenarioObstacle(Params):
    """A static obstacle (one place) or a moving one (a path walked at `speed_mps`)."""
    name: str
    kind: Literal["box", "crate", "pedestrian", "cart", "vehicle"]
    size_m: tuple[float, float, float] | None = param(None, "length, width, height (default: the kind's)", unit="m")
    path: list[ScenarioPlace] = param(doc="where it stands, or the path it follows", min_length=1)
    speed_mps: float = param(0.0, "walking or driving speed along the path", unit="m/s", ge=0)
    start_t_s: float | None = param(None, "starts moving at this stack time ...", unit="s", ge=0)
    start_when_vehicle_at_s: float | None = param(None, "... or when the vehicle reaches this distance along the "
                                                        "route (its first lap)", unit="m", ge=0)

    def size(self) -> tuple[float, float, float]:
        return self.size_m or OBSTACLE_SIZES[self.kind]


class ScenarioAlongTour(Params):
    """Obstacles of several sizes placed along the tour, beside the path the shuttle drives."""
    every_m: float = param(40.0, "one obstacle every ...", unit="m", gt=0)
    kinds: list[Literal["box", "crate", "pedestrian", "cart", "vehicle"]] = param(
        factory=lambda: ["box", "crate", "pedestrian", "cart", "vehicle"], doc="in turn")
    clearance_m: float = param(1.5, "gap between the route's centre line and the obstacle's near side", unit="m", ge=0)
    skip_narrower_than_m: float = param(5.0, "no obstacle where the road is narrower", unit="m", gt=0)


class ScenarioPassengers(Params):
    """People at a point of interest: they alight, then board, one at a time, when the doors open."""
    poi: str = param(doc="the POI's name (in the tour)")
    boarding: int = param(0, "people getting on", ge=0)
    alighting: int = param(0, "people getting off", ge=0)
    on_ramp: int = param(0, "of those boarding, how many need the ramp (a wheelchair, a pram): they wait for it",
                         ge=0)
    late: int = param(0, "of those boarding, how many more step into the doorway as the doors begin to close", ge=0)

    @model_validator(mode="after")
    def _ramp_users_board(self):
        if self.on_ramp > self.boarding:
            raise ValueError(f"on_ramp ({self.on_ramp}) is more than boarding ({self.boarding})")
        return self


FAULT_FIELDS: dict[str, tuple[set[str], set[str]]] = {     # kind -> (fields it needs, fields it may have)
    "block_lidar": ({"sensor", "at_t_s"}, {"duration_s"}),
    "gnss_outage": (set(), {"at_t_s", "duration_s", "s_start_m", "s_end_m"}),
    "gnss_no_corrections": (set(), {"at_t_s", "duration_s", "s_start_m", "s_end_m"}),
    "wheel_speed_scale": ({"scale"}, {"at_t_s", "duration_s"}),
    "gyro_bias": ({"bias_deg_s"}, {"at_t_s", "duration_s"}),
    "freeze_imu": ({"at_t_s"}, {"duration_s"}),
    "kill_process": ({"process", "at_t_s"}, set()),
    "stop_process": ({"process", "at_t_s"}, set()),
    "hang_process": ({"process", "at_t_s"}, set()),
}
PROCESS_FAULTS = ("kill_process", "stop_process", "hang_process")


class ScenarioFault(Params):
    """A fault, from `at_t_s` (stack time) for `duration_s`, or over a stretch of the route
    (`s_start_m`..`s_end_m`, every lap); without either, for the whole run."""
    kind: Literal["block_lidar", "gnss_outage", "gnss_no_corrections", "wheel_speed_scale", "gyro_bias", "freeze_imu",
                  "kill_process", "stop_process", "hang_process"] = param(
        doc="block_lidar: an opaque cover over a LiDAR; gnss_outage: no fix at all; gnss_no_corrections: no RTK "
            "corrections (a float fix, as in a tour's rtk_loss zone); wheel_speed_scale: the CAN wheel speed reads "
            "(1 + scale) x the truth; gyro_bias: the IMU's yaw rate reads bias_deg_s too much; freeze_imu: the IMU "
            "repeats its last reading; kill_process: SIGKILL; stop_process: SIGTERM (it exits); hang_process: "
            "SIGSTOP (alive but its loop stands still, until the supervisor kills it)")
    process: str | None = param(None, "process faults: which process (a name of the process table)")
    sensor: Literal["roof", "front_left", "front_right"] | None = param(None, "block_lidar: which LiDAR")
    at_t_s: float | None = param(None, "stack time it begins", unit="s", ge=0)
    duration_s: float | None = param(None, "how long it lasts (for ever if not given)", unit="s", gt=0)
    s_start_m: float | None = param(None, "GNSS faults: the stretch of the route where it holds ...", unit="m", ge=0)
    s_end_m: float | None = param(None, "... and where it ends", unit="m", ge=0)
    scale: float | None = param(None, "wheel_speed_scale: 0.02 reads 2 % fast", gt=-0.5, lt=0.5)
    bias_deg_s: float | None = param(None, "gyro_bias: added to the yaw rate", unit="deg/s")

    @model_validator(mode="after")
    def _fields_of_its_kind(self):
        needs, may = FAULT_FIELDS[self.kind]
        given = {name for name in ("sensor", "at_t_s", "duration_s", "s_start_m", "s_end_m", "scale", "bias_deg_s",
                                   "process")
                 if getattr(self, name) is not None}
        if needs - given:
            raise ValueError(f"a {self.kind} fault needs {', '.join(sorted(needs - given))}")
        if given - needs - may:
            raise ValueError(f"a {self.kind} fault has no {', '.join(sorted(given - needs - may))}")
        if (self.s_start_m is None) != (self.s_end_m is None):
            raise ValueError("a stretch needs both s_start_m and s_end_m")
        if self.s_start_m is not None and (self.at_t_s is not None or self.s_end_m <= self.s_start_m):
            raise ValueError("a fault holds over a stretch (s_start_m < s_end_m) or from a time, not both")
        return self

    def active(self, t: float, s: float | None = None) -> bool:
        """Whether it holds at stack time t with the vehicle at s along the route."""
        if self.s_start_m is not None:
            return s is not None and self.s_start_m <= s <= self.s_end_m
        begins = self.at_t_s or 0.0
        return t >= begins and (self.duration_s is None or t < begins + self.duration_s)


class ScenarioOperatorAction(Params):
    """An operator's action through the vehicle's services, at a stack time."""
    at_t_s: float = param(doc="stack time", unit="s", ge=0)
    action: Literal["rearm", "pause", "resume", "cancel"]


class Scenario(Params):
    """What happens around the simulated shuttle: obstacles and their motion, faults and their times."""
    name: str
    description: str = ""
    obstacles: list[ScenarioObstacle] = param(factory=list)
    along_tour: ScenarioAlongTour | None = param(None, "also place obstacles along the tour")
    faults: list[ScenarioFault] = param(factory=list)
    passengers: list[ScenarioPassengers] = param(factory=list, doc="people waiting at the POIs")
    operator: list[ScenarioOperatorAction] = param(factory=list, doc="what the operator does, and when")
    start_s_m: float | None = param(None, "where along the route the shuttle stands at start (default: sim.start_s_m)",
                                    unit="m", ge=0)
    mission: Literal["tour", "drive"] | None = param(None, "the goal the run starts: every POI of the tour, or round "
                                                           "without stopping (default: the configuration's)")

    @model_validator(mode="after")
    def _one_visit_per_poi(self):
        pois = [p.poi for p in self.passengers]
        if len(set(pois)) != len(pois):
            raise ValueError(f"passengers: one entry per POI ({pois})")
        return self


def load_scenario(name: str) -> Scenario:
    path = named_file("scenarios", name)
    return validated(Scenario, load_yaml(path), str(path))


# ---- the sections every process reads --------------------------------------------------------

class CoreConfig(Params):
    vehicle_id: str = param("shuttle01", "this shuttle's id in every bus key (ares/<vehicle_id>/...); one per "
                                         "vehicle so that a fleet shares one Zenoh network", pattern=VEHICLE_ID_PATTERN)
    vehicle: str = param("ares_shuttle", "vehicle profile: a name in ares/config/vehicles/ or a YAML file")
    tour: str = param("default", "built-in tour: a name in ares/config/tours/ or a YAML file")
    route_file: str | None = param(None, "an open route (CSV of x,y[,z] metres) driven instead of the tour")
    scenario: str | None = param(None, "simulated obstacles and faults: a name in ares/config/scenarios/ or a YAML file")
    simulate: bool = param(True, "run the simulated shuttle (the `sim` process) with the stack")
    lidars: bool = param(True, "run the LiDARs and LiDAR perception (off: the stack drives on GNSS and odometry "
                               "alone, as the tests that are not about perception do, to save time)")
    origin_utm: UtmOrigin = param(doc="origin of the local frame", factory=UtmOrigin)
    bus: BusSettings = param(doc="the Zenoh bus", factory=BusSettings)
    heartbeat: HeartbeatSettings = param(doc="process heartbeats", factory=HeartbeatSettings)
    lockstep: LockstepSettings = param(doc="the simulator-driven clock of `--speed max`", factory=LockstepSettings)
    replay: ReplaySettings = param(doc="process replay recordings", factory=ReplaySettings)
    vehicle_profile: VehicleProfile | None = param(None, "the profile named by `vehicle`, resolved by `ares run`; "
                                                         "its fields may be overridden here")


CORE_SECTIONS = tuple(CoreConfig.model_fields)


# ---- files ------------------------------------------------------------------------------------

def load_yaml(path: str | Path) -> dict:
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise ConfigError(f"no such configuration file: {path}") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read: {exc.strerror}") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML: {exc}") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping of sections at the top level, got {type(data).__name__}")
    return data


def packaged_file(kind: str, name: str) -> Path:
    """Where a packaged file of config/<kind>/ by that name is (it may not exist)."""
    return CONFIG_DIR / kind / f"{name}.yaml"


def named_file(kind: str, name: str) -> Path:
    """A packaged file of config/<kind>/ by name, or a YAML file given by path."""
    candidate = Path(name)
    if candidate.suffix in (".yaml", ".yml") and candidate.exists():
        return candidate
    path = packaged_file(kind, name)
    if not path.exists():
        known = sorted(p.stem for p in (CONFIG_DIR / kind).glob("*.yaml"))
        raise ConfigError(f"unknown {kind[:-1]} {name!r}; known: {', '.join(known)} (or a path to a .yaml file)")
    return path


def load_vehicle(name: str, overrides: Mapping | None = None) -> VehicleProfile:
    path = named_file("vehicles", name)
    data = deep_merge(load_yaml(path), dict(overrides or {}))
    return validated(VehicleProfile, data, str(path))


def load_tour(name: str) -> TourDescription:
    path = named_file("tours", name)
    return validated(TourDescription, load_yaml(path), str(path))


# ---- merging and validation -------------------------------------------------------------------

def deep_merge(base: Mapping, override: Mapping) -> dict:
    out = copy.deepcopy(dict(base))
    for key, value in override.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping):
            out[key] = deep_merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def validated(model: type[BaseModel], data: Mapping, source: str):
    """`model` validated from `data`; a ConfigError naming `source`, the key and what is allowed."""
    try:
        return model.model_validate(dict(data))
    except ValidationError as exc:
        raise ConfigError(describe_errors(model, exc, source)) from None


def describe_errors(model: type[BaseModel], exc: ValidationError, source: str, prefix: str = "") -> str:
    return _sentence(source, [error_line(model, err, prefix) for err in exc.errors(include_url=False)])


def _sentence(source: str, lines: list[str]) -> str:
    return f"{source}: " + ("; ".join(lines) if len(lines) == 1 else "\n  " + "\n  ".join(lines))


def error_line(model: type[BaseModel], err: Mapping, prefix: str = "") -> str:
    """One validation error as `key: what is wrong; what is allowed` (prefix: where model sits)."""
    loc = [str(p) for p in err["loc"]]
    key = prefix + ".".join(loc) or "<top level>"
    if err["type"] == "extra_forbidden":
        allowed = _fields_at(model, loc[:-1])
        hint = difflib.get_close_matches(loc[-1], allowed, n=1)
        maybe = f" (did you mean {hint[0]!r}?)" if hint else ""
        return f"{key}: unknown key{maybe}; allowed here: {', '.join(allowed) or '(none)'}"
    if err["type"] == "missing":
        return f"{key}: required, missing"
    return f"{key}: {err['msg']} (got {err.get('input')!r:.80})"


def _fields_at(model: type[BaseModel], loc: list[str]) -> list[str]:
    """Field names of the (nested) model at loc, or [] where it is not a model. Parts that name
    no field (list indices, mapping keys, union tags) are stepped over: the model stays the same."""
    current: Any = model
    for part in loc:
        fields = getattr(current, "model_fields", None)
        if not fields:
            return []
        if part in fields:
            current = _model_in(fields[part].annotation)
    return sorted(getattr(current, "model_fields", {}) or {})


def _model_in(annotation: Any) -> Any:
    """The BaseModel class inside an annotation such as `Foo | None`, if any."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    for arg in getattr(annotation, "__args__", ()) or ():
        found = _model_in(arg)
        if found is not None:
            return found
    return None


COMMAND_LINE = "the command line"


def build(model: type[CoreConfig], files: tuple[str | Path, ...] = (), overrides: Mapping | None = None) -> dict:
    """The run configuration as a JSON-ready dict: the model's defaults, each file, then `overrides`
    (the command line's choices), each layer validated on its own so that an error names it; the
    vehicle profile resolved into `vehicle_profile`, with any of its fields overridden there."""
    layers = [(str(path), load_yaml(path)) for path in files]
    if overrides:
        layers.append((COMMAND_LINE, dict(overrides)))
    data: dict = {}
    profile_overrides: dict = {}
    set_by: dict[str, str] = {}             # profile field -> the layer that last overrode it
    for source, content in layers:
        content = _empty_sections_as_mappings(model, content)
        validated(model, _without_profile(content), source)
        data = deep_merge(data, _without_profile(content))
        changes = _profile_overrides(content, source)
        profile_overrides = deep_merge(profile_overrides, changes)
        set_by.update(dict.fromkeys(changes, source))
    cfg = validated(model, data, " + ".join(source for source, _ in layers) or "the defaults")
    out = cfg.model_dump(mode="json")
    out["vehicle_profile"] = _profile(cfg.vehicle, profile_overrides, set_by).model_dump(mode="json")
    return out


def _profile(vehicle: str, overrides: dict, set_by: dict[str, str]) -> VehicleProfile:
    """The named profile with its overrides; an error names the layer that set the field."""
    path = named_file("vehicles", vehicle)
    try:
        return VehicleProfile.model_validate(deep_merge(load_yaml(path), overrides))
    except ValidationError as exc:
        by_source: dict[str, list[str]] = {}
        for err in exc.errors(include_url=False):
            overridden = str(err["loc"][0]) in set_by if err["loc"] else False
            source = set_by[str(err["loc"][0])] if overridden else str(path)
            prefix = "vehicle_profile." if overridden else ""
            by_source.setdefault(source, []).append(error_line(VehicleProfile, err, prefix))
        raise ConfigError("\n".join(_sentence(source, lines) for source, lines in by_source.items())) from None


def _profile_overrides(content: Mapping, source: str) -> dict:
    overrides = content.get("vehicle_profile")
    if overrides is None:
        return {}
    if not isinstance(overrides, Mapping):
        raise ConfigError(f"{source}: vehicle_profile: expected a mapping of profile fields to override, "
                          f"got {type(overrides).__name__}")
    return dict(overrides)


def _empty_sections_as_mappings(model: type[BaseModel], content: Mapping) -> dict:
    """`section:` with nothing under it (YAML null) means the section's defaults."""
    def is_section(name: str) -> bool:
        field = model.model_fields.get(name)
        return field is not None and isinstance(field.annotation, type) and issubclass(field.annotation, BaseModel)
    return {k: ({} if v is None and is_section(k) else v) for k, v in content.items()}


def _without_profile(data: Mapping) -> dict:
    """A configuration without its vehicle_profile overrides: those are single fields, validated
    once merged into the named profile."""
    return {k: v for k, v in data.items() if k != "vehicle_profile"}


def core_defaults() -> dict:
    """Only the core sections, for a process started without a run configuration."""
    return build(CoreConfig)


def write_run_config(cfg: Mapping, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(cfg, indent=1))
    return path


def current() -> dict:
    """The run's configuration in a child process (ARES_RUN_CONFIG), else the core defaults."""
    path = os.environ.get(RUN_CONFIG_ENV)
    if path:
        try:
            return json.loads(Path(path).read_text())
        except (OSError, ValueError) as exc:
            raise ConfigError(f"{RUN_CONFIG_ENV}={path}: cannot read the run configuration: {exc}") from None
    return core_defaults()


def core(cfg: Mapping) -> CoreConfig:
    """The core sections of a run configuration, typed (the named vehicle's profile if it has none)."""
    typed = validated(CoreConfig, {k: cfg[k] for k in CORE_SECTIONS if k in cfg}, "the run configuration")
    if typed.vehicle_profile is None:
        typed = typed.model_copy(update={"vehicle_profile": load_vehicle(typed.vehicle)})
    return typed


def section(cfg: Mapping, name: str, model: type[Params]) -> Params:
    """One section of a run configuration, typed (its defaults where the section is absent)."""
    return validated(model, cfg.get(name) or {}, f"the run configuration, section {name!r}")
