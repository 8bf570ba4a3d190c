"""The simulated LiDARs behind the wire (`ares run --wire`): Velodyne UDP packets instead of clouds.

The same world, obstacles, faults and sensors as simulator/lidar_node.py, but each sweep leaves
as the data packets of one rotation (simulator/velodyne_wire.py), sent by UDP to 127.0.0.1 at the
port of the sensor's `vehicle_io.lidars` device, where the LiDAR driver (drivers/velodyne_node.py)
reads them and publishes lidar/<name>/points. A sweep is cast from one pose, so its packets carry
the sweep's time: the first packet's timestamp is the sweep's stamp (µs past the UTC hour of the
clock's utc_epoch + stack time), the others a packet period apart; the driver's stamp rule gives
the stamp back exactly. sim/world (the obstacles as they are, for evaluation) stays on the bus.
"""

from __future__ import annotations

import math
import socket

import numpy as np

from ares.core.messages import VehicleTruth
from simulator.lidar import SimulatedLidar
from simulator.lidar_node import LidarSimulator
from simulator.velodyne_wire import WireLidar

SEND_BUFFER = 4 * 1024 * 1024


class SteadySpin:
    """A sensor on the wire spins without pause: its rotations follow one another exactly a period
    apart (on the grid of its first), whatever the loop's jitter and whichever truth message (at
    most one truth period old) was the latest."""

    def __init__(self, rate_hz: float):
        self.period = 1.0 / rate_hz
        self.start: float | None = None  # the first rotation's time

    def pose(self, now: float, truth: VehicleTruth) -> VehicleTruth:
        """The pose at the time of the rotation due at `now`, moved from the truth by its speed and
        yaw rate."""
        if self.start is None:
            self.start = now
        t = self.start + round((now - self.start) / self.period) * self.period
        dt = t - truth.t
        yaw = truth.yaw + 0.5 * truth.yaw_rate * dt  # along the arc's mean heading
        return truth.model_copy(
            update={
                "t": t,
                "x": truth.x + truth.v * math.cos(yaw) * dt,
                "y": truth.y + truth.v * math.sin(yaw) * dt,
                "yaw": truth.yaw + truth.yaw_rate * dt,
            }
        )


class WireLidarSimulator(LidarSimulator):
    """Three simulated LiDARs sending Velodyne data packets to the driver's UDP ports."""

    wire_outputs = ("wire/lidar",)
    roof = None  # type: ignore[assignment]  # the driver publishes the clouds
    front_left = None  # type: ignore[assignment]
    front_right = None  # type: ignore[assignment]

    def make_sensors(self) -> dict[str, SimulatedLidar]:
        devices = self.core.vehicle_io.lidars
        self.wire_sensors: dict[str, WireLidar] = {}
        for i, (name, mount) in enumerate(self.vehicle.lidars.items()):
            device = devices.get(name)
            if device is None:
                self.log.warning("lidar %s has no vehicle_io device: not simulated behind the wire", name)
                continue
            rng = np.random.default_rng([self.params.seed, i])
            self.wire_sensors[name] = WireLidar(name, mount, self.vehicle, self.params, rng, device)
        return {name: wired.sim for name, wired in self.wire_sensors.items()}  # faults cover these

    def setup(self) -> None:
        super().setup()
        self.spin = SteadySpin(self.params.rate_hz)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, SEND_BUFFER)
        self.send_errors = 0

    def teardown(self) -> None:
        self.sock.close()

    def sweep_pose(self, now: float, truth: VehicleTruth) -> VehicleTruth:
        """The pose at the rotation's own time (SteadySpin)."""
        return self.spin.pose(now, truth)

    def send_sweeps(self, stamp: float, rotation: np.ndarray, position: np.ndarray, obstacle_scene) -> None:
        """Each sensor's sweep as the packets of one rotation, to its UDP port."""
        first_us = round(((self.clock.utc_epoch + stamp) % 3600.0) * 1e6)
        for wired in self.wire_sensors.values():
            packets = wired.packets(
                self.world.scene, rotation, position, obstacle_scene, self.world.material_of, first_us
            )
            self._send(packets, wired.device.port)

    def _send(self, packets: list[bytes], port: int) -> None:
        for packet in packets:
            try:
                self.sock.sendto(packet, ("127.0.0.1", port))
            except OSError as exc:  # a full buffer, a refused port: the packet is lost, as on a wire
                self.send_errors += 1
                if self.send_errors == 1 or self.send_errors % 1000 == 0:
                    self.log.warning(
                        "lidar packets to udp port %d not sent (%d so far): %s", port, self.send_errors, exc
                    )
