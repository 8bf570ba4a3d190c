"""The simulated shuttle behind its wires (`ares run --wire`): the same plant, road and sensors as
ares.sim.simulator_node, but what a real shuttle's devices would send goes out in their formats,
to the devices of `vehicle_io`, for the drivers to read:

- the GNSS receiver's NMEA to a pseudo-terminal (ares.sim.nmea_wire), read as a serial port;
- the CAN frames of the drive-by-wire board, the body and the IMU (ares/core/wire/ares.dbc) on a
  python-can bus (udp_multicast here, socketcan on a vehicle), from which it also takes the
  bridge's efforts and the mission's body commands.

Its NMEA times are the stack clock's calendar time (`clock.utc`), so the GNSS driver stamps each
epoch with the time it was measured, as it would against a real receiver's UTC. The truth
(sim/truth), the driver service (sim/driver) and the clock stay on the bus: they are the
simulation's, not the vehicle's.
"""

from __future__ import annotations

from ares.core.messages import ActuatorCommand, BodyCommand
from ares.sim.can_wire import SimCanPort
from ares.sim.nmea_wire import NmeaPty
from ares.sim.simulator_node import Simulator


class WireSimulator(Simulator):
    """The simulated shuttle speaking NMEA and CAN to the drivers instead of the bus (--wire)."""

    # what the vehicle's devices carry leaves the bus: the drivers publish it
    gnss = imu = can = panel = body_state = None
    actuators = body_command = None
    wire_inputs = ("wire/can",)
    wire_outputs = ("wire/gnss", "wire/can")

    def setup(self) -> None:
        super().setup()
        io = self.core.vehicle_io
        if io.gnss is None or io.gnss.source != "serial" or not io.gnss.device:
            raise RuntimeError("the wire simulator writes its NMEA to a serial device: vehicle_io.gnss.device")
        if io.can is None:
            raise RuntimeError("the wire simulator needs a CAN bus: vehicle_io.can")
        # the receiver's UTC is the stack clock's calendar time
        self.sensors.gnss.time_of_day0 = self.clock.utc_epoch % 86400.0
        self.pty = NmeaPty(io.gnss.device)
        self.can_port = SimCanPort(io.can)
        self._command: tuple[float, ActuatorCommand] | None = None
        self._body_pending: list[BodyCommand] = []
        self._actuator_timeout_s = self.params.actuator_timeout_s

    def teardown(self) -> None:
        for close in (getattr(self, "pty", None), getattr(self, "can_port", None)):
            if close is not None:
                close.close()
        super().teardown()

    def _send(self, what: str, msg) -> None:
        if what == "gnss":
            self.pty.write(msg.sentences)
        elif what == "can":
            self.can_port.send_can(msg)
        elif what == "imu":
            self.can_port.send_imu(msg)
        elif what == "body":
            self.can_port.send_body(msg)
        else:
            self.can_port.send_panel(msg)

    def _actuator_command(self, t: float) -> ActuatorCommand | None:
        commands, bodies = self.can_port.poll(t)
        if commands:
            self._command = (t, commands[-1])
        self._body_pending.extend(bodies)
        if self._command is None or t - self._command[0] > self._actuator_timeout_s:
            return None  # the board's watchdog: no frame for the timeout
        return self._command[1]

    def _body_commands(self) -> list[BodyCommand]:
        pending, self._body_pending = self._body_pending, []
        return pending
