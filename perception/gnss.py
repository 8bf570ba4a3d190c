"""From a validated GGA (and the GST of the same epoch, when the receiver sends one) to a fix in
UTM and in the stack's local frame (ARES §3.1: "NMEA GGA in, UTM out").

The local frame is UTM minus a configured origin (`gnss.origin_utm`, by default the
simulator's `sim.gnss.origin_utm`): x east, y north, z above the origin's altitude. Positions
are projected with the `utm` package, and its answer is checked: a fix whose natural UTM zone or
hemisphere differs from the origin's is refused (reason "utm zone") rather than forced into the
origin's zone, because a receiver hundreds of kilometres from the site means a wrong fix or a
wrong configuration, and either way the stack must not drive on it.

Variances: a GST's latitude / longitude / altitude standard deviations, squared (the receiver's
own estimate), else figures by fix quality from config — the paper's ≈ 5e-5 m² with RTK fixed
(quality 4) and ≈ 0.5 m² without corrections.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterable, Mapping

import utm

from ares import config
from ares.messages import GnssFix
from perception.nmea import Gga, Gst, NmeaError

RTK_FIXED = 4               # GGA fix quality of an RTK fixed solution


class GnssError(NmeaError):
    """A well-formed sentence whose fix cannot be used (e.g. outside the site's UTM zone)."""


@dataclass(frozen=True)
class Origin:
    """The local frame's origin in UTM."""
    zone: int
    northern: bool
    easting: float
    northing: float
    altitude_m: float

    @classmethod
    def from_config(cls, cfg: Mapping) -> "Origin":
        o = config.get(cfg, "gnss.origin_utm") or config.get(cfg, "sim.gnss.origin_utm")
        if not o:
            raise config.ConfigError("no local frame origin: set gnss.origin_utm (or sim.gnss.origin_utm)")
        return cls(zone=int(o["zone"]), northern=str(o.get("hemisphere", "N")).upper().startswith("N"),
                   easting=float(o["easting"]), northing=float(o["northing"]),
                   altitude_m=float(o.get("altitude_m", 0.0)))


@dataclass(frozen=True)
class Projected:
    """One position in UTM and in the local frame."""
    x: float
    y: float
    z: float
    easting: float
    northing: float
    zone: int
    hemisphere: str


class GnssProjector:
    """lat/lon/alt -> UTM -> local frame, and GGA (+ GST) -> GnssFix."""

    def __init__(self, origin: Origin, variance_by_quality: Mapping[int, float] | None = None,
                 default_variance_m2: float = 0.5, vertical_variance_factor: float = 4.0):
        self.origin = origin
        self.variance_by_quality = dict(variance_by_quality or {RTK_FIXED: 5e-5})
        self.default_variance_m2 = float(default_variance_m2)
        self.vertical_variance_factor = float(vertical_variance_factor)

    @classmethod
    def from_config(cls, cfg: Mapping) -> "GnssProjector":
        g = config.get(cfg, "gnss", {}) or {}
        # YAML int keys become strings once the run config went through JSON: accept both
        by_quality = {int(k): float(v) for k, v in (g.get("variance_m2") or {str(RTK_FIXED): 5e-5}).items()}
        return cls(Origin.from_config(cfg), by_quality, float(g.get("default_variance_m2", 0.5)),
                   float(g.get("vertical_variance_factor", 4.0)))

    def project(self, lat: float, lon: float, altitude_m: float) -> Projected:
        """UTM and local coordinates; GnssError("utm zone" / "utm range") if unusable."""
        try:
            easting, northing, zone, letter = utm.from_latlon(lat, lon)
        except utm.error.OutOfRangeError as exc:      # beyond UTM's 80 S .. 84 N, for instance
            raise GnssError("utm range", f"position {lat:.6f}, {lon:.6f} has no UTM coordinates: {exc}") from None
        northern = letter >= "N"
        if zone != self.origin.zone or northern != self.origin.northern:
            raise GnssError("utm zone", f"position {lat:.6f}, {lon:.6f} is in UTM zone {zone}{'N' if northern else 'S'}, "
                                        f"the site's origin is in {self.origin.zone}{'N' if self.origin.northern else 'S'}")
        easting, northing = float(easting), float(northing)
        if not (math.isfinite(easting) and math.isfinite(northing)
                and 0.0 < easting < 1_000_000.0 and 0.0 <= northing <= 10_000_000.0):
            raise GnssError("utm range", f"UTM projection of {lat:.6f}, {lon:.6f} gave {easting}, {northing}")
        return Projected(x=easting - self.origin.easting, y=northing - self.origin.northing,
                         z=altitude_m - self.origin.altitude_m, easting=easting, northing=northing,
                         zone=zone, hemisphere="N" if northern else "S")

    def variances(self, gga: Gga, gst: Gst | None) -> tuple[float, float, float]:
        """(var_x, var_y, var_z) in m²: x is east (longitude), y north (latitude)."""
        if gst is not None:
            return gst.sigma_lon_m ** 2, gst.sigma_lat_m ** 2, gst.sigma_alt_m ** 2
        horizontal = self.variance_by_quality.get(gga.quality, self.default_variance_m2)
        return horizontal, horizontal, horizontal * self.vertical_variance_factor

    def fix(self, gga: Gga, gst: Gst | None = None, t: float = 0.0) -> GnssFix:
        """The GnssFix message of a GGA; a GST is used only if it belongs to the same epoch."""
        if gst is not None and gst.time != gga.time:
            gst = None
        p = self.project(gga.lat, gga.lon, gga.altitude_m)
        var_x, var_y, var_z = self.variances(gga, gst)
        return GnssFix(t=t, x=p.x, y=p.y, z=p.z, lat=gga.lat, lon=gga.lon, easting=p.easting,
                       northing=p.northing, zone=p.zone, hemisphere=p.hemisphere, quality=gga.quality,
                       rtk=gga.quality == RTK_FIXED, satellites=gga.satellites, hdop=gga.hdop,
                       var_x=var_x, var_y=var_y, var_z=var_z)


def pair_epochs(sentences: Iterable[Gga | Gst], earlier_gst: Gst | None = None) -> list[tuple[Gga, Gst | None]]:
    """Each GGA with the most recent GST of the same time among `sentences` (either order: a
    receiver may send GST before or after its GGA) or, failing that, `earlier_gst`."""
    sentences = list(sentences)
    pairs = []
    for s in sentences:
        if not isinstance(s, Gga):
            continue
        match = None
        for other in sentences:     # the last GST of that time wins: "the most recent"
            if isinstance(other, Gst) and other.time == s.time:
                match = other
        if match is None and earlier_gst is not None and earlier_gst.time == s.time:
            match = earlier_gst
        pairs.append((s, match))
    return pairs
