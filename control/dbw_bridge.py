"""Drive-by-wire bridge (DBW paper §4): navigation setpoints in, actuator efforts out.

Inputs:   control/setpoint (v, kappa) · vehicle/panel (button, pedals, steering wheel)
          · sensors/can (measured steering-wheel angle and wheel speed, pedal positions)
Outputs:  dbw/actuators (efforts to the steering motor and traction/brake) · dbw/reference
          · dbw/measure · dbw/car_state · events (mode changes, watchdog)
Services: set_automatic_mode (the software half of Manual -> Ready -> Automatic)
Params:   dbw.rate_hz (10 Hz inner loops), dbw.setpoint_timeout_s, vehicle profile and its
          dbw_pid gains.

The mode machine, watchdog and command gate live in control.dbw_logic; the equations in
control.ackermann; this node only wires them to the bus and runs the two inner PID loops.
"""
from __future__ import annotations

import math

from ares.messages import (ActuatorCommand, CarState, DbwMeasure, DbwReference, DriveMode,
                           EventLevel, ModeReply, PanelInput)
from ares.node import Node, run_node
from control.ackermann import SetpointConversion
from control.dbw_logic import DbwCore, Event
from control.pid import PID

PANEL_EVENTS = {
    PanelInput.BUTTON: Event.button,
    PanelInput.THROTTLE_PEDAL: Event.throttle_pedal,
    PanelInput.BRAKE_PEDAL: Event.brake_pedal,
    PanelInput.STEERING_WHEEL: Event.steering_wheel,
}
PEDAL_PRESSED = 0.05    # pedal travel that counts as the driver acting (filters sensor noise)


class DbwBridge(Node):
    name = "dbw_bridge"
    rate_key = "dbw.rate_hz"

    def setup(self) -> None:
        profile = self.cfg["vehicle_profile"]
        self.core = DbwCore.from_profile(profile, float(self.cfg["dbw"]["setpoint_timeout_s"]))
        self.conversion = SetpointConversion(profile)
        self.steering_pid = PID.from_config(profile["dbw_pid"]["steering"])
        self.wheel_speed_pid = PID.from_config(profile["dbw_pid"]["throttle"])
        self.dt = 1.0 / self.rate_hz
        self.setpoints = self.bus.subscribe("control/setpoint", queue=64)
        self.panel = self.bus.subscribe("vehicle/panel", queue=64)
        self.can = self.bus.subscribe("sensors/can")
        self.actuators = self.bus.publisher("dbw/actuators")
        self.bus.serve("set_automatic_mode", self._set_automatic_mode)
        self._was_engaged = False
        self.standstill_speed = float(self.cfg["dbw"]["standstill_speed_mps"])
        self.standstill_brake = float(self.cfg["dbw"]["standstill_brake_effort"])

    def _set_automatic_mode(self, _request) -> ModeReply:
        outcome = self._handle(Event.set_automatic(self.clock.now()))
        return ModeReply(t=self.clock.now(), accepted=outcome.accepted, mode=DriveMode(self.core.mode.value),
                         reason=outcome.reason)

    def _handle(self, event: Event):
        outcome = self.core.handle(event)
        if outcome.transition is not None:
            tr = outcome.transition
            self.event("mode_change", f"{tr.from_mode.value} -> {tr.to_mode.value}: {tr.reason}",
                       **{"from": tr.from_mode.value, "to": tr.to_mode.value, "cause": event.kind.value})
        if outcome.watchdog_changed:
            cmd = outcome.command
            if cmd.watchdog_tripped:
                age = "ever" if cmd.setpoint_age_s is None else f"{cmd.setpoint_age_s:.2f} s"
                self.event("watchdog", f"no setpoint for {age}: stopping, steering centred", EventLevel.FAULT)
            else:
                self.event("watchdog", "setpoints are back", EventLevel.INFO)
        return outcome

    def _driver_actions_from_can(self, now: float) -> None:
        """The pedals and steering torque on the CAN bus: a second path to Manual, should a
        panel event be missed."""
        can = self.can.latest
        if can is None or self.core.mode.value == DriveMode.MANUAL.value:
            return
        if can.throttle_pedal > PEDAL_PRESSED:
            self._handle(Event.throttle_pedal(now))
        elif can.brake_pedal > PEDAL_PRESSED:
            self._handle(Event.brake_pedal(now))
        elif can.steering_torque:
            self._handle(Event.steering_wheel(now))

    def step(self, now: float) -> None:
        for _, panel in self.panel.drain():
            self._handle(PANEL_EVENTS[panel.input](now))
        self._driver_actions_from_can(now)
        for _, sp in self.setpoints.drain():
            self._handle(Event.setpoint(sp.v, sp.kappa, now))
        self._handle(Event.tick(now))
        cmd = self.core.command(now)

        can = self.can.latest
        measured_angle = can.steering_wheel_deg if can else 0.0
        measured_speed = can.speed_mps if can else 0.0
        reference = self.conversion.to_actuators(cmd.v, cmd.kappa)
        if cmd.engaged and can is not None:
            if not self._was_engaged:
                self.steering_pid.reset()
                self.wheel_speed_pid.reset()
            steer_effort = self.steering_pid.step(reference.steering_wheel_angle_deg, measured_angle, self.dt)
            drive_effort = self.wheel_speed_pid.step(reference.wheel_speed_rad_s, can.wheel_speed_rad_s, self.dt)
            if cmd.v == 0.0 and measured_speed < self.standstill_speed:
                # a PI loop alone creeps around zero on a slope; the board holds the brake
                drive_effort = min(drive_effort, -self.standstill_brake)
        else:
            steer_effort = drive_effort = 0.0
        self._was_engaged = cmd.engaged and can is not None
        self.actuators.put(ActuatorCommand(t=now, engaged=cmd.engaged, steer_effort=steer_effort,
                                           drive_effort=drive_effort))

        self.bus.publish("dbw/reference", DbwReference(
            t=now, steering_wheel_deg=reference.steering_wheel_angle_deg,
            wheel_speed_deg_s=reference.wheel_speed_deg_s, v=cmd.v, kappa=cmd.kappa))
        if can is not None:
            wheel_speed_deg_s = math.degrees(can.wheel_speed_rad_s)
            measured = self.conversion.to_speed_curvature_deg(can.steering_wheel_deg, wheel_speed_deg_s)
            self.bus.publish("dbw/measure", DbwMeasure(
                t=now, steering_wheel_deg=can.steering_wheel_deg, wheel_speed_deg_s=wheel_speed_deg_s,
                v=measured.v, kappa=measured.kappa))
        self.bus.publish("dbw/car_state", CarState(
            t=now, mode=DriveMode(self.core.mode.value), engaged=cmd.engaged,
            watchdog_tripped=cmd.watchdog_tripped, setpoint_age_s=cmd.setpoint_age_s,
            v_command=cmd.v, kappa_command=cmd.kappa, speed_mps=measured_speed,
            steering_wheel_deg=measured_angle, reason=cmd.reason))


def main() -> None:
    run_node(DbwBridge)


if __name__ == "__main__":
    main()
