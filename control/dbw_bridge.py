"""Drive-by-wire bridge (DBW paper §4): navigation setpoints in, actuator efforts out.

The mode machine, watchdog and command gate live in control.dbw_logic; the equations in
control.ackermann. `BridgeLoop` is one period of the board: driver actions and setpoints into the
mode machine, the gated command through Ackermann into the two inner PID loops at 10 Hz, the
standstill brake. The node wires it to the bus; the closed-loop harness drives the same class.

The mode lives on the board (its hardware keeps it), this process is its software half: a
restarted bridge process finds the mode where its predecessor left it (`dbw_bridge.json` beside
the run's configuration stands for the board's memory), with the watchdog tripped until commands
come again. A first start is always Manual: only a person's button arms the board.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass

from ares.config import Params, VehicleProfile, param
from ares.messages import (ActuatorCommand, CanFrame, CarState, DbwMeasure, DbwReference, DriveMode, EventLevel,
                           ModeReply, PanelInput)
from ares.node import Input, Node, Output, service
from control.ackermann import ActuatorSetpoint, SetpointConversion
from control.dbw_logic import Command, DbwCore, Event, Mode, Outcome
from control.pid import PID

PANEL_EVENTS = {
    PanelInput.BUTTON: Event.button,
    PanelInput.THROTTLE_PEDAL: Event.throttle_pedal,
    PanelInput.BRAKE_PEDAL: Event.brake_pedal,
    PanelInput.STEERING_WHEEL: Event.steering_wheel,
}


class DbwBridgeParams(Params):
    rate_hz: float = param(10.0, "inner PID loops (DBW paper: 100 ms period)", unit="Hz", gt=0)
    setpoint_timeout_s: float = param(0.5, "no command this long: stop and centre the steering (the DBW paper's "
                                           "1 s was for a 10 Hz navigation setpoint; the movement manager sends at "
                                           "50 Hz, and a dead one must be a stop begun within 1 s)", unit="s", gt=0)
    standstill_speed_mps: float = param(0.3, "below this with a zero speed setpoint, hold the brake", unit="m/s", ge=0)
    standstill_brake_effort: float = param(0.5, "the brake held at standstill", ge=0, le=1)
    pedal_pressed: float = param(0.05, "pedal travel that counts as the driver acting (filters sensor noise)",
                                 ge=0, le=1)
    brake_assist_deadband_mps: float = param(0.5, "measured speed this far above the command: the brake helps the "
                                                  "speed loop (a limit that falls at once: an obstacle, a pause); "
                                                  "smaller gaps, as a speed section's step, are the loop's alone",
                                             unit="m/s", ge=0)
    brake_assist_time_s: float = param(0.5, "... asking the deceleration that closes the gap beyond the deadband in "
                                            "this time", unit="s", gt=0)
    brake_assist_max_decel_mps2: float = param(3.0, "... at most (the full brake is for emergencies)", unit="m/s^2",
                                               gt=0)
    can_timeout_s: float = param(0.5, "older CAN readings leave the inner loops blind: engaged, the board brakes",
                                 unit="s", gt=0)


@dataclass(frozen=True)
class BridgeOutput:
    command: Command                # what the mode machine and the gate let through
    reference: ActuatorSetpoint     # the inner loops' references for that command
    steer_effort: float
    drive_effort: float


class BridgeLoop:
    """The board without the bus: events in, efforts out, one call per period."""

    def __init__(self, profile: VehicleProfile, params: DbwBridgeParams):
        self.params = params
        self.core = DbwCore.from_profile(profile, params.setpoint_timeout_s)
        self.conversion = SetpointConversion.from_profile(profile)
        self.steering_pid = PID.from_gains(profile.dbw_pid.steering)
        self.wheel_speed_pid = PID.from_gains(profile.dbw_pid.throttle)
        self.dt = 1.0 / params.rate_hz
        # the speed loop's PI, tuned for tracking (DBW paper), brakes at a fraction of 1 m/s^2 for
        # a speed 1 m/s too high: the brake's effort per m/s^2 for a gap it must close fast
        self.brake_effort_per_mps2 = (profile.empty_mass_kg + 2 * profile.passenger_mass_kg) / \
            profile.actuators.traction.max_brake_force_n
        self._was_engaged = False
        self.emergency = False          # the movement manager's latched emergency stop: brake fully

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

    def efforts(self, now: float, can: CanFrame | None) -> BridgeOutput:
        """The period's command and the efforts of the two inner loops; `can` None: no fresh
        readings, so the loops cannot close and an engaged board brakes with the wheel left alone."""
        cmd = self.core.command(now)
        reference = self.conversion.to_actuators(cmd.v, cmd.kappa)
        steer_effort = drive_effort = 0.0
        if cmd.engaged and can is None:
            drive_effort = -1.0
        elif cmd.engaged:
            if not self._was_engaged:
                self.steering_pid.reset()
                self.wheel_speed_pid.reset()
            steer_effort = self.steering_pid.step(reference.steering_wheel_angle_deg, can.steering_wheel_deg, self.dt)
            drive_effort = self.wheel_speed_pid.step(reference.wheel_speed_rad_s, can.wheel_speed_rad_s, self.dt)
            gap = can.speed_mps - cmd.v
            if gap > self.params.brake_assist_deadband_mps:
                decel = min((gap - self.params.brake_assist_deadband_mps) / self.params.brake_assist_time_s,
                            self.params.brake_assist_max_decel_mps2)
                drive_effort = min(drive_effort, -min(1.0, decel * self.brake_effort_per_mps2))
            if cmd.v == 0.0 and can.speed_mps < self.params.standstill_speed_mps:
                # a PI loop alone creeps around zero on a slope; the board holds the brake
                drive_effort = min(drive_effort, -self.params.standstill_brake_effort)
            if self.emergency:
                drive_effort = -1.0
        self._was_engaged = cmd.engaged and can is not None
        return BridgeOutput(cmd, reference, steer_effort, drive_effort)


class DbwBridge(Node):
    """Manual / Ready / Automatic modes, the setpoint watchdog, the command gate, the inner loops."""
    name = "dbw_bridge"
    Params = DbwBridgeParams
    setpoints = Input("movement/command", queue=64, doc="(v, kappa, emergency) from the movement manager: the only "
                                                        "source of commands")
    panel = Input("vehicle/panel", queue=64, doc="button, pedals, steering wheel")
    can = Input("sensors/can", max_age="can_timeout_s",
                doc="measured steering-wheel angle and wheel speed, pedal positions")
    actuators = Output("dbw/actuators", rate="rate_hz", doc="efforts to the steering motor and traction/brake")
    reference = Output("dbw/reference", rate="rate_hz", doc="the inner loops' references")
    measure = Output("dbw/measure", doc="when CAN readings have arrived")
    car_state = Output("dbw/car_state", rate="rate_hz", doc="mode, watchdog, command and measured motion")

    def setup(self) -> None:
        self.board = BridgeLoop(self.vehicle, self.params)
        self.kept = self.kept_state_path()
        if self.restarted and self.kept is not None and self.kept.exists():
            try:
                mode = Mode(json.loads(self.kept.read_text())["mode"])
            except (OSError, ValueError, KeyError, TypeError) as exc:
                self.event("mode_change", f"the board's mode could not be read ({exc}): Manual", EventLevel.WARNING)
            else:
                self.board.core.mode = mode
                self.event("mode_change", f"restarted: the board is still in {mode.value}", to=mode.value)

    def _keep_mode(self) -> None:
        if self.kept is not None:
            tmp = self.kept.with_suffix(".tmp")
            tmp.write_text(json.dumps({"mode": self.board.core.mode.value}))
            tmp.replace(self.kept)

    @service("set_automatic_mode")
    def _set_automatic_mode(self, _request) -> ModeReply:
        outcome = self._handle(Event.set_automatic(self.clock.now()))
        return ModeReply(t=self.clock.now(), accepted=outcome.accepted, mode=DriveMode(self.board.core.mode.value),
                         reason=outcome.reason)

    def _handle(self, event: Event) -> Outcome:
        return self._report(self.board.handle(event), event)

    def _report(self, outcome: Outcome, event: Event) -> Outcome:
        if outcome.transition is not None:
            tr = outcome.transition
            self.event("mode_change", f"{tr.from_mode.value} -> {tr.to_mode.value}: {tr.reason}",
                       **{"from": tr.from_mode.value, "to": tr.to_mode.value, "cause": event.kind.value})
            self._keep_mode()
        if outcome.watchdog_changed:
            cmd = outcome.command
            if cmd.watchdog_tripped:
                age = "ever" if cmd.setpoint_age_s is None else f"{cmd.setpoint_age_s:.2f} s"
                self.event("watchdog", f"no setpoint for {age}: stopping, steering centred", EventLevel.FAULT)
            else:
                self.event("watchdog", "setpoints are back", EventLevel.INFO)
        return outcome

    def step(self, now: float) -> None:
        for _, panel in self.panel.drain():
            self._handle(PANEL_EVENTS[panel.input](now))
        can = self.can.fresh(now)
        for outcome in self.board.driver_actions_from_can(can, now):
            self._report(outcome, outcome.event)
        for _, sp in self.setpoints.drain():
            # as old as its stamp says: a setpoint that arrives late must not keep the watchdog quiet
            self._handle(Event.setpoint(sp.v, sp.kappa, sp.t))
            self.board.emergency = sp.emergency
        self._handle(Event.tick(now))
        out = self.board.efforts(now, can)
        cmd = out.command
        self.actuators.put(ActuatorCommand(t=now, engaged=cmd.engaged, steer_effort=out.steer_effort,
                                           drive_effort=out.drive_effort))
        self.reference.put(DbwReference(t=now, steering_wheel_deg=out.reference.steering_wheel_angle_deg,
                                        wheel_speed_deg_s=out.reference.wheel_speed_deg_s, v=cmd.v, kappa=cmd.kappa))
        if can is not None:
            wheel_speed_deg_s = math.degrees(can.wheel_speed_rad_s)
            measured = self.board.conversion.to_speed_curvature_deg(can.steering_wheel_deg, wheel_speed_deg_s)
            self.measure.put(DbwMeasure(t=now, steering_wheel_deg=can.steering_wheel_deg,
                                        wheel_speed_deg_s=wheel_speed_deg_s, v=measured.v, kappa=measured.kappa))
        self.car_state.put(CarState(
            t=now, mode=DriveMode(self.board.core.mode.value), engaged=cmd.engaged,
            watchdog_tripped=cmd.watchdog_tripped, setpoint_age_s=cmd.setpoint_age_s,
            v_command=cmd.v, kappa_command=cmd.kappa, speed_mps=can.speed_mps if can else 0.0,
            steering_wheel_deg=can.steering_wheel_deg if can else 0.0, reason=cmd.reason,
            emergency=self.board.emergency))
