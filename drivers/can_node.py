"""The CAN driver: the drive-by-wire board's, the body's and the IMU's frames (ares/core/wire/ares.dbc)
to the bus, and the bridge's efforts and the mission's body commands to the vehicle.

It reads `vehicle_io.can` through python-can (socketcan on a vehicle, udp_multicast with `ares run
--wire`) without blocking: each step sends what the bridge and the mission manager sent since the
last one, then reads every frame waiting, decodes it (ares.core.wire.can_frames) and publishes
what the simulator publishes in simulation: sensors/can and sensors/imu (each sample assembled from
its three frames), vehicle/panel and body/state, stamped with the step's time.

The board's watchdog (1 s without a setpoint: stop, DBW paper section 4.5) must see the silence when
the bridge stops: so the driver sends each actuator command it receives once, the newest of a step
only, and never repeats an old one. Frames lost (counter gaps) and refused (by cause) are counted
on drivers/status; a bus that fails is reopened every `reopen_s`, one that goes silent too.
"""

from __future__ import annotations

import time
from typing import cast

import can

from ares.core.bus import Publisher
from ares.core.clock import Clock, WallClock
from ares.core.config import Params, param
from ares.core.driver import DriverNode
from ares.core.messages import BodyState, CanFrame, Imu, PanelEvent
from ares.core.node import Input, Output
from ares.core.schema import Msg
from ares.core.wire.can_frames import (
    OWN_DIRECTION,
    UNDECODABLE,
    CanCodec,
    CanDecoder,
    CanEncoder,
    Decoded,
    open_can_bus,
)

_PACKAGED = CanCodec.load()  # the packaged DBC: the expected output rates' defaults
PLAUSIBLE_CLOCK_S = 60.0  # a frame's timestamp further than this from time.time() is not a wall time


class CanDriverParams(Params):
    rate_hz: float = param(50.0, "loop rate: commands sent and frames read every step", unit="Hz", gt=0)
    reopen_s: float = param(0.5, "a bus that failed to open or read is tried again this often (wall)", unit="s", gt=0)
    silent_after_s: float = param(
        1.0, "no frame from the vehicle for this long (wall): the bus counts as silent, and is reopened", unit="s", gt=0
    )
    max_frames_per_step: int = param(
        5000, "frames read in one step at most, so a flooded bus cannot hold the loop", gt=0
    )
    can_hz: float = param(
        _PACKAGED.rate_hz("VehicleSpeed"), "sensors/can's rate: the vehicle's VehicleSpeed frames", unit="Hz", gt=0
    )
    imu_hz: float = param(_PACKAGED.rate_hz("Imu_Accel"), "sensors/imu's rate: the IMU's frames", unit="Hz", gt=0)
    body_hz: float = param(_PACKAGED.rate_hz("Body_State"), "body/state's rate: the body's frames", unit="Hz", gt=0)


class CanDriver(DriverNode):
    """CAN driver: the vehicle's frames to sensors/can, sensors/imu, vehicle/panel, body/state; the
    bridge's efforts and the body commands to the vehicle."""

    name = "can_driver"
    Params = CanDriverParams
    params: CanDriverParams
    wire_inputs = ("wire/can",)
    wire_outputs = ("wire/can",)  # the commands to the board and the body

    actuators = Input("dbw/actuators", queue=16, doc="the bridge's efforts: each sent once, as a DBW_Command frame")
    body_command = Input("body/command", queue=64, doc="the mission manager's demands: each sent as a Body_Command")
    can_out = Output("sensors/can", rate="can_hz", doc="SteeringWheel + Pedals + VehicleSpeed frames of one sample")
    imu_out = Output("sensors/imu", rate="imu_hz", doc="Imu_Attitude + Imu_Gyro + Imu_Accel frames of one sample")
    panel_out = Output("vehicle/panel", doc="the driver's actions the board reports (PanelEvent frames)")
    body_out = Output("body/state", rate="body_hz", doc="the body's Body_State frames")

    def __init__(self, *args, wall: Clock | None = None, **kwargs) -> None:  # type: ignore[no-untyped-def]
        """`wall`: the computer's clock, by which the bus's health is judged (silence, reopening: real
        seconds, whatever the stack's clock does); a test gives a manual one."""
        super().__init__(*args, **kwargs)
        self.wall: Clock = wall if wall is not None else WallClock()

    def setup(self) -> None:
        device = self.core.vehicle_io.can
        if device is None:
            raise RuntimeError("the CAN driver has no device: set vehicle_io.can (ares run --vehicle-io FILE)")
        self.device = device
        self.codec = CanCodec.load(device.dbc)
        self.encoder = CanEncoder(self.codec)
        self.decoder = CanDecoder(self.codec, "computer")
        self.counters = self.wire("can")
        self.sent: dict[str, int] = {}
        # each a plain topic's publisher (not a family of keys): what the decoder gives goes out as it is
        self._outputs: dict[type[Msg], Publisher[Msg]] = {
            CanFrame: cast(Publisher[Msg], self.can_out),
            Imu: cast(Publisher[Msg], self.imu_out),
            PanelEvent: cast(Publisher[Msg], self.panel_out),
            BodyState: cast(Publisher[Msg], self.body_out),
        }
        self._bus: can.BusABC | None = None
        self._retry_at = -float("inf")  # times of self.wall: the next open attempt,
        self._opened_at = -float("inf")  # the bus's last opening,
        self._heard_at = -float("inf")  # the last frame from the vehicle
        self._open(self.wall.now())

    def teardown(self) -> None:
        self._close()

    def step(self, now: float) -> None:
        wall = self.wall.now()
        if self._bus is None and wall >= self._retry_at:
            self._open(wall)
        self._send_commands()
        if self._bus is not None:
            self._read(now)
        silence = self.params.silent_after_s
        if self._bus is not None and min(wall - self._heard_at, wall - self._opened_at) > silence:
            # a bus opened this long ago on which the vehicle says nothing: open it afresh, at once
            # (the commands keep going out), and give it the same time to speak
            self.counters.problem("silent", f"no frame from the vehicle for {silence:g} s: reopened")
            self._close()
            self._open(wall)
        self.counters.connected = self._bus is not None and self.wall.now() - self._heard_at <= silence
        sent = ", ".join(f"{name} {n}" for name, n in sorted(self.sent.items()))
        self.counters.detail = f"{self.device.interface} {self.device.channel}" + (f"; sent {sent}" if sent else "")
        self.report(now)

    # ---- the bus ----------------------------------------------------------------------------------
    def _open(self, wall: float) -> None:
        try:
            self._bus = open_can_bus(self.device)
        except (can.CanError, OSError, ValueError) as exc:  # absent interface, bad group, unknown interface
            self._bus = None
            self._retry_at = wall + self.params.reopen_s
            self.counters.problem("cannot open", f"{self.device.interface} {self.device.channel}: {exc}")
            return
        self._opened_at = wall

    def _close(self) -> None:
        if self._bus is not None:
            try:
                self._bus.shutdown()
            except (can.CanError, OSError):
                pass  # it is gone already
            self._bus = None

    def _lost_bus(self, exc: Exception) -> None:
        self.counters.problem("bus failed", f"{type(exc).__name__}: {exc}")
        self._close()
        self._retry_at = self.wall.now() + self.params.reopen_s

    # ---- to the vehicle ---------------------------------------------------------------------------
    def _send_commands(self) -> None:
        commands = [msg for _, msg in self.actuators.drain()]
        bodies = [msg for _, msg in self.body_command.drain()]
        if len(commands) > 1:  # a late step: only the newest effort still means anything to the board
            self.counters.skip("superseded command", len(commands) - 1)
        pending = commands[-1:] + bodies
        if not pending:
            return
        if self._bus is None:
            self.counters.skip("commands while disconnected", len(pending))
            return
        for msg in pending:
            for frame in self.encoder.encode(msg, time.time()):
                try:
                    self._bus.send(frame, timeout=0)
                except (can.CanError, OSError) as exc:  # a full transmit queue (no node acknowledges), a bus gone
                    self.counters.problem("send failed", f"{type(exc).__name__}: {exc}")
                    self.counters.skip("commands not sent")
                    continue
                name = self.codec.by_id[frame.arbitration_id].name
                self.sent[name] = self.sent.get(name, 0) + 1

    # ---- from the vehicle -------------------------------------------------------------------------
    def _read(self, now: float) -> None:
        assert self._bus is not None
        for _ in range(self.params.max_frames_per_step):
            try:
                frame = self._bus.recv(timeout=0)
            except can.CanOperationError as exc:
                if isinstance(exc.__cause__, OSError):
                    self._lost_bus(exc)
                    return
                # a datagram on the group that is no frame (udp_multicast): the bus itself is fine
                self.counters.got()
                self.counters.refuse(UNDECODABLE, str(exc))
                continue
            except (can.CanError, OSError, ValueError) as exc:  # the interface went down, the socket closed
                self._lost_bus(exc)
                return
            if frame is None:
                return
            self._take(frame, now)

    def _take(self, frame: can.Message, now: float) -> None:
        counters = self.counters
        counters.got()
        decoded: Decoded = self.decoder.decode(frame, now)
        if decoded.lost:
            counters.missing(decoded.lost, f"counter gap on {decoded.frame}")
        if decoded.refused is not None:
            counters.refuse(decoded.refused, decoded.detail)
            return  # garbage is not the vehicle speaking: a bus of only garbage goes silent
        if decoded.skipped != OWN_DIRECTION:
            self._heard_at = self.wall.now()
        if decoded.skipped is not None:
            counters.skip(decoded.skipped)
            return
        msg = decoded.message
        if msg is None:
            return  # a part of a sample: its closing frame publishes it
        output = self._outputs.get(type(msg))
        if output is None:
            counters.skip(f"{decoded.frame} not read by ARES")
            return
        output.put(msg)
        counters.put(read_wall=_wall_time(frame))


def _wall_time(frame: can.Message) -> float:
    """When the frame arrived (wall): the kernel's timestamp, unless the interface keeps its own clock."""
    now = time.time()
    return frame.timestamp if abs(now - frame.timestamp) < PLAUSIBLE_CLOCK_S else now
