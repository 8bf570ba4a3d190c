"""Message schemas, defined once for the bus, the black box and the REST API.

Which topic carries which schema, and which service takes and answers which, is the table in
ares.core.topics. Small messages are JSON (`Msg`), bulk arrays travel as a typed header plus raw
arrays (`BulkMsg`); both are validated on receipt (ares.core.schema). Every message carries `t`, the
stack time (s) at which it was produced.
"""

from __future__ import annotations

from datetime import datetime
from enum import Enum
from typing import Annotated, ClassVar, Literal, Self

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from ares.core.config import VEHICLE_ID_PATTERN
from ares.core.schema import Array, BulkMsg, Msg
from ares.core.signed_command import CommandSignature

__all__ = ["Msg", "BulkMsg"]  # re-exported: the base classes live in ares.core.schema


# ---- process health ----------------------------------------------------------------------


class Heartbeat(Msg):
    process: str
    seq: int = Field(ge=0)
    pid: int
    wall: float  # wall-clock seconds (time.time()) when sent
    loop_overruns: int = 0  # loop periods that took longer than the period
    step_ms: float = 0.0  # duration of the last step
    # each declared output with an expected rate: [rate_hz, stack time of its last message or
    # null]; the supervisor notices a process that is alive but silent on an output
    outputs: dict[str, tuple[Annotated[float, Field(gt=0)], float | None]] = Field(default_factory=dict)


class ProcessState(str, Enum):
    STARTING = "starting"
    RUNNING = "running"
    RESTARTING = "restarting"  # dead or hung, waiting out its backoff
    STOPPED = "stopped"


class ProcessStatus(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    name: str
    state: ProcessState
    pid: int | None = None
    restarts: int = 0
    last_exit_code: int | None = None
    last_failure: str = ""  # why it was last restarted: "exited 1", "liveliness lost", ...
    safety_relevant: bool = False
    heartbeat_age_s: float | None = None
    silent: list[str] = Field(default_factory=list)  # declared outputs it has stopped publishing


class SupervisorState(Msg):
    processes: list[ProcessStatus]


class EventLevel(str, Enum):
    INFO = "info"
    WARNING = "warning"
    FAULT = "fault"


class Event(Msg):
    source: str  # process that saw it
    kind: str  # "mode_change", "process_restart", "watchdog", ...
    level: EventLevel = EventLevel.INFO
    message: str
    data: dict[str, str | float | int | bool | None] = Field(default_factory=dict)


class SnapshotRequest(Msg):
    """Someone asks for an incident snapshot now (`ares snapshot`): the recorder saves its ring and
    the seconds after, and says so in a `snapshot` event carrying `request_id`."""

    requested_by: str
    reason: str = ""
    request_id: str = ""


# ---- simulator: ground truth, sensors, control panel --------------------------------------


class VehicleTruth(Msg):
    """What really happened, for evaluation only: no vehicle-side process may steer from it
    once localization exists."""

    x: float
    y: float
    z: float
    yaw: float
    pitch: float = 0.0
    v: float
    yaw_rate: float = 0.0
    accel: float = 0.0
    steering_wheel_deg: float
    wheel_angle_rad: float
    s: float  # progress along the route (m, wraps on a closed tour)
    odometer_m: float
    lap: int = 0
    rtk_available: bool = True
    passengers: int = 0
    board_failsafe: bool = False  # the drive-by-wire board brakes: the bridge has gone quiet


class ObstacleBox(BaseModel):
    """An obstacle's footprint and height in the local frame (the world's truth)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    name: str
    kind: str
    x: float
    y: float
    yaw: float = 0.0
    length_m: float = Field(gt=0)
    width_m: float = Field(gt=0)
    height_m: float = Field(gt=0)
    moving: bool = False


class WorldTruth(Msg):
    """The simulated world's obstacles as they are now, for evaluation only."""

    obstacles: list[ObstacleBox] = Field(default_factory=list)
    blocked_lidars: list[str] = Field(default_factory=list)


class LidarFault(Msg):
    """Cover (or uncover) a simulated LiDAR: fault injection."""

    sensor: Literal["roof", "front_left", "front_right"]
    blocked: bool = True


class SensorFault(Msg):
    """Begin a fault of the simulated GNSS or IMU now, for `duration_s` of stack time: fault
    injection at run time (a scenario's faults of the same kinds are timed in its file)."""

    kind: Literal["gnss_outage", "gnss_no_corrections", "freeze_imu"]
    duration_s: float = Field(gt=0)


class GnssSentences(Msg):
    """Raw NMEA sentences from the receiver, as the serial port gives them."""

    sentences: list[str]


class Imu(Msg):
    yaw: float  # magnetometer yaw (rad), with its calibration offset
    roll: float
    pitch: float
    gyro_x: float
    gyro_y: float
    gyro_z: float
    accel_x: float
    accel_y: float
    accel_z: float


class CanFrame(Msg):
    wheel_speed_rad_s: float
    speed_mps: float
    steering_wheel_deg: float
    throttle_pedal: float = Field(ge=0.0, le=1.0)
    brake_pedal: float = Field(ge=0.0, le=1.0)
    steering_torque: bool  # the driver is holding/turning the steering wheel


class DriverStatus(Msg):
    """A device driver's counts since it started, once a second (drivers/status): what came in on
    the wire, what went out on the bus, and what was refused and why."""

    driver: str  # its process
    device: str  # gnss, lidar/roof, can, ...
    connected: bool  # the device is open and has spoken within its silence timeout
    received: int = Field(ge=0)  # packets, frames or lines read from the wire
    published: int = Field(ge=0)  # messages put on the bus
    lost: int = Field(0, ge=0)  # packets or frames known to be missing (sequence, azimuth or counter gaps)
    malformed: dict[str, int] = Field(default_factory=dict)  # refused, by cause
    skipped: dict[str, int] = Field(default_factory=dict)  # read and set aside on purpose (UBX frames, ...)
    latency_p50_ms: float | None = None  # wire to bus (wall): from the kernel's or the read's time to the put
    latency_p99_ms: float | None = None
    detail: str = ""


class PanelInput(str, Enum):
    BUTTON = "BUTTON"  # Auto/Manual button on the control panel
    THROTTLE_PEDAL = "THROTTLE_PEDAL"
    BRAKE_PEDAL = "BRAKE_PEDAL"
    STEERING_WHEEL = "STEERING_WHEEL"


class PanelEvent(Msg):
    """A discrete driver action seen by the vehicle's hardware."""

    input: PanelInput
    value: float = 1.0


# ---- localization, odometry and path ------------------------------------------------------


class GnssFix(Msg):
    """One validated GNSS fix (from GGA, with GST's error statistics when the receiver sends
    them), projected to UTM and to the stack's local frame (UTM minus the configured origin)."""

    x: float  # local frame, metres east of the origin
    y: float  # metres north
    z: float | None  # metres above the origin's altitude; None: the receiver sent no altitude
    lat: float
    lon: float
    easting: float
    northing: float
    zone: int
    hemisphere: Literal["N", "S"]
    quality: int  # GGA fix quality: 1 GPS, 2 DGPS, 4 RTK fixed, 5 RTK float, ...
    rtk: bool  # RTK corrections in use (quality 4)
    satellites: int | None  # None: not sent
    hdop: float | None
    var_x: float  # position variances, m^2
    var_y: float
    var_z: float | None


# GGA fix quality -> its name, for people
FIX_QUALITY_NAMES = {0: "no fix", 1: "single", 2: "DGPS", 4: "RTK fixed", 5: "RTK float", 6: "dead reckoning"}


class CorrectionsStatus(Msg):
    """Where the receiver's RTK corrections stand, once a second (gnss/corrections): their link (an
    NTRIP caster over 4G, or the simulator's model of one) and how old the newest is."""

    STALE_S: ClassVar[float] = 3.0  # it comes once a second: older than this, its source is not heard

    source: str  # "ntrip HOST:PORT/MOUNT", "simulated"
    link: Literal["streaming", "connecting", "down", "unauthorized", "no mount point", "none"]
    age_s: float | None  # stack seconds since the newest whole frame reached the receiver; None: none yet
    frames: int = Field(ge=0)  # whole, checked RTCM frames forwarded
    by_type: dict[str, int] = Field(default_factory=dict)  # message number -> frames
    outages: int = Field(0, ge=0)  # streams that were flowing and stopped
    station_id: int | None = None  # the reference station the corrections come from
    detail: str = ""  # the last failure, or what the link is doing

    def stale(self, now: float) -> bool:
        return now - self.t > self.STALE_S

    def outage(self, fresh_s: float = 5.0) -> str | None:
        """What keeps the corrections from the receiver, in a few words ("link down (no 4G here),
        the newest 23 s old"); None while they stream and the newest is under `fresh_s` old."""
        age = "none received yet" if self.age_s is None else f"the newest {self.age_s:.0f} s old"
        if self.link != "streaming":
            why = f" ({self.detail})" if self.detail else ""
            return f"link {self.link}{why}, {age}"
        if self.age_s is None or self.age_s > fresh_s:
            return f"streaming but {age}"
        return None


class RtcmData(BulkMsg):
    """Whole, CRC-checked RTCM 3 frames for the receiver's corrections port (gnss/rtcm)."""

    frames: int = Field(ge=1)
    data: Annotated[np.ndarray, Array("u1", doc="the frames' bytes, back to back")]


class Pose(Msg):
    """The fused pose estimate (UKF) of the rear-axle centre, with its covariance."""

    x: float
    y: float
    z: float
    yaw: float
    v: float
    yaw_rate: float
    cov_xx: float
    cov_xy: float
    cov_yy: float
    var_yaw: float
    var_v: float
    position_std_m: float  # sqrt of the largest eigenvalue of the x-y covariance
    rtk: bool  # the last GNSS fix used had RTK corrections
    gnss_age_s: float | None  # stack seconds since the last GNSS fix was fused
    var_z: float | None = None  # of z, m²; None: not given (a recording made before it was)


class OdometryScore(Msg):
    """How much the pose estimate deserves trust: 1 - a / (1 + exp(-b (cov - c))), ARES eq. 6."""

    score: float = Field(ge=0.0, le=1.0)
    covariance: float  # the input: position variance, m^2
    pose_age_s: float
    cause: str | None = None  # why the covariance is what it is, when it is not RTK: "corrections 23 s old (link down)"


class PathMatch(Msg):
    """Where the vehicle is on its route, and the path ahead of it for the controllers."""

    index: int
    s: float
    lap: int
    xte: float  # signed cross-track error, m (positive: vehicle left of path)
    heading_error: float  # vehicle yaw minus path yaw, rad
    zones: list[str]  # zones the vehicle is in: rtk_loss, intersection, road_opening, narrow
    force_odometry: bool  # intersection or road opening: the path manager forces odometry control
    distance_to_end_m: float | None  # open routes only
    # the road's narrowest width from the match over the path ahead (None: recorded before it was sent)
    road_width_ahead_m: float | None = None
    ahead_x: list[float]  # poses ahead of the match, every ~0.5 m
    ahead_y: list[float]
    ahead_yaw: list[float]
    ahead_curvature: list[float]
    ahead_speed: list[float]  # speed limit from the path's curvature profile, m/s
    ahead_s: list[float]


# ---- speed manager ------------------------------------------------------------------------

SectionKind = Literal["cruise", "deceleration", "curve", "acceleration"]


class SpeedSection(BaseModel):
    """One single-speed section of the route's speed profile (ARES Figure 17)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    index: int = Field(ge=0)  # numbered from 0 along s
    s_start: float  # m
    s_end: float  # m: the next section's s_start
    speed: float = Field(ge=0.0)  # m/s: never above the profile over the section
    kind: SectionKind


class SpeedSections(Msg):
    """The whole route's sections: they cover [0, length] contiguously."""

    route: str
    length_m: float
    closed: bool
    sections: list[SpeedSection]


class SpeedLimits(Msg):
    """The speed limit where the vehicle is, and the one coming next."""

    s: float  # the path match's s, m
    section: int  # the section the vehicle is in
    kind: SectionKind
    limit_mps: float = Field(ge=0.0)
    next_section: int | None  # None past the last section of an open route
    next_limit_mps: float | None
    distance_to_next_m: float | None  # from s to the next section's start


# ---- control ------------------------------------------------------------------------------


class Setpoint(Msg):
    """Navigation's demand to the drive-by-wire bridge (DBW paper §4): linear speed, curvature."""

    v: float
    kappa: float
    source: str


class MovementCommand(Msg):
    """The one command the drive-by-wire bridge accepts: the movement manager's (ARES §3.7)."""

    v: float = Field(ge=0.0)
    kappa: float
    emergency: bool = False  # brake fully and hold: a latched level-1 stop
    source: str  # the controller whose command it carries, or "stop"


class MovementStatus(Msg):
    """The movement gate's state: what limits the shuttle now, and why."""

    level: int | None  # the awareness level seen (0 nominal, 1 critical, 2 low; None: missing)
    latched: bool  # an emergency stop waits for a re-arm
    latch_cause: str = ""
    stopping: bool  # a controlled stop (level 2, or an input missing)
    limit_mps: float | None  # the lowest active limit (None: none)
    limited_by: str  # the manager it comes from, "stop", "emergency" or ""
    limits: dict[str, float | None] = Field(default_factory=dict)  # each manager's limit (None: missing; absent: none)
    v: float
    kappa: float
    reason: str


class ObstacleState(Msg):
    """The obstacle manager's verdict (ARES §3.5.3): the search area and what is in it."""

    score: float = Field(ge=0.0, le=1.0)  # the nearest obstacle's distance / the area's length (1: none)
    band: Literal["clear", "ready", "slow", "stop", "unknown"]
    nearest_m: float | None  # along the predicted arc from the front bumper
    limit_mps: float = Field(ge=0.0)
    length_m: float
    cells: int  # occupied cells inside the area
    area_x: list[float]  # the area's outline, vehicle frame (x ahead of the rear axle, y left)
    area_y: list[float]
    reason: str = ""


class AwarenessState(Msg):
    """Self-awareness (ARES §3.7): the level and everything that holds it there."""

    level: int = Field(ge=0, le=2)  # 0 nominal, 1 critical (emergency stop), 2 low (stop, resume when cleared)
    causes: list[str] = Field(default_factory=list)  # "lidar roof: 0.0 Hz (blocked?)", "process mpc: dead", ...
    sensors: dict[str, str] = Field(default_factory=dict)  # sensor -> ok, or what is wrong
    processes: dict[str, str] = Field(default_factory=dict)  # whitelisted process -> ok, or what is wrong


class ControlCandidate(Msg):
    """One controller's proposal (ARES §3.6: every controller computes all the time); the control
    manager decides whose reaches the drive-by-wire bridge."""

    controller: str  # mpc, rrc, pure_pursuit
    v: float
    kappa: float
    fresh: bool = True  # False: the MPC reused its previous solution (a late or failed solve)
    handover: bool = False  # the controller asks the control manager for its fallback
    stop_only: bool = False  # only to steer a controlled stop by (the RRC's road remembered, v = 0)
    solve_ms: float | None = None
    cross_track_m: float | None = None  # the error the controller sees (its own input), + vehicle left
    heading_error_rad: float | None = None
    note: str = ""  # why (a solver status, "creeping: heading uncertain", ...)


class PredictedTrajectory(Msg):
    """Where a controller expects the vehicle to go (the MPC's horizon), in the local frame."""

    controller: str
    x: list[float]
    y: list[float]
    step_s: float


class ControllerStatus(Msg):
    """The control manager's choice: who drives, why, and the errors along the route."""

    controller: str  # the candidate forwarded: mpc, rrc, pure_pursuit, creep (the odometry controller's,
    # at walking pace), or stop
    mode: str  # odometry, rrc, stop, creep (managers/control.py)
    reason: str
    s: float | None  # the path match (None while it is stale)
    xte: float | None
    heading_error: float | None
    target_speed: float
    odometry_score: float | None = None
    road_confidence: float | None = None
    finished: bool = False  # an open route's end has been reached


class ActuatorCommand(Msg):
    """Bridge -> vehicle hardware: efforts of the steering motor and traction/brake, in [-1, 1]."""

    engaged: bool  # False: the human drives (Manual)
    steer_effort: float = Field(ge=-1.0, le=1.0)
    drive_effort: float = Field(ge=-1.0, le=1.0)


class DbwReference(Msg):
    steering_wheel_deg: float
    wheel_speed_deg_s: float
    v: float
    kappa: float


class DbwMeasure(Msg):
    steering_wheel_deg: float
    wheel_speed_deg_s: float
    v: float
    kappa: float


class DriveMode(str, Enum):
    MANUAL = "MANUAL"
    READY = "READY"
    AUTOMATIC = "AUTOMATIC"


class CarState(Msg):
    mode: DriveMode
    engaged: bool
    watchdog_tripped: bool
    setpoint_age_s: float | None
    v_command: float
    kappa_command: float
    speed_mps: float
    steering_wheel_deg: float
    reason: str = ""
    emergency: bool = False  # braking fully for the movement manager's latched emergency stop


# ---- mission and the body (doors, ramp) ------------------------------------------------------

DoorState = Literal["closed", "opening", "open", "closing"]
RampState = Literal["stowed", "deploying", "deployed", "stowing"]


class BodyState(Msg):
    """The body's end-position sensors: doors and ramp, and whether anyone is in the entrance."""

    doors: DoorState
    ramp: RampState
    entrance_clear: bool  # nobody in the doorway or on the ramp
    media: bool = False  # the on-board media are playing
    passengers: int = Field(0, ge=0)


class BodyCommand(Msg):
    """The mission manager's demand to the body's actuators (None: leave it as it is)."""

    doors: Literal["open", "close"] | None = None
    ramp: Literal["deploy", "stow"] | None = None
    media: bool = False  # start the media


class PoiProgress(BaseModel):
    """One point of interest of a goal, and its actions done so far."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    name: str
    done: list[str] = Field(default_factory=list)


class MissionStatus(Msg):
    """The mission's feedback (ARES §3.3): state, the POI driven to, how far, when."""

    goal_id: int  # 0: no goal yet
    state: Literal["IDLE", "DRIVING", "AT_POI", "PAUSED", "SUCCEEDED", "CANCELED"]
    kind: Literal["none", "tour", "drive"]  # a tour stops at its POIs; a drive goes round without stopping
    poi: str | None  # the POI driven to, or the one whose actions run
    action: str | None  # the action running (AT_POI)
    distance_m: float | None  # to the POI's stop point
    eta_s: float | None  # expected arrival, stack time
    limit_mps: float | None = Field(ge=0.0)  # the mission's speed limit, which the movement gate applies (None: none)
    ready_to_move: bool  # doors closed and ramp stowed
    pois: list[PoiProgress] = Field(default_factory=list)
    result: str = ""  # why the last goal ended


class MissionGoal(Msg):
    """A goal: the POIs to serve in order (their names), every POI of the route ahead (`pois`
    None), or no POI at all (`drive`: go round without stopping). A new goal pre-empts one that runs."""

    operator: str = Field(min_length=1, max_length=64)
    pois: list[str] | None = None
    drive: bool = False
    repeat: bool = False  # a closed route's tour: round again after the last POI, until canceled
    signature: CommandSignature | None = None  # who commanded, signed (ares/core/signed_command.py)

    @model_validator(mode="after")
    def _one_kind(self) -> Self:
        if self.drive and self.pois:
            raise ValueError("a drive goal has no POIs")
        return self


class MissionRequest(Msg):
    """Pause, resume or cancel the mission (the operator's name goes to the black box)."""

    operator: str = Field(min_length=1, max_length=64)
    signature: CommandSignature | None = None  # who commanded, signed (ares/core/signed_command.py)


class BodyRequest(Msg):
    """An operator's demand to the doors or the ramp (the mission manager decides)."""

    operator: str = Field(min_length=1, max_length=64)
    doors: Literal["open", "close"] | None = None
    ramp: Literal["deploy", "stow"] | None = None
    signature: CommandSignature | None = None  # who commanded, signed (ares/core/signed_command.py)


class MissionReply(Msg):
    accepted: bool
    reason: str
    goal_id: int = 0
    state: str = ""


# ---- black box ----------------------------------------------------------------------------


class Position(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    x: float  # local frame, m
    y: float
    z: float
    easting: float  # UTM
    northing: float
    zone: int
    hemisphere: Literal["N", "S"]
    lat: float
    lon: float


class SensorHealth(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    rate_hz: float
    ok: bool


class ProcessHealth(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    state: ProcessState
    restarts: int = 0


class CorrectionsRecord(BaseModel):
    """The RTK corrections in a second of the black box: their link and age, and the fix they gave."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    link: str | None = None  # streaming, connecting, down, ...; None: no corrections' state
    age_s: float | None = None  # of the newest correction the receiver had
    fix_quality: int | None = None  # the receiver's GGA quality: 4 RTK fixed, 5 float, 2 DGPS, 1 single


class CommandRecord(BaseModel):
    """What was asked of the vehicle in a second of the black box, beside what it did (speed_mps,
    steering_wheel_deg): the speed aimed at, the controller's output, the command executed."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    target_speed_mps: float | None = None  # the speed profile's, as the control manager aims at it
    controller: str | None = None  # whose output the control manager forwarded (mpc, rrc, ..., stop)
    controller_speed_mps: float | None = None  # that output (control/setpoint): before the movement gate
    controller_curvature: float | None = None  # 1/m, + left
    commanded_speed_mps: float | None = None  # the movement manager's command as the bridge executes it
    commanded_curvature: float | None = None  # 1/m, + left
    emergency: bool | None = None  # the bridge brakes fully for a latched emergency stop


class VehicleRecord(BaseModel):
    """One second of the vehicle's state, as the black box keeps it (ARES §3.8)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    vehicle_id: str = Field(pattern=VEHICLE_ID_PATTERN)  # one key segment: the fleet files it under it
    time: datetime  # UTC, the whole second of vehicle time this record stands for
    t: float  # stack seconds of that second
    position: Position | None = None
    speed_mps: float | None = None
    steering_wheel_deg: float | None = None
    mode: DriveMode | None = None
    scores: dict[str, float] = Field(default_factory=dict)  # manager -> score, as they appear
    controller: str | None = None  # the active controller
    sensors: dict[str, SensorHealth] = Field(default_factory=dict)  # gnss, imu, can, ...
    processes: dict[str, ProcessHealth] = Field(default_factory=dict)
    awareness_level: int | None = None  # 0 nominal, 1 critical, 2 low (self-awareness)
    mission_state: str | None = None  # the mission's state, or the POI action running
    corrections: CorrectionsRecord | None = None  # the RTK corrections' link and age, and the fix type
    command: CommandRecord | None = None  # the speed aimed at, the controller's output, the command executed
    events: int = 0  # events recorded during this second (kept in full apart)
    # the recording run (one per recorder start): with the time, the record's key in the store, so
    # that a clock set back between two runs adds the second run's record beside the first's;
    # None: a record stored before runs were told apart, or not from a recorder
    run: str | None = None


class StoredEvent(BaseModel):
    """An event as the black box keeps it: the bus Event plus its vehicle and absolute time."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    vehicle_id: str
    time: datetime  # UTC vehicle time, sub-second
    t: float
    source: str
    kind: str
    level: EventLevel
    message: str
    data: dict[str, str | float | int | bool | None] = Field(default_factory=dict)


class BlackboxRecord(Msg):
    """A second of the black box as the recorder built it, published for the fleet's store."""

    record: VehicleRecord


class BlackboxStatus(Msg):
    """The black box's own health, as its writer counts it (blackbox/register/recorder.py)."""

    store_up: bool  # the last write reached the store and nothing waits before it
    written: int = Field(ge=0)  # records the store confirmed holding
    events_written: int = Field(ge=0)
    dropped: int = Field(ge=0)  # records lost: neither store nor spool took them and memory was full
    events_dropped: int = Field(ge=0)
    lost: int = Field(ge=0)  # records and events the writer's queue had no room for
    store_faults: int = Field(ge=0)  # failed store calls and spool writes
    spooled: int = Field(ge=0)  # waiting on disk
    in_memory: int = Field(ge=0)  # waiting in memory (the spool failed too)
    last_error: str = ""


# ---- services -----------------------------------------------------------------------------


class Empty(Msg):
    pass


class ModeReply(Msg):
    accepted: bool
    mode: DriveMode
    reason: str = ""


class DriverCommand(Msg):
    """Inject a driver action into the simulated vehicle."""

    action: Literal["BUTTON", "THROTTLE", "BRAKE", "STEER", "RELEASE"]
    value: float = 0.0  # pedal position 0..1, or steering-wheel angle (deg) for STEER
    duration_s: float = Field(default=1.0, ge=0.0, le=600.0)


class RearmRequest(Msg):
    """A person re-arms after an emergency stop (the REST API checks the operator's credentials)."""

    operator: str = Field(min_length=1, max_length=64)
    signature: CommandSignature | None = None  # who commanded, signed (ares/core/signed_command.py)


class RearmReply(Msg):
    accepted: bool
    reason: str


class Ack(Msg):
    ok: bool
    detail: str = ""


class ServiceErrorReply(Msg):
    error: str
    detail: str = ""


# ---- the simulator-driven clock (`--speed max`, ares.core.lockstep) ---------------------------------


class ClockTick(Msg):
    """The stack time, from the simulator: it advances only when every participant is done."""


class ClockDone(Msg):
    """A participant finished its work up to `t`; its next step is due at `next_due`."""

    process: str
    next_due: float


# ---- bulk data -------------------------------------------------------------------------------


class PointCloud(BulkMsg):
    """Points of one LiDAR sweep in the sensor's frame (x forward, y left, z up), metres."""

    sensor: str
    frame: str
    x: Annotated[np.ndarray, Array("<f4", doc="m")]
    y: Annotated[np.ndarray, Array("<f4", doc="m")]
    z: Annotated[np.ndarray, Array("<f4", doc="m")]
    intensity: Annotated[np.ndarray, Array("<f4", doc="0..1")]
    ring: Annotated[np.ndarray, Array("u1", doc="laser index, 0 = lowest")]

    @model_validator(mode="after")
    def _same_length(self) -> PointCloud:
        n = len(self.x)
        if any(len(getattr(self, name)) != n for name in self.ARRAYS):
            raise ValueError("x, y, z, intensity and ring must have one entry per point")
        return self

    @property
    def size(self) -> int:
        return len(self.x)


class LidarPackets(BulkMsg):
    """A Velodyne's UDP data packets as the driver received them in one step, back to back, so a
    recording can keep them and rebuild the clouds through the same decoder
    (ares/core/wire/velodyne_packets.py)."""

    sensor: str
    epoch: float  # the calendar time of stack time 0 by which the packets' own times were read
    flushed: bool = False  # after these packets the rotation under way was finished as it was (the stream stopped)
    sizes: Annotated[np.ndarray, Array("<u2", doc="each packet's length, bytes")]
    received: Annotated[np.ndarray, Array("<f8", doc="each packet's wall receive time, s")]
    data: Annotated[np.ndarray, Array("u1", doc="the packets' bytes, back to back")]

    @model_validator(mode="after")
    def _whole(self) -> LidarPackets:
        if len(self.received) != len(self.sizes) or int(self.sizes.sum(dtype=np.int64)) != len(self.data):
            raise ValueError("one size and one receive time per packet, and as many bytes as the sizes say")
        return self


class RoadBoundary(BaseModel):
    """A road boundary or the centre line in the vehicle frame: y = c0 + c1 x + c2 x² + ..., valid
    between x_min and x_max."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    coefficients: list[float]
    x_min: float
    x_max: float
    points: int = Field(0, ge=0)  # boundary points that support it (after the outliers went)

    def y_at(self, x: float) -> float:
        return float(sum(c * x**i for i, c in enumerate(self.coefficients)))


class RoadDetection(Msg):
    """The road ahead as the LiDARs see it (ARES §3.4.2), in the vehicle frame."""

    found: bool
    left: RoadBoundary | None = None
    right: RoadBoundary | None = None
    centre: RoadBoundary | None = None
    lateral_offset_m: float | None = None  # the vehicle's origin left (+) of the road's centre
    heading_rad: float | None = None  # the vehicle's heading relative to the road (+ left)
    width_m: float | None = None
    confidence: float = Field(0.0, ge=0, le=1)


class LidarHealth(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    rate_hz: float = Field(ge=0)  # sweeps received over the last second
    points: int = Field(ge=0)  # in the last sweep
    road_points: int = Field(ge=0)  # of them scored as road
    age_s: float | None = None  # since the last sweep
    blind: bool = False  # its point count fell to about zero (covered, failed)
    counting_s: float | None = None  # since this perception process's first sweep of it: a rate
    # counted over less than a window is not judged (a restart)


class LidarStatus(Msg):
    """Per LiDAR: its rate and how much road it sees, for the awareness manager; the pipeline's
    stage times."""

    sensors: dict[str, LidarHealth]
    stage_ms: dict[str, float] = Field(default_factory=dict)
    # what the road's guide was told the vehicle drove since the last frame (None: no fresh speed, or
    # a gap): after a loss it moves the last road found, so a replay sees what the step latched
    moved_m: float | None = None
    moved_curvature: float | None = None


class OccupancyGrid(BulkMsg):
    """A local grid around the vehicle: cells[row, col], row along y, col along x."""

    frame: str
    resolution_m: float = Field(gt=0)
    origin_x: float  # position of cell (0, 0)'s corner in `frame`, m
    origin_y: float
    cells: Annotated[np.ndarray, Array("u1", shape=(None, None), doc="0 free, 100 occupied, 255 unknown")]


class RecordRange(Msg):
    """The black-box seconds [start, end) a fleet store lacks, as UTC epoch seconds."""

    start_epoch_s: int = Field(ge=0)
    end_epoch_s: int = Field(ge=0)


class RecordBatch(Msg):
    """The recorder's answer: the records of a range it holds (memory, then its store), oldest
    first; the oldest second in its memory; and `complete_to_epoch_s`: every second of the range
    before it was sent or never recorded (None: a recorder from before it, that answered from
    memory only)."""

    records: list[VehicleRecord] = Field(default_factory=list)
    oldest_epoch_s: int | None = None
    complete_to_epoch_s: int | None = Field(default=None, ge=0)


class Acknowledgement(Msg):
    """The fleet's store holds every record of this vehicle up to `upto_epoch_s` (UTC epoch s),
    contiguous, nothing open before it; None: the fleet only asks for the vehicle's mark."""

    upto_epoch_s: int | None = Field(default=None, ge=0)


class AcknowledgementReply(Msg):
    """The mark the vehicle's store holds now, the oldest second it holds, and why the
    acknowledgement was not taken as sent ('' when it was)."""

    acknowledged_epoch_s: int | None = None
    oldest_held_epoch_s: int | None = None
    refused: str = ""


# an incident snapshot's file name (blackbox/register/snapshot_files.py)
SNAPSHOT_NAME = r"[A-Za-z0-9][A-Za-z0-9_.-]{0,150}\.mcap"
SNAPSHOT_PART_MAX_BYTES = 1 << 20


class SnapshotListRequest(Msg):
    """The fleet asks a vehicle which incident snapshots it keeps."""


class KeptSnapshot(BaseModel):
    """A snapshot's file as the vehicle keeps it, and the `snapshot` event that lists it."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    name: str = Field(pattern=f"^{SNAPSHOT_NAME}$")
    size_bytes: int = Field(ge=0)
    event: StoredEvent


class SnapshotList(Msg):
    """The snapshots a vehicle keeps: those its black box lists (newest first, at most a hundred)."""

    snapshots: list[KeptSnapshot] = Field(default_factory=list)


class SnapshotPartRequest(Msg):
    """The bytes [offset, offset + max_bytes) of a snapshot's file."""

    name: str = Field(pattern=f"^{SNAPSHOT_NAME}$")
    offset: int = Field(ge=0)
    max_bytes: int = Field(gt=0, le=SNAPSHOT_PART_MAX_BYTES)


class SnapshotPart(BulkMsg):
    """A piece of a snapshot's file from `offset`, and the file's whole size; `missing`: the
    vehicle keeps no such file (gone with the retention, or never one)."""

    name: str
    offset: int = Field(ge=0)
    size_bytes: int = Field(ge=0)
    missing: bool = False
    data: Annotated[np.ndarray, Array("u1", doc="the file's bytes from offset")]
