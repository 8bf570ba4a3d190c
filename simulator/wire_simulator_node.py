"""The simulated shuttle behind its wires (`ares run --wire`): the same plant, road and sensors as
simulator.simulator_node, but what a real shuttle's devices would send goes out in their formats,
to the devices of `vehicle_io`, for the drivers to read:

- the GNSS receiver's NMEA to a pseudo-terminal (simulator.nmea_wire), read as a serial port;
- the CAN frames of the drive-by-wire board, the body and the IMU (ares/core/wire/ares.dbc) on a
  python-can bus (udp_multicast here, socketcan on a vehicle), from which it also takes the
  bridge's efforts and the mission's body commands;
- the RTK corrections (simulator/base_station.py): a base station's RTCM served by a real NTRIP
  caster (RTKLIB's str2str), behind a 4G relay that is cut in the tour's `no_4g` zones, at the
  address of `vehicle_io.ntrip`; the receiver takes the frames the GNSS driver writes to its
  port, and its fix follows their age (simulator/corrections.py).

Its NMEA times are the stack clock's calendar time (`clock.utc`), so the GNSS driver stamps each
epoch with the time it was measured, as it would against a real receiver's UTC. The truth
(sim/truth), the driver service (sim/driver) and the clock stay on the bus: they are the
simulation's, not the vehicle's.
"""

from __future__ import annotations

from ares.core.localhost import free_port
from ares.core.messages import ActuatorCommand, BodyCommand
from ares.core.wire.rtcm import RtcmStream
from simulator.base_station import CASTER, BaseStation, ModemRelay
from simulator.can_wire import SimCanPort
from simulator.nmea_wire import NmeaPty
from simulator.simulator_node import Simulator


class WireSimulator(Simulator):
    """The simulated shuttle speaking NMEA and CAN to the drivers instead of the bus (--wire)."""

    # what the vehicle's devices carry leaves the bus: the drivers publish it (the corrections' state: the NTRIP client)
    gnss = imu = can = panel = body_state = corrections = None
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
        self.rtcm = RtcmStream()
        # the receiver's corrections come as RTCM on its port only; the 4G model now cuts the relay
        self.cellular = self.sensors.gnss.link
        self.sensors.gnss.link = None
        self.base: BaseStation | None = None
        self.modem: ModemRelay | None = None
        if io.ntrip is not None:
            caster_port = free_port()
            # its stderr is a status line a second: not for the run's logs
            self.base = BaseStation(caster_port, io.ntrip.mountpoint, io.ntrip.user or "", io.ntrip.password or "")
            if not self.base.ready():
                raise RuntimeError(f"the NTRIP caster ({CASTER}) did not start on port {caster_port}")
            self.modem = ModemRelay(io.ntrip.port, ("127.0.0.1", caster_port))
            self.periods["base"] = 1.0 / self.params.gnss.corrections.rate_hz
            self.next_due["base"] = self.clock.now()
            self.log.info("corrections: %s on port %d, behind the 4G relay on %d", CASTER, caster_port, io.ntrip.port)
        self._command: tuple[float, ActuatorCommand] | None = None
        self._body_pending: list[BodyCommand] = []
        self._actuator_timeout_s = self.params.actuator_timeout_s

    def teardown(self) -> None:
        for close in (
            getattr(self, "pty", None),
            getattr(self, "can_port", None),
            getattr(self, "modem", None),
            getattr(self, "base", None),
        ):
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

    def _publish_sensors(self) -> None:
        st = self.plant.state
        t = st.t
        frames = self.rtcm.feed(self.pty.read())  # the corrections the driver wrote to the port
        if frames:
            self.sensors.gnss.receiver.received(t, len(frames))
        if self.modem is not None and self.base is not None:
            assert self.cellular is not None  # the plant's 4G model, kept for the relay
            self.cellular.faults = self.sensors.gnss.faults
            self.modem.set_up(self.cellular.up(st.s, t))
            if self._due("base"):
                self.base.send()
            self.modem.poll()
        super()._publish_sensors()

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
