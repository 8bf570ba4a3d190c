"""Drive-by-wire bridge (DBW paper §4): navigation setpoints in, actuator efforts out.

The mode machine, watchdog, command gate and the board's period (`BridgeLoop`) live in
control.dbw_bridge; the equations in control.ackermann. This node wires them to the bus.

The mode lives on the board (its hardware keeps it), this process is its software half: a
restarted bridge process finds the mode where its predecessor left it (`dbw_bridge.json` beside
the run's configuration stands for the board's memory), with the watchdog tripped until commands
come again. A first start is always Manual: only a person's button arms the board.
"""

from __future__ import annotations

import json
import math

from ares.core.messages import (
    ActuatorCommand,
    CarState,
    DbwMeasure,
    DbwReference,
    DriveMode,
    EventLevel,
    ModeReply,
    PanelInput,
)
from ares.core.node import Input, Node, Output, service
from control.dbw_bridge import BridgeLoop, DbwBridgeParams, Event, Mode, Outcome

PANEL_EVENTS = {
    PanelInput.BUTTON: Event.button,
    PanelInput.THROTTLE_PEDAL: Event.throttle_pedal,
    PanelInput.BRAKE_PEDAL: Event.brake_pedal,
    PanelInput.STEERING_WHEEL: Event.steering_wheel,
}


class DbwBridge(Node):
    """Manual / Ready / Automatic modes, the setpoint watchdog, the command gate, the inner loops."""

    name = "dbw_bridge"
    Params = DbwBridgeParams
    setpoints = Input(
        "movement/command", queue=64, doc="(v, kappa, emergency) from the movement manager: the only source of commands"
    )
    panel = Input("vehicle/panel", queue=64, doc="button, pedals, steering wheel")
    can = Input(
        "sensors/can", max_age="can_timeout_s", doc="measured steering-wheel angle and wheel speed, pedal positions"
    )
    imu = Input("sensors/imu", max_age="imu_timeout_s", doc="the pitch: how hard the hill-hold must let the motor push")
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
        return ModeReply(
            t=self.clock.now(),
            accepted=outcome.accepted,
            mode=DriveMode(self.board.core.mode.value),
            reason=outcome.reason,
        )

    def _handle(self, event: Event) -> Outcome:
        return self._report(self.board.handle(event), event)

    def _report(self, outcome: Outcome, event: Event) -> Outcome:
        if outcome.transition is not None:
            tr = outcome.transition
            self.event(
                "mode_change",
                f"{tr.from_mode.value} -> {tr.to_mode.value}: {tr.reason}",
                **{"from": tr.from_mode.value, "to": tr.to_mode.value, "cause": event.kind.value},
            )
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
        imu = self.imu.fresh(now)
        out = self.board.efforts(now, can, None if imu is None else imu.pitch)
        cmd = out.command
        self.actuators.put(
            ActuatorCommand(t=now, engaged=cmd.engaged, steer_effort=out.steer_effort, drive_effort=out.drive_effort)
        )
        self.reference.put(
            DbwReference(
                t=now,
                steering_wheel_deg=out.reference.steering_wheel_angle_deg,
                wheel_speed_deg_s=out.reference.wheel_speed_deg_s,
                v=cmd.v,
                kappa=cmd.kappa,
            )
        )
        if can is not None:
            wheel_speed_deg_s = math.degrees(can.wheel_speed_rad_s)
            measured = self.board.conversion.to_speed_curvature_deg(can.steering_wheel_deg, wheel_speed_deg_s)
            self.measure.put(
                DbwMeasure(
                    t=now,
                    steering_wheel_deg=can.steering_wheel_deg,
                    wheel_speed_deg_s=wheel_speed_deg_s,
                    v=measured.v,
                    kappa=measured.kappa,
                )
            )
        self.car_state.put(
            CarState(
                t=now,
                mode=DriveMode(self.board.core.mode.value),
                engaged=cmd.engaged,
                watchdog_tripped=cmd.watchdog_tripped,
                setpoint_age_s=cmd.setpoint_age_s,
                v_command=cmd.v,
                kappa_command=cmd.kappa,
                speed_mps=can.speed_mps if can else 0.0,
                steering_wheel_deg=can.steering_wheel_deg if can else 0.0,
                reason=cmd.reason,
                emergency=self.board.emergency,
            )
        )
