"""From a validated GGA (and the GST of the same epoch, when the receiver sends one) to a fix in
UTM and in the stack's local frame (ARES §3.1: "NMEA GGA in, UTM out").

The local frame and the checks on a position (within the frame's reach of the origin) are
ares.core.geodesy's. Variances: a GST's latitude / longitude / altitude standard deviations, squared
(the receiver's own estimate), else figures by fix quality from config — the paper's ≈ 5e-5 m²
with RTK fixed (quality 4) and ≈ 0.5 m² without corrections.
"""

from __future__ import annotations

from collections.abc import Iterable

from ares.core.config import Params, param
from ares.core.geodesy import FrameError, LocalFrame, Projected
from ares.core.messages import GnssFix
from perception.nmea_parser import Gga, Gst, NmeaError

RTK_FIXED = 4  # GGA fix quality of an RTK fixed solution


class GnssError(NmeaError):
    """A well-formed sentence whose fix cannot be used (e.g. hundreds of km from the site)."""


class GnssParams(Params):
    rate_hz: float = param(
        20.0, "loop rate; each loop drains every queued receiver message (sim.gnss_hz is 5)", unit="Hz", gt=0
    )
    queue: int = param(64, "receiver messages buffered between two loops", ge=1)
    variance_m2: dict[int, float] = param(
        doc="horizontal variance by GGA fix quality when no GST of the same "
        "epoch arrived: RTK fixed (4), ARES §3.1 (~5e-5 with corrections)",
        unit="m^2",
        factory=lambda: {RTK_FIXED: 5.0e-5},
    )
    default_variance_m2: float = param(0.5, "any other fix quality: no corrections (ARES §3.1: ~0.5)", unit="m^2", gt=0)
    vertical_variance_factor: float = param(
        4.0, "without GST: the vertical sigma is taken as twice the horizontal one", gt=0
    )
    event_period_s: float = param(
        10.0, "at most one nmea_rejected event per reason per this many stack seconds", unit="s", gt=0
    )


class GnssProjector:
    """lat/lon/alt -> UTM -> local frame, and GGA (+ GST) -> GnssFix."""

    def __init__(self, frame: LocalFrame, params: GnssParams):
        self.frame = frame
        self.variance_by_quality = dict(params.variance_m2)
        self.default_variance_m2 = params.default_variance_m2
        self.vertical_variance_factor = params.vertical_variance_factor

    def project(self, lat: float, lon: float, altitude_m: float | None) -> Projected:
        """UTM and local coordinates; GnssError("far from origin" / "utm range") if unusable."""
        try:
            return self.frame.project(lat, lon, altitude_m)
        except FrameError as exc:
            raise GnssError(exc.reason, str(exc)) from None

    def variances(self, gga: Gga, gst: Gst | None) -> tuple[float, float, float]:
        """(var_x, var_y, var_z) in m²: x is east (longitude), y north (latitude)."""
        if gst is not None:
            return gst.sigma_lon_m**2, gst.sigma_lat_m**2, gst.sigma_alt_m**2
        horizontal = self.variance_by_quality.get(gga.quality, self.default_variance_m2)
        return horizontal, horizontal, horizontal * self.vertical_variance_factor

    def fix(self, gga: Gga, gst: Gst | None = None, t: float = 0.0) -> GnssFix:
        """The GnssFix message of a GGA; a GST is used only if it belongs to the same epoch."""
        if gst is not None and (not gga.time or gst.time != gga.time):
            gst = None
        p = self.project(gga.lat, gga.lon, gga.altitude_m)
        var_x, var_y, var_z = self.variances(gga, gst)
        return GnssFix(
            t=t,
            x=p.x,
            y=p.y,
            z=p.z,
            var_z=None if p.z is None else var_z,
            lat=gga.lat,
            lon=gga.lon,
            easting=p.easting,
            northing=p.northing,
            zone=p.zone,
            hemisphere=p.hemisphere,
            quality=gga.quality,
            rtk=gga.quality == RTK_FIXED,
            satellites=gga.satellites,
            hdop=gga.hdop,
            var_x=var_x,
            var_y=var_y,
        )


def pair_epochs(sentences: Iterable[Gga | Gst], earlier_gst: Gst | None = None) -> list[tuple[Gga, Gst | None]]:
    """Each GGA with the most recent GST of the same time among `sentences` (either order: a
    receiver may send GST before or after its GGA) or, failing that, `earlier_gst`."""
    sentences = list(sentences)
    pairs = []
    for s in sentences:
        if not isinstance(s, Gga):
            continue
        match = None
        for other in sentences:  # the last GST of that time wins: "the most recent"
            if isinstance(other, Gst) and s.time and other.time == s.time:
                match = other
        if match is None and earlier_gst is not None and s.time and earlier_gst.time == s.time:
            match = earlier_gst
        pairs.append((s, match))
    return pairs
