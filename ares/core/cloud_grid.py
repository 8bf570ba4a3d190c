"""A spinning LiDAR's sampling grid: where its points can lie, and a point cloud as integers on it.

A spinning sensor measures a range along a laser (its ring, a fixed elevation) at an azimuth, and
reports both at a resolution: Velodyne's 0.01° in azimuth and 2 mm in range, an intensity byte. A
point of such a sensor is therefore three small integers and a byte, about 6 bytes against the
17 of float32 x, y, z, intensity and a ring byte. `place` turns the integers into the float32
points a cloud carries. The simulator places its points with it, as a real sensor's firmware
does; a recorder turns a cloud back into its integers (`to_grid`) and checks, point by point,
that placing them gives the very same float32 bits, so a cloud stored as integers comes back
exactly. A point off the grid is kept apart as float32: still exact, only larger.

A grid is anything that places integers and finds the nearest integers of a point (`Grid`):
`SensorGrid` below is the simulator's (its datasheet's elevations, float32 arithmetic); a Velodyne
driver's is its calibration with the decoder's own arithmetic (ares/core/wire/velodyne_grid.py),
so the clouds a driver decodes are stored as the integers of their packets.

    r = range · RANGE_UNIT_M,   x = r cos(el[ring]) cos(az),   y = r cos(el[ring]) sin(az),
    z = r sin(el[ring]),        az = azimuth · 2π / AZIMUTH_STEPS,   intensity = byte / 255
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cache
from typing import Any, Protocol

import numpy as np

AZIMUTH_STEPS = 36000  # 0.01°, as a Velodyne packet states its azimuth
AZIMUTH_UNIT_RAD = 2 * math.pi / AZIMUTH_STEPS
RANGE_UNIT_M = 0.002  # 2 mm, the HDL-64E's and the VLP-16's range resolution
MAX_RANGE_STEPS = 65535  # a u16: 131 m
INTENSITY_STEPS = 255
_INTENSITY_STEPS32 = np.float32(INTENSITY_STEPS)
_RANGE_UNIT = np.float32(RANGE_UNIT_M)


@cache
def _azimuth_table() -> tuple[np.ndarray, np.ndarray]:
    angle = np.arange(AZIMUTH_STEPS, dtype=np.float64) * AZIMUTH_UNIT_RAD
    return np.cos(angle).astype(np.float32), np.sin(angle).astype(np.float32)


class Grid(Protocol):
    """Where a sensor's points can lie: `rings` lasers, points placed from (ring, azimuth step,
    range step) as float32 x, y, z, and the nearest steps of a point (which `place` may or may not
    give back to the bit: to_grid checks)."""

    @property
    def rings(self) -> int: ...

    def place(
        self, ring: np.ndarray, azimuth: np.ndarray, range_: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...

    def nearest(
        self, x: np.ndarray, y: np.ndarray, z: np.ndarray, ring: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]: ...

    def describe(self) -> dict[str, Any]: ...


@dataclass(frozen=True)
class SensorGrid:
    """One sensor's lasers: elevations in degrees, ring 0 the lowest (the datasheet's order)."""

    elevations_deg: tuple[float, ...]
    cos_elevation: np.ndarray = field(init=False, repr=False, compare=False)
    sin_elevation: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        elevation = np.radians(np.asarray(self.elevations_deg, dtype=np.float64))
        object.__setattr__(self, "cos_elevation", np.cos(elevation).astype(np.float32))
        object.__setattr__(self, "sin_elevation", np.sin(elevation).astype(np.float32))

    @property
    def rings(self) -> int:
        return len(self.elevations_deg)

    def place(
        self, ring: np.ndarray, azimuth: np.ndarray, range_: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return place(self, ring, azimuth, range_)

    def nearest(self, x: np.ndarray, y: np.ndarray, z: np.ndarray, ring: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        # float32 is enough to find the nearest step (errors ~1e-7 rad and ~10 µm against steps of
        # 1.7e-4 rad and 2 mm), and to_grid's check catches a point it would round the wrong way
        turns = np.arctan2(y, x)
        turns *= np.float32(1.0 / AZIMUTH_UNIT_RAD)
        np.rint(turns, out=turns)
        whole = turns.astype(np.int32)  # -18000 ... 18000
        whole[whole < 0] += AZIMUTH_STEPS
        whole[whole >= AZIMUTH_STEPS] -= AZIMUTH_STEPS
        r = np.square(x)
        r += np.square(y)
        r += np.square(z)
        np.sqrt(r, out=r)
        r *= np.float32(1.0 / RANGE_UNIT_M)
        np.rint(r, out=r)
        return whole.astype(np.uint16), np.clip(r, 0, MAX_RANGE_STEPS).astype(np.uint16)

    def describe(self) -> dict[str, Any]:
        return {"kind": "sensor", "elevations_deg": list(self.elevations_deg)}


def azimuth_steps(angle_rad: np.ndarray | float) -> np.ndarray:
    """An angle (any turn) to the nearest azimuth step, 0 ≤ step < AZIMUTH_STEPS."""
    steps = np.rint(np.asarray(angle_rad, dtype=np.float64) / AZIMUTH_UNIT_RAD).astype(np.int64)
    return np.mod(steps, AZIMUTH_STEPS).astype(np.uint16)


def range_steps(range_m: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(np.asarray(range_m, dtype=np.float64) / RANGE_UNIT_M), 0, MAX_RANGE_STEPS).astype(np.uint16)


def intensity_steps(intensity: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(np.asarray(intensity, dtype=np.float32) * INTENSITY_STEPS), 0, INTENSITY_STEPS).astype(
        np.uint8
    )


def place(
    grid: SensorGrid, ring: np.ndarray, azimuth: np.ndarray, range_: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """float32 x, y, z of points given by ring, azimuth step and range step."""
    cos_az, sin_az = _azimuth_table()
    r = range_.astype(np.float32)
    r *= _RANGE_UNIT
    across = r * np.take(grid.cos_elevation, ring)
    x = across * np.take(cos_az, azimuth)
    y = np.multiply(across, np.take(sin_az, azimuth), out=across)
    z = r * np.take(grid.sin_elevation, ring)
    return x, y, z


def intensity_of(steps: np.ndarray) -> np.ndarray:
    """The byte as 0..1 in float32, divided as a Velodyne decoder divides it."""
    out = steps.astype(np.float32)
    out /= _INTENSITY_STEPS32
    return out


@dataclass
class GridCloud:
    """A cloud on a sensor's grid: per point its ring, azimuth step, range step and intensity byte;
    the points that are not on the grid (`off`, their indices) kept as float32."""

    ring: np.ndarray  # u1
    azimuth: np.ndarray  # u2
    range: np.ndarray  # u2
    intensity: np.ndarray  # u1
    off: np.ndarray  # u4: indices of the points kept as they are
    off_xyzi: np.ndarray  # f4 (len(off), 4)

    @property
    def size(self) -> int:
        return len(self.ring)


def to_grid(
    grid: Grid, x: np.ndarray, y: np.ndarray, z: np.ndarray, intensity: np.ndarray, ring: np.ndarray
) -> GridCloud:
    """The cloud's integers on the grid, each point checked to place back to the same float32 bits."""
    ring = np.asarray(ring, dtype=np.uint8)
    x32, y32, z32 = (np.asarray(a, dtype=np.float32) for a in (x, y, z))
    i32 = np.asarray(intensity, dtype=np.float32)
    known_ring = ring < grid.rings
    safe_ring = np.where(known_ring, ring, 0).astype(np.uint8)
    azimuth, range_ = grid.nearest(x32, y32, z32, safe_ring)
    steps = intensity_steps(i32)
    px, py, pz = grid.place(safe_ring, azimuth, range_)
    same = known_ring & _same_bits(px, x32) & _same_bits(py, y32) & _same_bits(pz, z32)
    same &= _same_bits(intensity_of(steps), i32)
    off = np.flatnonzero(~same).astype(np.uint32)
    off_xyzi = np.stack([x32[off], y32[off], z32[off], i32[off]], axis=1) if len(off) else np.zeros((0, 4), np.float32)
    return GridCloud(ring=ring, azimuth=azimuth, range=range_, intensity=steps, off=off, off_xyzi=off_xyzi)


def from_grid(grid: Grid, cloud: GridCloud) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """float32 x, y, z, intensity of a GridCloud, exactly those to_grid was given."""
    safe_ring = np.where(cloud.ring < grid.rings, cloud.ring, 0).astype(np.uint8)
    x, y, z = grid.place(safe_ring, cloud.azimuth, cloud.range)
    intensity = intensity_of(cloud.intensity)
    if len(cloud.off):
        for column, values in zip((x, y, z, intensity), cloud.off_xyzi.T, strict=True):
            column[cloud.off] = values
    return x, y, z, intensity


def _same_bits(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    same: np.ndarray = a.view(np.uint32) == b.view(np.uint32)
    return same
