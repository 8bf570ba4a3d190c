"""The drive-by-wire bridge (DBW paper §4) without the bus: its decision core (modes, the setpoint
watchdog and the command gate) and `BridgeLoop`, one period of the board: driver actions and
setpoints into the mode machine, the gated command through Ackermann (control.ackermann) into the
two inner PID loops at 10 Hz, the standstill brake. The node (control.dbw_bridge_node) wires it to
the bus; the closed-loop harness drives the same class.

Read next to Fig. 17 of the DBW paper (§4.3 and §4.6):

    MANUAL --BUTTON--> READY --SET_AUTOMATIC--> AUTOMATIC
       ^                 |                          |
       +-----BUTTON------+                          |
       +-----BUTTON or any driver action -----------+   (driver action also from READY)

* The vehicle starts in MANUAL: the human drives and the bridge does not touch the actuators.
* The Auto/Manual button on the control panel is the hardware activation: MANUAL -> READY.
  In READY the bridge drives the actuators but only with null setpoints (stand still, steering
  wheel at 0), so a switched-on but idle stack cannot move the car.
* The `set_automatic_mode` service is the software activation: READY -> AUTOMATIC. Asked in
  MANUAL it is refused, since the button has to be pressed first.
* Pressing the throttle or brake pedal or turning the steering wheel returns to MANUAL from
  any mode: the driver can always take over.
* In AUTOMATIC the last setpoint is passed on, unless none has arrived for
  `setpoint_timeout_s` (1 s in the paper): then the bridge stops the car and centres the
  steering until fresh setpoints arrive.

No clock and no I/O here: every event carries its time t and `command(t)` is asked at a given
t, so the same event sequence always gives the same commands.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import asdict, dataclass
from enum import Enum

from ares.core.config import Params, VehicleProfile, param
from ares.core.messages import CanFrame, DriveMode
from control.ackermann import ActuatorSetpoint, SetpointConversion, max_curvature
from control.pid import PID

GRAVITY = 9.81  # m/s^2
STOP_COMMAND_MPS = 1e-3  # a command below this is a stop (the gate's ramps can leave 1e-17)


class Mode(str, Enum):
    MANUAL = "MANUAL"
    READY = "READY"
    AUTOMATIC = "AUTOMATIC"


class EventKind(str, Enum):
    BUTTON = "BUTTON"  # Auto/Manual button on the control panel
    SET_AUTOMATIC = "SET_AUTOMATIC"  # set_automatic_mode service request
    THROTTLE_PEDAL = "THROTTLE_PEDAL"  # driver actions ...
    BRAKE_PEDAL = "BRAKE_PEDAL"
    STEERING_WHEEL = "STEERING_WHEEL"
    SETPOINT = "SETPOINT"  # (v, kappa) from the navigation stack
    TICK = "TICK"  # time passes


DRIVER_ACTIONS = frozenset({EventKind.THROTTLE_PEDAL, EventKind.BRAKE_PEDAL, EventKind.STEERING_WHEEL})

# Fig. 17 as a table: (mode, event) -> next mode. Every pair is listed, so the tests can walk
# all of them and nothing is left to a default branch.
TRANSITIONS: dict[tuple[Mode, EventKind], Mode] = {
    (Mode.MANUAL, EventKind.BUTTON): Mode.READY,
    (Mode.MANUAL, EventKind.SET_AUTOMATIC): Mode.MANUAL,  # refused: button first
    (Mode.MANUAL, EventKind.THROTTLE_PEDAL): Mode.MANUAL,
    (Mode.MANUAL, EventKind.BRAKE_PEDAL): Mode.MANUAL,
    (Mode.MANUAL, EventKind.STEERING_WHEEL): Mode.MANUAL,
    (Mode.MANUAL, EventKind.SETPOINT): Mode.MANUAL,
    (Mode.MANUAL, EventKind.TICK): Mode.MANUAL,
    (Mode.READY, EventKind.BUTTON): Mode.MANUAL,
    (Mode.READY, EventKind.SET_AUTOMATIC): Mode.AUTOMATIC,
    (Mode.READY, EventKind.THROTTLE_PEDAL): Mode.MANUAL,
    (Mode.READY, EventKind.BRAKE_PEDAL): Mode.MANUAL,
    (Mode.READY, EventKind.STEERING_WHEEL): Mode.MANUAL,
    (Mode.READY, EventKind.SETPOINT): Mode.READY,
    (Mode.READY, EventKind.TICK): Mode.READY,
    (Mode.AUTOMATIC, EventKind.BUTTON): Mode.MANUAL,
    (Mode.AUTOMATIC, EventKind.SET_AUTOMATIC): Mode.AUTOMATIC,  # accepted, already there
    (Mode.AUTOMATIC, EventKind.THROTTLE_PEDAL): Mode.MANUAL,
    (Mode.AUTOMATIC, EventKind.BRAKE_PEDAL): Mode.MANUAL,
    (Mode.AUTOMATIC, EventKind.STEERING_WHEEL): Mode.MANUAL,
    (Mode.AUTOMATIC, EventKind.SETPOINT): Mode.AUTOMATIC,
    (Mode.AUTOMATIC, EventKind.TICK): Mode.AUTOMATIC,
}

SET_AUTOMATIC_REFUSED_IN_MANUAL = (
    "set_automatic_mode refused: the vehicle is in MANUAL; press the Auto/Manual button on "
    "the control panel first (hardware activation) to reach READY"
)

# Reasons attached to mode changes, for the events the bridge publishes.
_CHANGE_REASONS: dict[tuple[Mode, EventKind], str] = {
    (Mode.MANUAL, EventKind.BUTTON): "Auto/Manual button pressed: hardware armed, waiting for set_automatic_mode",
    (Mode.READY, EventKind.BUTTON): "Auto/Manual button pressed: back to manual driving",
    (Mode.AUTOMATIC, EventKind.BUTTON): "Auto/Manual button pressed: back to manual driving",
    (Mode.READY, EventKind.SET_AUTOMATIC): "set_automatic_mode accepted: autonomous driving",
}


def _change_reason(from_mode: Mode, kind: EventKind) -> str:
    if kind in DRIVER_ACTIONS:
        action = kind.value.lower().replace("_", " ")
        return f"driver actuated the {action}: driver takes over"
    return _CHANGE_REASONS[(from_mode, kind)]


@dataclass(frozen=True)
class Event:
    """Something that happened at time t (s, on the bridge's clock)."""

    kind: EventKind
    t: float
    v: float | None = None  # SETPOINT only
    kappa: float | None = None  # SETPOINT only

    def __post_init__(self):
        # A NaN or infinite time would silently break every age comparison below.
        if not isinstance(self.t, (int, float)) or not math.isfinite(self.t):
            raise ValueError(f"event time must be a finite number, got {self.t!r}")

    @classmethod
    def button(cls, t: float) -> Event:
        return cls(EventKind.BUTTON, t)

    @classmethod
    def set_automatic(cls, t: float) -> Event:
        return cls(EventKind.SET_AUTOMATIC, t)

    @classmethod
    def throttle_pedal(cls, t: float) -> Event:
        return cls(EventKind.THROTTLE_PEDAL, t)

    @classmethod
    def brake_pedal(cls, t: float) -> Event:
        return cls(EventKind.BRAKE_PEDAL, t)

    @classmethod
    def steering_wheel(cls, t: float) -> Event:
        return cls(EventKind.STEERING_WHEEL, t)

    @classmethod
    def setpoint(cls, v: float, kappa: float, t: float) -> Event:
        return cls(EventKind.SETPOINT, t, v, kappa)

    @classmethod
    def tick(cls, t: float) -> Event:
        return cls(EventKind.TICK, t)


@dataclass(frozen=True)
class Transition:
    """A mode change, as the bridge publishes it."""

    from_mode: Mode
    to_mode: Mode
    event: EventKind
    t: float
    reason: str

    def as_dict(self) -> dict:
        return {
            "from": self.from_mode.value,
            "to": self.to_mode.value,
            "event": self.event.value,
            "t": self.t,
            "reason": self.reason,
        }


@dataclass(frozen=True)
class Command:
    """What the bridge does at time t."""

    t: float
    mode: Mode
    engaged: bool  # False: the human drives; True: the bridge drives the actuators
    v: float  # m/s, within [0, max_speed]
    kappa: float  # 1/m, within ±max_curvature
    watchdog_tripped: bool  # AUTOMATIC without a setpoint for longer than the timeout
    limited: bool  # the command gate had to clamp v or kappa
    reason: str
    setpoint_age_s: float | None  # age of the last valid setpoint, None if none yet

    @property
    def is_null(self) -> bool:
        return self.v == 0.0 and self.kappa == 0.0

    def as_dict(self) -> dict:
        out = asdict(self)
        out["mode"] = self.mode.value
        return out


@dataclass(frozen=True)
class Outcome:
    """The answer to one event: accepted or not and why, the mode change if any, and the
    command at the event's time."""

    event: Event
    accepted: bool
    reason: str
    transition: Transition | None
    command: Command
    watchdog_changed: bool  # the watchdog tripped or recovered with this event


@dataclass(frozen=True)
class DbwLimits:
    """Vehicle limits that no command leaving the bridge may exceed."""

    max_speed_mps: float
    max_curvature: float  # 1/m, magnitude

    def __post_init__(self):
        for name in ("max_speed_mps", "max_curvature"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive finite number, got {value!r}")

    @classmethod
    def from_profile(cls, profile: VehicleProfile) -> DbwLimits:
        """From a vehicle profile: max_speed_mps, and the curvature the steering allows,
        tan(max_wheel_angle_rad) / wheelbase_m."""
        return cls(
            max_speed_mps=profile.max_speed_mps,
            max_curvature=max_curvature(profile.wheelbase_m, profile.max_wheel_angle_rad),
        )


def command_gate(v: float, kappa: float, limits: DbwLimits) -> tuple[float, float, bool]:
    """Last check before anything leaves the bridge: v into [0, max_speed], κ into
    ±max_curvature. A non-finite value (which should never get this far) becomes the null
    setpoint. Returns (v, kappa, limited)."""
    if not (math.isfinite(v) and math.isfinite(kappa)):
        return 0.0, 0.0, True
    gated_v = min(max(v, 0.0), limits.max_speed_mps)
    gated_kappa = min(max(kappa, -limits.max_curvature), limits.max_curvature)
    # +0.0 rather than -0.0, so a null setpoint always prints and compares the same way.
    gated_v += 0.0
    gated_kappa += 0.0
    return gated_v, gated_kappa, (gated_v != v or gated_kappa != kappa)


@dataclass(frozen=True)
class _Setpoint:
    v: float
    kappa: float
    t: float


def setpoint_problem(v: object, kappa: object) -> str | None:
    """Why a setpoint cannot be used, or None if it can."""
    for name, value in (("v", v), ("kappa", kappa)):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return f"setpoint rejected: {name} is not a number ({value!r})"
        if not math.isfinite(value):
            return f"setpoint rejected: {name} is not finite ({value!r})"
    return None


class DbwCore:
    """The bridge's state machine (DBW Fig. 17). Feed it events with `handle`, ask `command(t)`."""

    HISTORY_LENGTH = 100

    def __init__(self, limits: DbwLimits, setpoint_timeout_s: float = 1.0):
        if not (math.isfinite(setpoint_timeout_s) and setpoint_timeout_s > 0):
            raise ValueError(f"setpoint_timeout_s must be positive, got {setpoint_timeout_s!r}")
        self.limits = limits
        self.setpoint_timeout_s = float(setpoint_timeout_s)
        self.mode = Mode.MANUAL
        # Last valid setpoint received in any mode: feeds the watchdog and diagnostics.
        self.last_setpoint: _Setpoint | None = None
        # Setpoint received since the switch to AUTOMATIC, the only one ever acted on; cleared
        # on every mode change so a setpoint from before the switch is never used.
        self._active_setpoint: _Setpoint | None = None
        self.rejected_setpoints = 0
        self.last_rejection: str | None = None
        self.history: deque[Transition] = deque(maxlen=self.HISTORY_LENGTH)
        self._watchdog_was_tripped = False

    @classmethod
    def from_profile(cls, profile: VehicleProfile, setpoint_timeout_s: float) -> DbwCore:
        return cls(DbwLimits.from_profile(profile), setpoint_timeout_s)

    # -- events ---------------------------------------------------------------------------

    def handle(self, event: Event) -> Outcome:
        from_mode = self.mode
        to_mode = TRANSITIONS[(from_mode, event.kind)]
        accepted, reason = True, ""

        if event.kind is EventKind.SETPOINT:
            accepted, reason = self._take_setpoint(event)
        elif event.kind is EventKind.SET_AUTOMATIC:
            accepted = to_mode is Mode.AUTOMATIC
            if not accepted:
                reason = SET_AUTOMATIC_REFUSED_IN_MANUAL
            elif from_mode is Mode.AUTOMATIC:
                reason = "set_automatic_mode accepted: already AUTOMATIC"
        elif event.kind in DRIVER_ACTIONS and from_mode is Mode.MANUAL:
            reason = "driver action in MANUAL: the driver already drives"

        transition = None
        if to_mode is not from_mode:
            transition = Transition(from_mode, to_mode, event.kind, event.t, _change_reason(from_mode, event.kind))
            self.mode = to_mode
            self._active_setpoint = None
            self.history.append(transition)
            reason = transition.reason

        command = self.command(event.t)
        watchdog_changed = command.watchdog_tripped != self._watchdog_was_tripped
        self._watchdog_was_tripped = command.watchdog_tripped
        return Outcome(event, accepted, reason or "ok", transition, command, watchdog_changed)

    def _take_setpoint(self, event: Event) -> tuple[bool, str]:
        problem = setpoint_problem(event.v, event.kappa)
        if problem is not None:
            # A broken setpoint must not keep the watchdog quiet: it refreshes nothing.
            self.rejected_setpoints += 1
            self.last_rejection = problem
            return False, problem
        setpoint = _Setpoint(float(event.v), float(event.kappa), event.t)
        self.last_setpoint = setpoint
        if self.mode is Mode.AUTOMATIC:
            self._active_setpoint = setpoint
            return True, "ok"
        return True, f"setpoint noted but not used in {self.mode.value}"

    # -- output ---------------------------------------------------------------------------

    def command(self, t: float) -> Command:
        """What the bridge sends at time t. Does not change the state."""
        age = None if self.last_setpoint is None else t - self.last_setpoint.t

        if self.mode is Mode.MANUAL:
            return self._null(t, age, engaged=False, reason="MANUAL: the driver drives")
        if self.mode is Mode.READY:
            return self._null(t, age, engaged=True, reason="READY: null setpoint until set_automatic_mode")

        # AUTOMATIC. A negative age means the clock went backwards: trust nothing.
        if age is None or not (0.0 <= age <= self.setpoint_timeout_s):
            if age is None:
                why = "no setpoint received"
            elif age < 0.0:
                why = f"last setpoint is from the future ({-age:.3f} s ahead): clock went back"
            else:
                why = f"no setpoint for {age:.3f} s"
            return self._null(
                t,
                age,
                engaged=True,
                watchdog_tripped=True,
                reason=f"watchdog: {why} (timeout {self.setpoint_timeout_s} s): stop and centre the steering",
            )
        if self._active_setpoint is None:
            return self._null(t, age, engaged=True, reason="AUTOMATIC: waiting for a setpoint newer than the switch")

        v, kappa, limited = command_gate(self._active_setpoint.v, self._active_setpoint.kappa, self.limits)
        reason = "AUTOMATIC: setpoint limited to the vehicle" if limited else "AUTOMATIC"
        return Command(t, self.mode, True, v, kappa, False, limited, reason, age)

    def _null(
        self, t: float, age: float | None, *, engaged: bool, reason: str, watchdog_tripped: bool = False
    ) -> Command:
        v, kappa, limited = command_gate(0.0, 0.0, self.limits)
        return Command(t, self.mode, engaged, v, kappa, watchdog_tripped, limited, reason, age)


class DbwBridgeParams(Params):
    rate_hz: float = param(10.0, "inner PID loops (DBW paper: 100 ms period)", unit="Hz", gt=0)
    setpoint_timeout_s: float = param(
        0.5,
        "no command this long: stop and centre the steering (the DBW paper's "
        "1 s was for a 10 Hz navigation setpoint; the movement manager sends at "
        "50 Hz, and a dead one must be a stop begun within 1 s)",
        unit="s",
        gt=0,
    )
    standstill_speed_mps: float = param(0.3, "below this with a zero speed setpoint, hold the brake", unit="m/s", ge=0)
    standstill_brake_effort: float = param(0.5, "the brake held at standstill", ge=0, le=1)
    pedal_pressed: float = param(
        0.05, "pedal travel that counts as the driver acting (filters sensor noise)", ge=0, le=1
    )
    brake_assist_deadband_mps: float = param(
        0.5,
        "measured speed this far above a moving command: the brake helps the "
        "speed loop (a limit that falls at once: an obstacle, a pause); "
        "smaller gaps, as a speed section's step, are the loop's alone; a stop "
        "(a zero command) has no deadband",
        unit="m/s",
        ge=0,
    )
    brake_assist_time_s: float = param(
        0.5,
        "... asking the deceleration that closes the gap beyond the deadband in this time (a stop "
        "downhill: the grade's pull braked on top)",
        unit="s",
        gt=0,
    )
    brake_assist_max_decel_mps2: float = param(
        3.0, "... at most, besides a stop's measured descent (the full brake is for emergencies)", unit="m/s^2", gt=0
    )
    speed_feedforward: bool = param(
        False,
        "the speed loop adds the commanded speed's steady effort (v / the motor's full-effort speed): "
        "the PI keeps only the rest, so a ramp is followed at once, not after the integral (off: the "
        "DBW paper's board; in the whole stack it did not help, docs/control.md)",
    )
    can_timeout_s: float = param(
        0.5, "older CAN readings leave the inner loops blind: engaged, the board brakes", unit="s", gt=0
    )
    imu_timeout_s: float = param(
        0.5, "an older IMU reading leaves the hill-hold without a pitch: it assumes the steepest grade", unit="s", gt=0
    )
    hill_hold_unknown_grade: float = param(
        0.15,
        "the grade the hill-hold assumes without a pitch: the steepest the shuttle stands on (the tour's: 15 %)",
        ge=0,
    )


@dataclass(frozen=True)
class BridgeOutput:
    command: Command  # what the mode machine and the gate let through
    reference: ActuatorSetpoint  # the inner loops' references for that command
    steer_effort: float
    drive_effort: float


class BridgeLoop:
    """The board without the bus: events in, efforts out, one call per period."""

    def __init__(self, profile: VehicleProfile, params: DbwBridgeParams):
        self.params = params
        self.core = DbwCore.from_profile(profile, params.setpoint_timeout_s)
        self.conversion = SetpointConversion(profile)
        self.steering_pid = PID.from_gains(profile.dbw_pid.steering)
        self.wheel_speed_pid = PID.from_gains(profile.dbw_pid.throttle)
        self.dt = 1.0 / params.rate_hz
        # the speed loop's PI, tuned for tracking (DBW paper), brakes at a fraction of 1 m/s^2 for
        # a speed 1 m/s too high: the brake's effort per m/s^2 for a gap it must close fast
        traction = profile.actuators.traction
        self.brake_effort_per_mps2 = (
            profile.empty_mass_kg + 2 * profile.passenger_mass_kg
        ) / traction.max_brake_force_n
        self.full_effort_speed_mps = traction.full_effort_speed_mps
        # the motor at standstill pushes k_slip * effort * full-effort speed; the grade pulls m g sin(climb)
        self.loaded_weight_n = (profile.empty_mass_kg + profile.seats * profile.passenger_mass_kg) * GRAVITY
        self.stall_force_per_effort_n = traction.slip_stiffness_n_per_mps * traction.full_effort_speed_mps
        self.max_brake_force_n = traction.max_brake_force_n
        self.steepest_climb_rad = math.atan(params.hill_hold_unknown_grade)  # the steepest the shuttle stands on
        self.hill_hold = False  # standing on the brake until the motor holds the grade
        self._was_engaged = False
        self.emergency = False  # the movement manager's latched emergency stop: brake fully

    def handle(self, event: Event) -> Outcome:
        return self.core.handle(event)

    def driver_actions_from_can(self, can: CanFrame | None, now: float) -> list[Outcome]:
        """The pedals and steering torque on the CAN bus: a second path to Manual, should a panel
        event be missed."""
        if can is None or self.core.mode.value == DriveMode.MANUAL.value:
            return []
        if can.throttle_pedal > self.params.pedal_pressed:
            return [self.handle(Event.throttle_pedal(now))]
        if can.brake_pedal > self.params.pedal_pressed:
            return [self.handle(Event.brake_pedal(now))]
        if can.steering_torque:
            return [self.handle(Event.steering_wheel(now))]
        return []

    def hold_effort(self, pitch_rad: float | None) -> float:
        """The drive effort whose motor force at standstill holds the fully loaded shuttle on this
        pitch (REP-103: a climb's is negative); without a pitch, on the steepest grade it stands on.
        Rolling resistance, which helps to hold, is left out: the brake lets go a little late
        rather than early."""
        climb = -pitch_rad if pitch_rad is not None else self.steepest_climb_rad
        return min(max(self.loaded_weight_n * math.sin(climb) / self.stall_force_per_effort_n, 0.0), 1.0)

    def assist_effort(self, v_cmd: float, v: float, pitch_rad: float | None) -> float:
        """The brake's help to the speed loop (1.0: none; negative: braking). A speed above a moving
        command by more than the deadband asks the deceleration that closes the rest of the gap in
        `brake_assist_time_s`, at most `brake_assist_max_decel_mps2`, as before.

        A stop (a zero command) has no deadband and takes a descent's pull too: the PI alone let a
        shuttle roll on down a 12 % descent at the deadband's 0.5 m/s for 4 s after its command
        had reached 0 (soak), for its effort balanced the grade until its integral had wound up. The
        pull, m g sin(pitch) of the fully loaded shuttle, is braked on top of the deceleration asked
        with the IMU's pitch (REP-103: a descent's is positive); without one the steepest descent
        (`hill_hold_unknown_grade`) is assumed, within the largest deceleration, so that a stop on
        the flat with a silent IMU brakes no harder than the assist may."""
        stopping = v_cmd < STOP_COMMAND_MPS
        deadband = 0.0 if stopping else self.params.brake_assist_deadband_mps
        gap = v - v_cmd
        if gap <= deadband:
            return 1.0
        most = self.params.brake_assist_max_decel_mps2
        decel = min((gap - deadband) / self.params.brake_assist_time_s, most)
        effort = decel * self.brake_effort_per_mps2
        if stopping and pitch_rad is not None:
            effort += self.loaded_weight_n * math.sin(max(pitch_rad, 0.0)) / self.max_brake_force_n
        elif stopping:
            assumed = GRAVITY * math.sin(self.steepest_climb_rad)
            effort = min(decel + assumed, most) * self.brake_effort_per_mps2
        return -min(1.0, effort)

    def efforts(self, now: float, can: CanFrame | None, pitch_rad: float | None = None) -> BridgeOutput:
        """The period's command and the efforts of the two inner loops; `can` None: no fresh
        readings, so the loops cannot close and an engaged board brakes with the wheel left alone.
        `pitch_rad`: the IMU's (None: none fresh), for the hill-hold and a fresh loop's integral."""
        cmd = self.core.command(now)
        reference = self.conversion.to_actuators(cmd.v, cmd.kappa)
        steer_effort = drive_effort = 0.0
        if cmd.engaged and can is None:
            drive_effort = -1.0
        elif cmd.engaged:
            if not self._was_engaged:
                self.steering_pid.reset()
                # the integral that holds the climb it finds, not nought: a loop engaged (or
                # restarted) on a shuttle still rolling up a climb let it roll back (soak). A pitch
                # read on a bump may claim more: no steeper than the tour's steepest
                holding = 0.0 if pitch_rad is None else self.hold_effort(max(pitch_rad, -self.steepest_climb_rad))
                self.wheel_speed_pid.reset(integral=holding)
            steer_effort = self.steering_pid.step(reference.steering_wheel_angle_deg, can.steering_wheel_deg, self.dt)
            steady = cmd.v / self.full_effort_speed_mps if self.params.speed_feedforward else 0.0
            drive_effort = self.wheel_speed_pid.step(
                reference.wheel_speed_rad_s, can.wheel_speed_rad_s, self.dt, feedforward=steady
            )
            drive_effort = min(drive_effort, self.assist_effort(cmd.v, can.speed_mps, pitch_rad))
            standing = can.speed_mps < self.params.standstill_speed_mps
            stop_asked = cmd.v < STOP_COMMAND_MPS  # one meaning of a stop, as the brake assist's
            if standing and (stop_asked or not self._was_engaged):
                self.hill_hold = True
            if standing and self.hill_hold and (stop_asked or drive_effort < self.hold_effort(pitch_rad)):
                # a PI loop alone creeps around zero on a slope, and a start lets go of the brake
                # with the integral at nought (after an engagement, a restart): the board holds the
                # brake until the loop asks enough of the motor to hold the grade (a hill-hold)
                drive_effort = min(drive_effort, -self.params.standstill_brake_effort)
            else:
                self.hill_hold = False
            if self.emergency:
                drive_effort = -1.0
        self._was_engaged = cmd.engaged and can is not None
        return BridgeOutput(cmd, reference, steer_effort, drive_effort)
