"""A simulated LiDAR behind the Velodyne wire: one sweep cast along a firing pattern, sent as packets.

The sensor casts exactly the rays the decoder will reconstruct (ares/core/wire/velodyne.py,
`firing_pattern`, from the unit's calibration: the driver's), so that decoding the packets gives
back the simulated points within the format's quantisation (2 mm in range, 0.01° in azimuth).
Each kept point's range and intensity go in its (firing, laser) slot; a ghost (a spurious
near-field return, simulator/lidar.py) goes to the free slot of its ring nearest its azimuth.
With `azimuth_decimation` n, only every n-th firing is cast; the others are sent as no return.

The device's model decides the rays and the packets (any of the decoder's models: VLP-16,
HDL-32E, VLP-32C, HDL-64E, VLS-128, by their default or given calibration); the mount's sensor
class keeps its range, its noise and its place on the vehicle. So a shuttle whose roof carries a
VLS-128 is simulated by giving that LiDAR `model: VLS-128` in `vehicle_io`.
"""

from __future__ import annotations

import numpy as np

from ares.core.config import LidarMount, VehicleProfile
from ares.core.config.vehicle_io import VelodyneDevice
from ares.core.wire.velodyne import FiringPattern, encode_rotation, firing_pattern, load_calibration
from simulator.lidar import LidarSimParams, SimulatedLidar


class WireLidar:
    """One simulated sensor whose sweeps become Velodyne data packets."""

    def __init__(
        self,
        name: str,
        mount: LidarMount,
        vehicle: VehicleProfile,
        params: LidarSimParams,
        rng: np.random.Generator,
        device: VelodyneDevice,
        return_mode: str = "strongest",
    ):
        self.name = name
        self.device = device
        self.calibration = load_calibration(device.model, device.calibration)
        self.pattern: FiringPattern = firing_pattern(self.calibration, device.rate_hz, return_mode)
        self.fired = np.arange(0, self.pattern.firings, params.azimuth_decimation)
        lasers = self.pattern.lasers
        self.sim = SimulatedLidar(
            name,
            mount,
            vehicle,
            params,
            rng,
            directions=self.pattern.directions[self.fired].reshape(-1, 3),
            rings=np.tile(self.pattern.ring, len(self.fired)),
        )
        self._ring_lasers = {int(r): int(np.flatnonzero(self.pattern.ring == r)[0]) for r in range(lasers)}

    def slots(self, sweep) -> tuple[np.ndarray, np.ndarray]:
        """(distance, intensity), each (firings, lasers): the sweep's points in their slots."""
        pattern = self.pattern
        shape = (len(self.fired), pattern.lasers)
        distance = np.zeros(shape)
        intensity = np.zeros(shape)
        r = np.sqrt(sweep.x.astype(np.float64) ** 2 + sweep.y**2 + sweep.z**2)
        real = sweep.slot >= 0
        distance.flat[sweep.slot[real]] = r[real]
        intensity.flat[sweep.slot[real]] = sweep.intensity[real]
        for i in np.flatnonzero(~real):  # a few ghosts a sweep
            laser = self._ring_lasers[int(sweep.ring[i])]
            free = np.flatnonzero(distance[:, laser] == 0)
            if len(free) == 0:
                continue
            azimuth_cdeg = np.degrees(np.arctan2(-sweep.y[i], sweep.x[i])) * 100 % 36000  # Velodyne's: clockwise
            gap = np.abs(pattern.azimuth_cdeg[self.fired[free], laser] - azimuth_cdeg)
            nearest = free[np.argmin(np.minimum(gap, 36000 - gap))]
            distance[nearest, laser] = r[i]
            intensity[nearest, laser] = sweep.intensity[i]
        full_d = np.zeros((pattern.firings, pattern.lasers))
        full_i = np.zeros((pattern.firings, pattern.lasers))
        full_d[self.fired] = distance
        full_i[self.fired] = intensity
        return full_d, full_i

    def packets(
        self,
        world_scene,
        vehicle_rotation: np.ndarray,
        vehicle_position: np.ndarray,
        obstacles_scene,
        material_of,
        first_timestamp_us: int,
    ) -> list[bytes]:
        """One sweep from the vehicle's pose as the packets of one rotation, the first stamped
        `first_timestamp_us` (µs past the UTC hour) and the others a packet period apart."""
        sweep = self.sim.sweep(world_scene, vehicle_rotation, vehicle_position, obstacles_scene, material_of)
        if sweep.slot is None:  # blocked: no return at all (an empty sweep has no slots)
            distance = np.zeros((self.pattern.firings, self.pattern.lasers))
            intensity = distance
        else:
            distance, intensity = self.slots(sweep)
        return encode_rotation(
            self.calibration, self.pattern, distance, intensity, self.pattern.timestamps_us(first_timestamp_us)
        )
