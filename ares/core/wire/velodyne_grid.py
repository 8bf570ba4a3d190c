"""A Velodyne's sampling grid as its decoder places points (ares/core/cloud_grid.Grid): a return is
a laser, an azimuth in 0.01° and a raw distance in the calibration's resolution, placed by the
calibration with the decoder's own arithmetic (velodyne._place, float64 then float32), so the
clouds the driver publishes are found again, point by point, as the integers their packets held.

The ring a cloud carries is the laser's rank by vertical angle (Calibration.ring); the grid's rings
are those. The nearest integers of a point invert the calibration's model without its distance
and horizontal-offset corrections (what a VLP-16, an HDL-32E or a VLP-32C has); a factory-
calibrated HDL-64E's points mostly fail the check and are then stored as they travelled.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ares.core.wire import velodyne
from ares.core.wire.velodyne import Calibration

_STEP_RAD = np.radians(0.01)
_TURN = 36000
_MAX_RAW = 65535
# the calibration's per-laser arrays, as a recording's channel describes them
CORRECTIONS = (
    "rot_correction", "vert_correction", "dist_correction", "dist_correction_x", "dist_correction_y",
    "vert_offset", "horiz_offset",
)  # fmt: skip


@dataclass(frozen=True)
class VelodyneGrid:
    calibration: Calibration
    laser_of_ring: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        laser = np.empty(self.calibration.lasers, dtype=np.int64)
        laser[self.calibration.ring] = np.arange(self.calibration.lasers)
        object.__setattr__(self, "laser_of_ring", laser)

    @property
    def rings(self) -> int:
        return self.calibration.lasers

    def place(
        self, ring: np.ndarray, azimuth: np.ndarray, range_: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        laser = self.laser_of_ring[ring]
        return velodyne._place(self.calibration, range_.astype(np.uint16), azimuth.astype(np.int64), laser)

    def nearest(self, x: np.ndarray, y: np.ndarray, z: np.ndarray, ring: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        cal, laser = self.calibration, self.laser_of_ring[ring]
        x64, y64 = x.astype(np.float64), y.astype(np.float64)
        # the ROS frame: Velodyne's azimuth turns clockwise (y = -sin), less the laser's rotation
        turned = np.arctan2(-y64, x64) + cal.rot_correction[laser]
        azimuth = np.mod(np.rint(turned / _STEP_RAD).astype(np.int64), _TURN)
        cos_v = cal.trig["cos_vert"][laser]
        d = np.hypot(x64, y64) / np.where(cos_v > 1e-6, cos_v, 1.0)
        raw = np.clip(np.rint(d / cal.distance_resolution), 0, _MAX_RAW)
        return azimuth.astype(np.uint16), raw.astype(np.uint16)

    def describe(self) -> dict[str, Any]:
        cal = self.calibration
        return {
            "kind": "velodyne",
            "model": cal.model,
            "distance_resolution": cal.distance_resolution,
            **{name: getattr(cal, name).tolist() for name in CORRECTIONS},
        }

    @classmethod
    def from_description(cls, described: dict[str, Any]) -> VelodyneGrid:
        arrays = {name: np.asarray(described[name], dtype=np.float64) for name in CORRECTIONS}
        return cls(
            Calibration(
                model=str(described["model"]),
                distance_resolution=float(described["distance_resolution"]),
                path="(a recording's channel)",
                **arrays,
            )
        )
