"""A Velodyne's packets on the bus, and back into the clouds the driver made of them.

The driver (drivers/velodyne_node.py) gives each sensor's packets to a RotationAssembler and
publishes each whole rotation as `rotation_cloud` makes it. Each step it also publishes the
packets it gave the assembler that step, in their order, with their receive times
(`packets_message`), and whether it then finished the rotation under way because the stream
stopped. A recording can keep these packets in place of the clouds (raw packets are what a
Velodyne sends: 1,206 bytes for 384 returns): `PacketDecoder` gives them to an assembler built as
the driver's is and makes the very clouds the driver published, point for point and stamp for
stamp (tests/test_velodyne_packets.py checks it on a real VLP-16 capture).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence

import numpy as np

from ares.core.config.vehicle_io import VelodyneDevice
from ares.core.driver import device_stamp
from ares.core.messages import LidarPackets, PointCloud
from ares.core.wire.velodyne import HOUR_US, Rotation, RotationAssembler, load_calibration

HOUR_S = HOUR_US / 1e6


def rotation_cloud(sensor: str, rotation: Rotation, now: float, epoch: float) -> PointCloud:
    """A rotation as the driver publishes it at stack time `now`: stamped with its first packet's
    time by the stamp rule (`epoch`: the calendar time of stack time 0 its packets' times are read by)."""
    points = rotation.points
    return PointCloud(
        t=device_stamp(now, epoch, rotation.timestamp_us / 1e6, HOUR_S),
        sensor=sensor,
        frame=f"lidar/{sensor}",
        x=points.x,
        y=points.y,
        z=points.z,
        intensity=points.intensity,
        ring=points.ring,
    )


def packets_message(
    t: float, sensor: str, epoch: float, packets: Sequence[tuple[bytes, float]], flushed: bool = False
) -> LidarPackets:
    """One step's packets (bytes, wall receive time), in the order the assembler had them."""
    sizes = np.fromiter((len(data) for data, _ in packets), dtype="<u2", count=len(packets))
    return LidarPackets(
        t=t,
        sensor=sensor,
        epoch=epoch,
        flushed=flushed,
        sizes=sizes,
        received=np.fromiter((wall for _, wall in packets), dtype="<f8", count=len(packets)),
        data=np.frombuffer(b"".join(data for data, _ in packets), dtype=np.uint8),
    )


def packets_of(message: LidarPackets) -> Iterator[tuple[bytes, float]]:
    """The message's packets again: (bytes, wall receive time)."""
    data = message.data.tobytes()
    start = 0
    for size, wall in zip(message.sizes.tolist(), message.received.tolist(), strict=True):
        yield data[start : start + size], wall
        start += size


def assembler_for(device: VelodyneDevice, truncated_below_deg: float) -> RotationAssembler:
    """The assembler of a sensor as `vehicle_io` describes it: the driver's, and a replay's."""
    return RotationAssembler(
        load_calibration(device.model, device.calibration),
        device.rate_hz,
        truncated_below_deg,
        fov_deg=device.fov_deg,
    )


class PacketDecoder:
    """One sensor's recorded packets in, the clouds the driver published from them out."""

    def __init__(self, sensor: str, device: VelodyneDevice, truncated_below_deg: float):
        self.sensor = sensor
        self.assembler = assembler_for(device, truncated_below_deg)

    def feed(self, message: LidarPackets) -> list[PointCloud]:
        """The clouds the driver published in the step that sent `message` (truncated rotations it
        counted and left out)."""
        rotations: list[Rotation] = []
        for data, wall in packets_of(message):
            rotations += self.assembler.add(data, wall)
        if message.flushed:
            rotations += self.assembler.flush()
        return [rotation_cloud(self.sensor, r, message.t, message.epoch) for r in rotations if not r.truncated]
