"""A strict parser for the NMEA 0183 sentences that carry a position — GGA (the fix), RMC and GLL
— and GST (the fix's error statistics), from any talker (GP, GN, GL, GA, GB, BD, ...). Every other
well-framed sentence (GSA, GSV, VTG, ZDA, an echo sounder's DPT, a compass's HDG, proprietary
`$P...`, AIS `!AIVDM`) passes its checksum and comes back as `Other`: a receiver's ordinary
output, not an error.

Why not pynmea2 alone: it checks the checksum but parses fields lazily, so a sentence with a
valid checksum and garbage fields "parses" and fails later, or worse yields a plausible number
(docs/design.md §5). Here every field is checked before a sentence is returned, and a line is either a
fully valid, frozen sentence or an `NmeaError` whose `reason` is a short machine-readable word
("checksum", "framing", "field count", "latitude", "no fix", ...) and whose message names the
field. Nothing else escapes `parse_sentence`.

Every form NMEA 0183 allows is accepted: times with or without fractional seconds, empty
("null") fields wherever the data may be unavailable (altitude, geoid separation, HDOP,
satellites, the differential fields), integer altitudes, GGA with or without a fix (quality 0
is "no fix"), RMC of 11, 12 (mode) or 13 (navigational status) fields, GLL of 5, 6 or 7.

`NmeaReader` wraps the parser for a stream of lines and counts what it accepted (by sentence
address: talker and type) and rejected (by reason).
"""

from __future__ import annotations

import collections
import math
import re
from collections.abc import Iterable, Iterator
from dataclasses import dataclass

from ares.core.nmea_framing import checksum

# The standard says 82 characters, but high-precision receivers (and our simulator, with seven
# decimals of a minute for millimetre RTK fixes) exceed it; anything much longer is garbage.
MAX_LINE_CHARS = 200

# Plausibility bounds that catch digits that are well-formed but cannot be a ground vehicle's
# fix: altitude above mean sea level, and the geoid's separation from the ellipsoid (the real
# geoid stays within about -107..+86 m).
ALTITUDE_RANGE_M = (-1000.0, 20000.0)
GEOID_SEPARATION_MAX_M = 200.0
MAX_DGPS_STATION_ID = 1023

GGA_FIELDS = 14  # time, lat, N/S, lon, E/W, quality, sats, hdop, alt, M, geoid, M, age, station
GST_FIELDS = 8  # time, rms, semi-major, semi-minor, orientation, sigma lat, lon, alt
RMC_FIELDS = (11, 12, 13)  # time, status, lat, N/S, lon, E/W, speed, course, date, magvar, E/W
# [, mode (NMEA 2.3)] [, navigational status (NMEA 4.1)]
GLL_FIELDS = (4, 5, 6, 7)  # lat, N/S, lon, E/W [, time] [, status (2.x)] [, mode (2.3)]
MODE_NO_FIX = "N"  # RMC / GLL mode indicator: data not valid

_TIME_RE = re.compile(r"(\d{2})(\d{2})(\d{2}(?:\.\d{1,6})?)", re.ASCII)
_LAT_RE = re.compile(r"(\d{2})(\d{2}(?:\.\d{0,10})?)", re.ASCII)  # ddmm[.mmmm]
_LON_RE = re.compile(r"(\d{3})(\d{2}(?:\.\d{0,10})?)", re.ASCII)  # dddmm[.mmmm]
_UNSIGNED_RE = re.compile(r"\d+(?:\.\d*)?|\.\d+", re.ASCII)  # no exponent, no nan/inf, no sign
_SIGNED_RE = re.compile(r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)", re.ASCII)
_ADDRESS_RE = re.compile(r"[A-Z0-9]{5}|P[A-Z0-9]{1,8}", re.ASCII)  # talker + type, or proprietary
_DATE_RE = re.compile(r"(\d{2})(\d{2})(\d{2})", re.ASCII)
_HEX = frozenset("0123456789ABCDEFabcdef")


class NmeaError(ValueError):
    """A rejected line. `reason` is one short word or phrase for counting; str() says why."""

    def __init__(self, reason: str, message: str):
        super().__init__(message)
        self.reason = reason


@dataclass(frozen=True)
class Gga:
    """A GGA fix that passed every check (quality 1-8: a position is present)."""

    talker: str
    time: str  # hhmmss[.ss] as sent ("" when the receiver left it empty): pairs a GST
    seconds_of_day: float | None
    lat: float  # degrees, north positive
    lon: float  # degrees, east positive
    quality: int  # 1 GPS, 2 DGPS, 3 PPS, 4 RTK fixed, 5 RTK float, 6 dead reckoning, ...
    satellites: int | None
    hdop: float | None
    altitude_m: float | None  # above mean sea level
    geoid_separation_m: float | None
    dgps_age_s: float | None
    dgps_station: int | None

    kind = "GGA"


@dataclass(frozen=True)
class Rmc:
    """RMC, the recommended minimum: a position (status A) with speed, course and date; no altitude."""

    talker: str
    time: str
    seconds_of_day: float | None
    lat: float
    lon: float
    speed_knots: float | None
    course_deg: float | None
    date: str  # ddmmyy as sent, or ""

    kind = "RMC"
    altitude_m = None


@dataclass(frozen=True)
class Gll:
    """GLL: a latitude and longitude (status A, or no status in the oldest form); no altitude."""

    talker: str
    time: str
    seconds_of_day: float | None
    lat: float
    lon: float

    kind = "GLL"
    altitude_m = None


@dataclass(frozen=True)
class Gst:
    """GST: the receiver's own error estimate for the fix of the same time."""

    talker: str
    time: str
    seconds_of_day: float
    rms: float | None  # RMS of the range residuals
    semi_major_m: float | None  # error ellipse
    semi_minor_m: float | None
    orientation_deg: float | None
    sigma_lat_m: float  # 1-sigma errors, metres
    sigma_lon_m: float
    sigma_alt_m: float

    kind = "GST"


@dataclass(frozen=True)
class Other:
    """A well-framed sentence with a valid checksum that carries no position ARES uses: GSA, GSV,
    VTG, ZDA, instruments' DPT, HDG, MWV, proprietary `$P...` (`kind` is its address after the
    talker, e.g. "GSV", or the whole address of a proprietary or encapsulated sentence, e.g.
    "PUBX", "!AIVDM")."""

    talker: str  # "" for a proprietary or encapsulated sentence
    kind: str


Position = Gga | Rmc | Gll
Sentence = Gga | Rmc | Gll | Gst | Other


def address(sentence: Sentence) -> str:
    """The sentence's address as sent: GNGGA, SDDPT, PUBX."""
    return f"{sentence.talker}{sentence.kind}"


# ---- framing ------------------------------------------------------------------------------


def _frame(line: str | bytes) -> tuple[str, str, list[str]]:
    """Check the framing and checksum; (talker, sentence type, fields after the address)."""
    if isinstance(line, (bytes, bytearray)):
        try:
            line = bytes(line).decode("ascii")
        except UnicodeDecodeError:
            raise NmeaError("framing", "not ASCII text") from None
    if not isinstance(line, str):
        raise NmeaError("framing", f"expected text, got {type(line).__name__}")
    for ending in ("\r\n", "\n", "\r"):  # one optional line ending, as a serial port gives
        if line.endswith(ending):
            line = line[: -len(ending)]
            break
    if not line:
        raise NmeaError("framing", "empty line")
    if len(line) > MAX_LINE_CHARS:
        raise NmeaError("framing", f"line of {len(line)} characters (at most {MAX_LINE_CHARS})")
    if line[0] not in "$!":
        raise NmeaError("framing", "does not start with '$' (or '!' for encapsulated data)")
    if any(not (" " <= ch <= "~") for ch in line):
        raise NmeaError("framing", "contains a control or non-ASCII character")
    star = line.find("*")
    if star < 0:
        raise NmeaError("framing", "no '*' before the checksum")
    body, given = line[1:star], line[star + 1 :]
    if "$" in body or "!" in body or "*" in given:
        raise NmeaError("framing", "more than one '$', '!' or '*'")
    if len(given) != 2 or not set(given) <= _HEX:
        raise NmeaError("framing", f"checksum must be two hex digits, got {given!r}")
    expected = checksum(body)
    if given.upper() != expected:
        raise NmeaError("checksum", f"checksum {given} does not match the sentence's {expected}")
    fields = body.split(",")
    address = fields[0]
    if not _ADDRESS_RE.fullmatch(address):
        raise NmeaError("framing", f"bad address field {address!r}")
    if address.startswith("P"):
        return "", address, fields[1:]  # proprietary: the maker's own layout
    if line[0] == "!":
        return "", "!" + address, fields[1:]  # encapsulated data (AIS): never a fix here
    return address[:2], address[2:], fields[1:]


# ---- field checks ---------------------------------------------------------------------------


def _number(text: str, reason: str, name: str, signed: bool = False) -> float:
    pattern = _SIGNED_RE if signed else _UNSIGNED_RE
    if not text:
        raise NmeaError(reason, f"{name} is empty")
    if not pattern.fullmatch(text):
        raise NmeaError(reason, f"{name} is not a {'' if signed else 'non-negative '}decimal number: {text!r}")
    value = float(text)
    if not math.isfinite(value):  # e.g. four hundred digits
        raise NmeaError(reason, f"{name} is not finite: {text[:20]!r}")
    return value


def _optional_number(text: str, reason: str, name: str, signed: bool = False) -> float | None:
    return None if text == "" else _number(text, reason, name, signed)


def _time(text: str) -> float:
    m = _TIME_RE.fullmatch(text)
    if not m:
        raise NmeaError("time", f"time must be hhmmss[.ss], got {text!r}")
    hours, minutes, seconds = int(m[1]), int(m[2]), float(m[3])
    if hours > 23 or minutes > 59 or seconds >= 60.0:
        raise NmeaError("time", f"time out of range: {text!r}")
    return hours * 3600.0 + minutes * 60.0 + seconds


def _angle(text: str, hemisphere: str, kind: str) -> float:
    """ddmm.mmmm (latitude) or dddmm.mmmm (longitude) and its hemisphere letter, in degrees."""
    is_lat = kind == "latitude"
    m = (_LAT_RE if is_lat else _LON_RE).fullmatch(text)
    if not m:
        digits = "dd" if is_lat else "ddd"
        raise NmeaError(kind, f"{kind} must be {digits}mm.mmmm, got {text!r}")
    degrees, minutes = int(m[1]), float(m[2])
    limit = 90 if is_lat else 180
    if minutes >= 60.0 or degrees > limit or (degrees == limit and minutes > 0.0):
        raise NmeaError(kind, f"{kind} out of range: {text!r}")
    letters = ("N", "S") if is_lat else ("E", "W")
    if hemisphere not in letters:
        raise NmeaError(kind, f"{kind} hemisphere must be {' or '.join(letters)}, got {hemisphere!r}")
    value = degrees + minutes / 60.0
    return -value if hemisphere == letters[1] else value


def _optional_time(text: str) -> float | None:
    return None if text == "" else _time(text)


def _metres_unit(text: str, reason: str, name: str, optional: bool = False) -> None:
    if text != "M" and not (optional and text == ""):
        raise NmeaError(reason, f"{name} unit must be M, got {text!r}")


def _status(text: str, kind: str) -> None:
    """RMC / GLL status: A = data valid, V = void (the receiver has no fix)."""
    if text == "V":
        raise NmeaError("no fix", f"{kind} status V: the receiver has no fix")
    if text != "A":
        raise NmeaError("status", f"{kind} status must be A or V, got {text!r}")


def _mode(text: str, kind: str) -> None:
    """The NMEA 2.3 mode indicator (A autonomous, D differential, E estimated, F float RTK,
    M manual, N not valid, P precise, R RTK, S simulator)."""
    if text == MODE_NO_FIX:
        raise NmeaError("no fix", f"{kind} mode N: data not valid")
    if not re.fullmatch(r"[ADEFMPRS]?", text, re.ASCII):
        raise NmeaError("mode", f"{kind} mode indicator must be one of A D E F M N P R S, got {text!r}")


# ---- sentences ------------------------------------------------------------------------------


def _gga(talker: str, f: list[str]) -> Gga:
    if len(f) != GGA_FIELDS:
        raise NmeaError("field count", f"GGA has {GGA_FIELDS} fields after the address, got {len(f)}")
    # Quality first: a receiver without a fix leaves the position fields empty, and that is
    # "no fix", not a malformed latitude.
    if not re.fullmatch(r"[0-8]", f[5], re.ASCII):
        raise NmeaError("quality", f"fix quality must be one digit 0-8, got {f[5]!r}")
    quality = int(f[5])
    if quality == 0:
        raise NmeaError("no fix", "fix quality 0: the receiver has no fix")
    seconds = _optional_time(f[0])
    lat = _angle(f[1], f[2], "latitude")
    lon = _angle(f[3], f[4], "longitude")
    if f[6] != "" and not re.fullmatch(r"\d{1,2}", f[6], re.ASCII):
        raise NmeaError("satellites", f"satellites in use must be an integer 0-99, got {f[6]!r}")
    hdop = _optional_number(f[7], "hdop", "HDOP")
    # Null fields are the standard's way of saying "not available": altitude and geoid
    # separation may each be empty, with or without their unit letter.
    altitude = _optional_number(f[8], "altitude", "altitude", signed=True)
    if altitude is not None and not ALTITUDE_RANGE_M[0] <= altitude <= ALTITUDE_RANGE_M[1]:
        raise NmeaError("altitude", f"altitude {altitude} m outside {ALTITUDE_RANGE_M}")
    _metres_unit(f[9], "altitude", "altitude", optional=altitude is None)
    geoid = _optional_number(f[10], "geoid", "geoid separation", signed=True)
    if geoid is not None and abs(geoid) > GEOID_SEPARATION_MAX_M:
        raise NmeaError("geoid", f"geoid separation {geoid} m beyond ±{GEOID_SEPARATION_MAX_M}")
    _metres_unit(f[11], "geoid", "geoid separation", optional=geoid is None)
    age = _optional_number(f[12], "dgps", "age of differential corrections")
    if f[13] == "":
        station = None
    elif re.fullmatch(r"\d{1,4}", f[13], re.ASCII) and int(f[13]) <= MAX_DGPS_STATION_ID:
        station = int(f[13])
    else:
        raise NmeaError("dgps", f"differential station id must be 0-{MAX_DGPS_STATION_ID}, got {f[13]!r}")
    return Gga(
        talker=talker,
        time=f[0],
        seconds_of_day=seconds,
        lat=lat,
        lon=lon,
        quality=quality,
        satellites=int(f[6]) if f[6] else None,
        hdop=hdop,
        altitude_m=altitude,
        geoid_separation_m=geoid,
        dgps_age_s=age,
        dgps_station=station,
    )


def _rmc(talker: str, f: list[str]) -> Rmc:
    if len(f) not in RMC_FIELDS:
        raise NmeaError("field count", f"RMC has 11, 12 or 13 fields after the address, got {len(f)}")
    _status(f[1], "RMC")  # first: a void RMC leaves the position empty
    if len(f) >= 12:
        _mode(f[11], "RMC")
    if len(f) == 13 and not re.fullmatch(r"[SCUV]?", f[12], re.ASCII):
        raise NmeaError("status", f"RMC navigational status must be S, C, U or V, got {f[12]!r}")
    seconds = _optional_time(f[0])
    lat = _angle(f[2], f[3], "latitude")
    lon = _angle(f[4], f[5], "longitude")
    speed = _optional_number(f[6], "speed", "speed over ground")
    course = _optional_number(f[7], "course", "course over ground")
    if course is not None and course > 360.0:
        raise NmeaError("course", f"course {course} deg beyond 360")
    if f[8]:
        m = _DATE_RE.fullmatch(f[8])
        if not m or not (1 <= int(m[1]) <= 31 and 1 <= int(m[2]) <= 12):
            raise NmeaError("date", f"date must be ddmmyy, got {f[8]!r}")
    variation = _optional_number(f[9], "variation", "magnetic variation")
    if variation is not None and variation > 180.0:
        raise NmeaError("variation", f"magnetic variation {variation} deg beyond 180")
    if f[10] not in ("", "E", "W"):
        raise NmeaError("variation", f"magnetic variation direction must be E or W, got {f[10]!r}")
    return Rmc(
        talker=talker,
        time=f[0],
        seconds_of_day=seconds,
        lat=lat,
        lon=lon,
        speed_knots=speed,
        course_deg=course,
        date=f[8],
    )


def _gll(talker: str, f: list[str]) -> Gll:
    if len(f) not in GLL_FIELDS:
        raise NmeaError("field count", f"GLL has 4 to 7 fields after the address, got {len(f)}")
    if len(f) >= 6:
        _status(f[5], "GLL")
    if len(f) == 7:
        _mode(f[6], "GLL")
    lat = _angle(f[0], f[1], "latitude")
    lon = _angle(f[2], f[3], "longitude")
    time = f[4] if len(f) >= 5 else ""
    return Gll(talker=talker, time=time, seconds_of_day=_optional_time(time), lat=lat, lon=lon)


def _gst(talker: str, f: list[str]) -> Gst:
    if len(f) != GST_FIELDS:
        raise NmeaError("field count", f"GST has {GST_FIELDS} fields after the address, got {len(f)}")
    seconds = _time(f[0])
    # The residual RMS and the ellipse are informative only; the three sigmas are what the
    # fix's variances come from, so they must be present.
    rms = _optional_number(f[1], "sigma", "RMS of range residuals")
    major = _optional_number(f[2], "sigma", "semi-major axis sigma")
    minor = _optional_number(f[3], "sigma", "semi-minor axis sigma")
    orientation = _optional_number(f[4], "orientation", "ellipse orientation")
    if orientation is not None and orientation > 360.0:
        raise NmeaError("orientation", f"ellipse orientation {orientation} deg beyond 360")
    sigma_lat = _number(f[5], "sigma", "latitude sigma")
    sigma_lon = _number(f[6], "sigma", "longitude sigma")
    sigma_alt = _number(f[7], "sigma", "altitude sigma")
    return Gst(
        talker=talker,
        time=f[0],
        seconds_of_day=seconds,
        rms=rms,
        semi_major_m=major,
        semi_minor_m=minor,
        orientation_deg=orientation,
        sigma_lat_m=sigma_lat,
        sigma_lon_m=sigma_lon,
        sigma_alt_m=sigma_alt,
    )


_PARSERS = {"GGA": _gga, "RMC": _rmc, "GLL": _gll, "GST": _gst}


def parse_sentence(line: str | bytes) -> Sentence:
    """One line -> a validated Gga, Rmc, Gll, Gst or Other, else NmeaError (and nothing else)."""
    try:
        talker, kind, fields = _frame(line)
        parser = _PARSERS.get(kind) if talker else None
        if parser is None:
            return Other(talker=talker, kind=kind)
        return parser(talker, fields)
    except NmeaError:
        raise
    except Exception as exc:  # a bug in a check must reject the line, never pass it or crash
        raise NmeaError("internal", f"parser error: {exc!r}") from exc


class NmeaReader:
    """Parses lines and counts them: `accepted` by sentence type, `rejected` by reason.

    `last_error` is the latest rejection, for the caller to log.
    """

    def __init__(self) -> None:
        self.accepted: collections.Counter[str] = collections.Counter()
        self.rejected: collections.Counter[str] = collections.Counter()
        self.last_error: NmeaError | None = None

    def parse(self, line: str | bytes) -> Sentence | None:
        """The sentence, or None (counted under its reason) when the line is rejected."""
        try:
            sentence = parse_sentence(line)
        except NmeaError as exc:
            self.reject(exc)
            return None
        self.accepted[address(sentence)] += 1
        return sentence

    def reject(self, error: NmeaError) -> int:
        """Count a rejection (also used for fixes refused after parsing, e.g. a wrong UTM
        zone); returns how many of that reason so far."""
        self.rejected[error.reason] += 1
        self.last_error = error
        return self.rejected[error.reason]

    def read(self, lines: Iterable[str | bytes]) -> Iterator[Sentence]:
        for line in lines:
            sentence = self.parse(line)
            if sentence is not None:
                yield sentence

    @property
    def total_rejected(self) -> int:
        return sum(self.rejected.values())

    @property
    def total_accepted(self) -> int:
        return sum(self.accepted.values())
