"""The stack's local frame: UTM in the origin's zone, minus the origin (x east, y north, z up).

Every process that turns positions on the Earth into the local frame or back uses this one
class: the GNSS node (fixes), the simulator (its receiver's sentences), the black box (records'
latitude and longitude), route import. Every position is projected in the origin's zone and
hemisphere, whatever its own: a drive across a zone boundary (or the equator) stays one
continuous frame — Transverse Mercator stays accurate to well under a millimetre per metre a
few tens of kilometres beyond its zone. `project` is strict in distance instead: a position
farther than `reach_km` from the origin is refused (FrameError "far from origin"), because a
receiver hundreds of kilometres from the site means a wrong fix or a wrong configuration.

`origin_at` makes the origin of a frame from a latitude, longitude and altitude (a route
recorded anywhere on Earth carries its own).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import utm

from ares.core.config import UtmOrigin


class FrameError(ValueError):
    """A position that has no place in the local frame; `reason` is a short word for counting."""

    def __init__(self, reason: str, message: str):
        super().__init__(message)
        self.reason = reason


@dataclass(frozen=True)
class Projected:
    """One position in UTM and in the local frame."""

    x: float
    y: float
    z: float | None  # None when the position came without an altitude
    easting: float
    northing: float
    zone: int
    hemisphere: str


def origin_at(
    lat: float,
    lon: float,
    altitude_m: float,
    reach_km: float | None = None,
    zone: int | None = None,
    hemisphere: str | None = None,
) -> UtmOrigin:
    """The origin of a local frame at a geodetic position, in that position's own UTM zone and
    hemisphere unless they are given."""
    northern = None if hemisphere is None else hemisphere == "N"
    try:
        easting, northing, own_zone, letter = utm.from_latlon(lat, lon, force_zone_number=zone, force_northern=northern)
    except (utm.error.OutOfRangeError, ValueError) as exc:
        raise FrameError("utm range", f"position {lat:.6f}, {lon:.6f} has no UTM coordinates: {exc}") from None
    if northern is None:
        northern = letter >= "N"
    extra = {} if reach_km is None else {"reach_km": reach_km}
    # to the millimetre: what a route file records is then the origin exactly
    return UtmOrigin(
        zone=own_zone,
        hemisphere="N" if northern else "S",
        easting=round(float(easting), 3),
        northing=round(float(northing), 3),
        altitude_m=round(float(altitude_m), 3),
        **extra,
    )


class LocalFrame:
    def __init__(self, origin: UtmOrigin):
        self.origin = origin
        self.zone = origin.zone
        self.northern = origin.hemisphere == "N"
        self.reach_m = origin.reach_km * 1000.0

    def project(self, lat: float, lon: float, altitude_m: float | None) -> Projected:
        """UTM (in the origin's zone) and local coordinates of a position; FrameError if it lies
        beyond the frame's reach or outside what UTM can express."""
        try:
            x, y = self.from_latlon_forced(lat, lon)
        except (utm.error.OutOfRangeError, ValueError) as exc:  # beyond UTM's 80 S .. 84 N, for instance
            raise FrameError("utm range", f"position {lat:.6f}, {lon:.6f} has no UTM coordinates: {exc}") from None
        o = self.origin
        easting, northing = o.easting + x, o.northing + y
        if not (math.isfinite(x) and math.isfinite(y)) or math.hypot(x, y) > self.reach_m:
            raise FrameError(
                "far from origin",
                f"position {lat:.6f}, {lon:.6f} lies "
                f"{math.hypot(x, y) / 1000.0:.0f} km from the site's origin "
                f"(reach {o.reach_km:g} km, origin_utm.reach_km)",
            )
        return Projected(
            x=x,
            y=y,
            z=None if altitude_m is None else altitude_m - o.altitude_m,
            easting=easting,
            northing=northing,
            zone=self.zone,
            hemisphere=o.hemisphere,
        )

    def to_latlon(self, x: float, y: float) -> tuple[float, float]:
        """Latitude and longitude of a local position; ValueError when it lies outside what UTM
        can express."""
        easting = self.origin.easting + x
        if not 0.0 < easting < 1_000_000.0:
            raise ValueError(f"easting {easting:.0f} m is outside what UTM can express")
        # not utm's strict check: a frame's positions may lie across its zone's edge or the equator
        lat, lon = utm.to_latlon(easting, self.origin.northing + y, self.zone, northern=self.northern, strict=False)
        if not -80.0 <= lat <= 84.0:
            raise ValueError(f"local position {x:.0f}, {y:.0f} lies beyond UTM's 80 S .. 84 N")
        return float(lat), float(lon)

    def from_latlon_forced(self, lat: float, lon: float) -> tuple[float, float]:
        """Local x, y of a position, in the origin's zone, at any distance."""
        e, n, _, _ = utm.from_latlon(lat, lon, force_zone_number=self.zone, force_northern=self.northern)
        return float(e - self.origin.easting), float(n - self.origin.northing)

    def utm_of(self, x: float, y: float) -> tuple[float, float]:
        return self.origin.easting + x, self.origin.northing + y
