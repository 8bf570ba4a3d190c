"""The simulated vehicle's side of the CAN bus (`ares run --wire`): what the drive-by-wire board,
the body and the IMU would send, as the frames of ares/core/wire/ares.dbc, and the computer's
frames (the bridge's efforts, the body commands) taken back.

The WireSimulator (simulator/wire_simulator_node.py) calls `send_can`, `send_imu`, `send_panel` and
`send_body` where the plain simulator publishes on the bus, and `poll(t)` each physics step for the
commands. It opens the same `CanDevice` as the CAN driver (udp_multicast in simulation, where the
group loops its own frames back: the decoder skips them as "own direction").
"""

from __future__ import annotations

import logging
import time
from collections import Counter

import can

from ares.core.config.vehicle_io import CanDevice
from ares.core.messages import ActuatorCommand, BodyCommand, BodyState, CanFrame, Imu, PanelEvent
from ares.core.schema import Msg
from ares.core.wire.can_frames import UNDECODABLE, CanCodec, CanDecoder, CanEncoder, open_can_bus

log = logging.getLogger("sim.can_wire")
MAX_FRAMES_PER_POLL = 10_000  # a flooded group cannot hold the simulator's step


class SimCanPort:
    """The vehicle's CAN nodes (board, body, IMU) on one python-can bus."""

    def __init__(self, device: CanDevice):
        self.device = device
        self.codec = CanCodec.load(device.dbc)
        self.encoder = CanEncoder(self.codec)
        self.decoder = CanDecoder(self.codec, "vehicle")
        self.bus = open_can_bus(device, receive_own=False)
        self.sent = 0  # frames
        self.received = 0  # frames read, own ones included
        self.lost = 0  # the computer's frames missing (counter gaps)
        self.refused: Counter[str] = Counter()  # by cause
        self.send_failures: Counter[str] = Counter()

    # ---- the vehicle's frames -------------------------------------------------------------------
    def send_can(self, msg: CanFrame) -> None:
        self._send(msg)

    def send_imu(self, msg: Imu) -> None:
        self._send(msg)

    def send_panel(self, msg: PanelEvent) -> None:
        self._send(msg)

    def send_body(self, msg: BodyState) -> None:
        self._send(msg)

    def _send(self, msg: Msg) -> None:
        for frame in self.encoder.encode(msg, time.time()):
            try:
                self.bus.send(frame)
            except (can.CanError, OSError) as exc:  # the simulated board goes on: the driver sees the gap
                cause = type(exc).__name__
                self.send_failures[cause] += 1
                if self.send_failures[cause] == 1:
                    log.warning("CAN send failed (%s): %s", cause, exc)
                continue
            self.sent += 1

    # ---- the computer's frames ------------------------------------------------------------------
    def poll(self, t: float) -> tuple[list[ActuatorCommand], list[BodyCommand]]:
        """Every frame waiting, without blocking: the commands they carry, stamped `t`."""
        commands: list[ActuatorCommand] = []
        bodies: list[BodyCommand] = []
        for _ in range(MAX_FRAMES_PER_POLL):
            try:
                frame = self.bus.recv(timeout=0)
            except can.CanOperationError as exc:
                if isinstance(exc.__cause__, OSError):
                    raise  # the simulator's own bus is gone: nothing to simulate against
                self.received += 1
                self.refused[UNDECODABLE] += 1  # a datagram on the group that is no frame
                continue
            if frame is None:
                break
            self.received += 1
            decoded = self.decoder.decode(frame, t)
            self.lost += decoded.lost
            if decoded.refused is not None:
                self.refused[decoded.refused] += 1
                if self.refused[decoded.refused] == 1:
                    log.warning("CAN frame refused (%s): %s", decoded.refused, decoded.detail)
            elif isinstance(decoded.message, ActuatorCommand):
                commands.append(decoded.message)
            elif isinstance(decoded.message, BodyCommand):
                bodies.append(decoded.message)
        return commands, bodies

    @property
    def saturated(self) -> Counter[str]:
        """Values beyond their signal's range, sent at its limit, by "Frame.Signal"."""
        return self.encoder.saturated

    def close(self) -> None:
        self.bus.shutdown()
