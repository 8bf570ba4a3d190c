"""Route files from a recorded drive (`ares route import`): the ARES path manager's global path
is "recorded from the real vehicle" (docs/design.md §3) — this turns such a recording into a route.

Input: a CSV of x,y[,z] metres in the local frame, or an NMEA log as a receiver or logger writes
it (the format is told from the content). In a log, comment and header lines (any text, any
encoding), CRLF line ends, NMEA 4 tag blocks and timestamp prefixes are allowed; every sentence
is parsed strictly (perception.nmea_parser) and counted: positions come from the GGA fixes (from RMC,
else GLL, when a log has none), one per epoch; sentences without a position and lines without
a fix are skipped; a line with a bad checksum or broken fields is skipped under its reason (or,
with `strict`, fails the import naming the line). Steps:

1. projection to a local frame: the configured origin's when the drive lies within its reach,
   else one at the drive's first fix (a drive recorded anywhere on Earth). Every fix is
   projected in the origin's UTM zone, so a drive across a zone boundary stays continuous; the
   route file records the origin, and a run that drives the route uses it;
2. de-duplication of standstill fixes: a vehicle waiting at a stop yields hundreds of nearly
   identical fixes, which would make a tangle of tiny zig-zags; a point closer than
   `min_step_m` to the last kept one is dropped (order is kept). Fixes without RTK wander by
   metres (HDOP x `uere_m`) while the car stands or creeps: each run of fixes within that of
   their mean becomes that mean, one point;
3. resampling to even spacing along the path (a whole number of equal steps), first at a fine
   step for the filter, at the end at the route's spacing (default 0.5 m);
4. smoothing: a quadratic Savitzky-Golay filter over a window of a few metres on x and y.
   Being quadratic, it follows an arc of radius R with a small bias (under a centimetre for
   R >= 8 m with the default 5 m window, which lets through about what a 2.5 m moving average
   would), while averaging the millimetre RTK noise of the fixes in the window. The window is
   not shorter because consumers differentiate the path twice: curvature sets the speed
   profile, and with a 3 m window RTK noise alone reads as curves of 15-30 m radius on
   straights. z gets a longer window: the grade the simulator feels is dz/ds, which amplifies
   altitude noise. Fixes without RTK get a window in proportion to their wander
   (`noisy_window_per_m`), grown while any turn is sharper than the vehicle can steer (its
   wheelbase and largest wheel angle: a kink of such fixes is noise); with RTK a corner that
   sharp is the road's, kept and reported;
5. altitude: only RTK fixes' altitude is used (without RTK the height errs by metres and drifts
   while the receiver converges: one real log climbs 350 m in 88 s); others are interpolated
   between RTK ones, or the route is flat. The grade is then limited to `max_grade`;
6. yaw from the neighbouring poses (central differences).

The route file records the road's width (`road_width_m`, a comment Route.from_csv reads).

The output is a CSV with '# ares route: ...' and '# origin: ...' comments and the header
x,y,z,yaw, which Route.from_csv reads back. A recording whose end comes back to its start is reported as a
closed loop; the file stays an open route (its two ends simply meet).
"""

from __future__ import annotations

import collections
import math
import os
import re
import tempfile
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ares.core import config
from ares.core.config import Params, UtmOrigin, param
from ares.core.geodesy import FrameError, LocalFrame, origin_at
from ares.core.route import Route, RouteError, origin_comment, width_comment
from ares.core.wire.nmea_stream import UBX_SYNC, NmeaStream, ubx_frame_length
from perception.gnss import RTK_FIXED
from perception.nmea_parser import Gga, NmeaError, Other, Position, address, parse_sentence

FORMATS = ("auto", "csv", "nmea")
SMOOTHING_STEP_M = 0.1  # resampling step the smoothing filter works on
DETECT_LINES = 2000  # lines looked at to tell NMEA from CSV
POSITION_KINDS = ("GGA", "RMC", "GLL")  # in order of preference: GGA has quality and altitude
# where a sentence starts after a logger's prefix (a timestamp, a port name, then a space, a comma
# or a semicolon): "$GNGGA," or "!AIVDM,"
_SENTENCE_START = re.compile(rb"(?:^|[\s,;])([$!](?:[A-Z0-9]{5}|P[A-Z0-9]{1,8})[,*])")


class RouteImportError(RouteError):
    """A recording that cannot be turned into a route; the message names the line."""


class RouteImportSettings(Params):
    """The `route_import` section: `ares route import`, a recorded drive -> a route file."""

    spacing_m: float = param(0.5, "distance between route points", unit="m", gt=0)
    min_step_m: float = param(0.1, "standstill: drop fixes closer than this to the last kept one", unit="m", gt=0)
    smooth_window_m: float = param(
        5.0, "quadratic Savitzky-Golay on x, y: removes mm RTK noise, keeps arcs of R >= 8 m", unit="m", gt=0
    )
    smooth_polyorder: int = param(2, "order of the smoothing polynomial", ge=1, le=5)
    z_window_m: float = param(10.0, "longer on z: the grade dz/ds amplifies altitude noise", unit="m", gt=0)
    loop_close_m: float = param(5.0, "end this close to the start: reported as a closed loop", unit="m", gt=0)
    uere_m: float = param(
        1.0,
        "how far a fix without RTK wanders per unit of its HDOP (user equivalent range error, short-term): "
        "fixes of a standing receiver within HDOP x this of each other are one point",
        unit="m",
        gt=0,
    )
    noisy_window_per_m: float = param(
        7.0,
        "fixes without RTK: the x, y smoothing window per metre of their wander (HDOP x uere_m), "
        "at least smooth_window_m",
        gt=0,
    )
    max_window_m: float = param(
        60.0, "fixes without RTK: the window grows up to this while the path is sharper than the vehicle turns", gt=0
    )
    max_grade: float = param(0.15, "steepest road grade kept (town streets stay under 15 %)", gt=0)
    road_width_m: float = param(
        5.5,
        "the road's width, written into the route file: a town street of 5-6 m, which leaves the 2 m "
        "shuttle the obstacle manager's margins and room for its cross-track error (4 m leaves ~0.2 m)",
        unit="m",
        gt=0,
    )
    stood_still_m: float = param(
        10.0,
        "points all within this of their centre, along a path many times longer than that: a receiver "
        "that stood still and wandered (refused), not a drive",
        unit="m",
        gt=0,
    )


@dataclass
class ImportResult:
    source: str
    fmt: str  # "csv" or "nmea"
    points_in: int  # CSV rows or GGA fixes read
    kept: int  # after standstill de-duplication
    xyz: np.ndarray  # the route's points, evenly spaced
    yaw: np.ndarray
    spacing_m: float
    closed_loop: bool
    loop_gap_m: float  # distance from the last point to the first
    log: NmeaLog | None = None  # what an NMEA log held, line by line
    origin: UtmOrigin | None = None  # the route's frame (NMEA); a CSV is in the configured one
    origin_source: str = ""  # "configured" or "first fix"
    output: str = ""
    window_m: float = 0.0  # the x, y smoothing window used
    noise_m: float = 0.0  # median wander radius of the fixes (0: RTK or no quality given)
    notes: list[str] = field(default_factory=list)  # what the geometry steps changed, for the summary

    @property
    def length_m(self) -> float:
        return float(np.sum(np.hypot(np.diff(self.xyz[:, 0]), np.diff(self.xyz[:, 1]))))

    @property
    def step_m(self) -> float:
        """The actual spacing: the length over a whole number of steps, close to spacing_m."""
        return self.length_m / max(len(self.xyz) - 1, 1)

    def summary(self) -> str:
        """What was used and what was skipped, by sentence type and reason: a few lines."""
        unit = f"{self.log.used} fixes" if self.log else "points"
        lines = [
            f"{self.source}{f' -> {self.output}' if self.output else ''}: {self.points_in} {unit} in, "
            f"{self.kept} kept ({self.points_in - self.kept} standstill/duplicates dropped), "
            f"{len(self.xyz)} route points every {self.step_m:.2f} m, length {self.length_m:.1f} m"
        ]
        if self.closed_loop:
            lines.append(f"closed loop detected (end {self.loop_gap_m:.2f} m from start), written as an open route")
        if self.origin is not None:
            o = self.origin
            lines.append(
                f"origin ({'the configured one' if self.origin_source == 'configured' else 'the first fix'}): "
                f"UTM {o.zone}{o.hemisphere} {o.easting:.2f} E {o.northing:.2f} N, altitude "
                f"{o.altitude_m:.1f} m; a run that drives this route uses it"
            )
        lines += self.notes
        if self.log is not None:
            lines += self.log.report()
        return "\n  ".join(lines)


# ---- reading --------------------------------------------------------------------------------


def sentence_of(line: bytes) -> bytes | None:
    """The NMEA sentence in a log line, without a tag block or a logger's prefix (a timestamp,
    a port name) before it; None for a comment, header or other text line."""
    line = line.strip()
    if line.startswith(b"\\"):  # NMEA 4 tag block: \s:GPS1,c:1700000000*5A\$GPGGA,...
        end = line.find(b"\\", 1)
        line = line[end + 1 :] if end > 0 else line
    if line[:1] in (b"$", b"!"):
        return line
    m = _SENTENCE_START.search(line)
    return line[m.start(1) :] if m else None


def _is_csv_row(line: bytes) -> bool:
    cells = line.split(b",")
    try:
        return len(cells) >= 2 and all(math.isfinite(float(c)) for c in cells)
    except ValueError:
        return False


def detect_format(data: bytes) -> str | None:
    """'nmea' when more of the first lines hold NMEA sentences than x,y rows, 'csv' when rows
    win; comments, headers and blank lines count for neither. None when there is neither."""
    sentences = rows = 0
    for raw in data.splitlines()[:DETECT_LINES]:
        line = raw.strip().lstrip(b"\xef\xbb\xbf")
        if not line:
            continue
        if sentence_of(line) is not None:
            sentences += 1
        elif _is_csv_row(line):
            rows += 1
    if sentences == rows == 0:
        return None
    return "nmea" if sentences > rows else "csv"


def read_csv_points(data: bytes, source: str) -> np.ndarray:
    """x,y[,z] rows (a 4th column, yaw, is accepted and recomputed later); a header line and
    '#' comments are allowed."""
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise RouteImportError(f"{source}: not a text file (byte {exc.start} is not UTF-8)") from None
    points = []
    first_row = True
    for lineno, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        cells = [c.strip() for c in stripped.split(",")]
        try:
            values = [float(c) for c in cells]
        except ValueError:
            if first_row and not any(c and (c[0].isdigit() or c[0] in "+-.") for c in cells):
                first_row = False
                continue  # a header such as x,y,z
            raise RouteImportError(f"{source}:{lineno}: expected numbers x,y[,z], got {stripped[:80]!r}") from None
        first_row = False
        if len(values) not in (2, 3, 4):
            raise RouteImportError(f"{source}:{lineno}: expected 2 or 3 numbers x,y[,z], got {len(values)}")
        if not all(math.isfinite(v) for v in values):
            raise RouteImportError(f"{source}:{lineno}: not a finite number in {stripped[:80]!r}")
        points.append((values[0], values[1], values[2] if len(values) >= 3 else 0.0))
    return np.array(points, dtype=float).reshape(-1, 3)


@dataclass
class NmeaLog:
    """What an NMEA log held: the positions used, and every other line counted."""

    used: str  # the sentence type the positions come from: GGA, RMC or GLL
    fixes: list[tuple[int, Position]]  # (line number, position), file order, one per epoch
    sentences: collections.Counter  # valid sentences, by address (GNGGA, GPGSV, SDDPT, PUBX)
    no_fix: collections.Counter  # position sentences saying the receiver had no fix, by type
    bad: collections.Counter  # rejected lines, by reason
    first_bad: dict[str, int]  # reason -> line number of its first line
    text_lines: int  # comments, headers, other text
    same_epoch: int  # a second position of an epoch already used (another talker)
    far: int = 0  # fixes beyond the frame's reach (set by the projection)
    non_rtk: int = 0  # GGA fixes without RTK fixed: metre-level errors
    no_altitude: int = 0  # fixes without altitude (interpolated between neighbours)
    altitude_dropped: int = 0  # altitudes of fixes without RTK, not used
    hdop: np.ndarray | None = None  # per projected fix; NaN where the sentence gives none
    rtk: np.ndarray | None = None  # per projected fix: RTK fixed (GGA quality 4)
    ubx_frames: int = 0  # u-blox binary frames on the same stream (skipped)
    broken_binary: dict[str, int] = field(default_factory=dict)  # binary that is no frame, by cause (skipped)

    def report(self) -> list[str]:
        unused = {a: n for a, n in self.sentences.items() if a[-3:] not in (self.used, "GST")}
        other_positions = sorted(a for a in unused if a[-3:] in POSITION_KINDS)
        lines = []
        if unused:
            lines.append(
                "skipped, no position used: "
                + _counts(unused)
                + (f" ({', '.join(other_positions)}: positions taken from {self.used})" if other_positions else "")
            )
        gst = {a: n for a, n in self.sentences.items() if a[-3:] == "GST"}
        if gst:
            lines.append(f"error statistics not needed for a route: {_counts(gst)}")
        if self.no_fix:
            lines.append("skipped, no fix: " + _counts(self.no_fix))
        if self.same_epoch:
            lines.append(f"skipped, same epoch as the fix before (another talker): {self.same_epoch}")
        if self.text_lines:
            lines.append(f"skipped, comment or header lines: {self.text_lines}")
        if self.ubx_frames:
            lines.append(f"skipped, u-blox binary (UBX) frames between the sentences: {self.ubx_frames}")
        if self.broken_binary:
            lines.append(
                "skipped, binary that is no whole frame (a broken or cut UBX frame, noise): "
                + _counts(self.broken_binary)
            )
        if self.bad:
            lines.append(
                "skipped, bad lines: "
                + ", ".join(f"{r} {n} (first: line {self.first_bad[r]})" for r, n in sorted(self.bad.items()))
            )
        if self.far:
            lines.append(f"skipped, fixes beyond the frame's reach: {self.far}")
        if self.no_altitude or self.altitude_dropped:
            unused = self.no_altitude + self.altitude_dropped
            what = (
                f"{self.no_altitude} fixes without altitude"
                if not self.altitude_dropped
                else f"altitude of the {self.altitude_dropped} fixes without RTK not used (it errs and drifts "
                f"by metres to hundreds of metres: no grade can be read from it)"
                + (f", {self.no_altitude} fixes without altitude" if self.no_altitude else "")
            )
            lines.append(
                f"{what}: z interpolated between the others"
                if unused < len(self.fixes) - self.far
                else f"{what}: the route is flat (z = 0, the origin's altitude)"
                if self.altitude_dropped
                else "no altitude in the log: the route is flat (z = 0)"
            )
        if self.non_rtk:
            lines.append(f"warning: {self.non_rtk} fixes without RTK (quality != {RTK_FIXED}), errors up to metres")
        if self.used != "GGA":
            lines.append(f"warning: positions from {self.used} carry no fix quality: their accuracy is unknown")
        return lines


def _counts(counter: Mapping[str, int]) -> str:
    return ", ".join(f"{k} {n}" for k, n in sorted(counter.items(), key=lambda kv: (-kv[1], kv[0])))


def strip_ubx(data: bytes) -> tuple[bytes, int]:
    """The stream without its u-blox binary frames (u-blox receivers interleave them with the
    NMEA on one port by default), and how many there were. A frame: sync B5 62, class, id,
    little-endian length, payload, and the two Fletcher-8 bytes over class..payload; only frames
    whose checksum holds are taken out, so text that happens to hold the sync bytes stays
    (ares.core.wire.nmea_stream.ubx_frame_length, which the GNSS driver's framer uses too)."""
    if UBX_SYNC not in data:
        return data, 0
    out = bytearray()
    frames = 0
    i = 0
    while True:
        j = data.find(UBX_SYNC, i)
        if j < 0:
            out += data[i:]
            return bytes(out), frames
        length = ubx_frame_length(data, j)
        if length > 0:
            out += data[i:j]
            frames += 1
            i = j + length
        else:  # not a frame, or cut short by the end of the file: the bytes stay
            out += data[i : j + 2]
            i = j + 2


def nmea_of_binary(data: bytes) -> tuple[bytes, dict[str, int]]:
    """The sentences of a stream that holds binary the UBX scan did not take out (a frame with a
    broken checksum, a cut one, noise), framed as the GNSS driver frames its port (NmeaStream),
    one a line, and what was refused by cause. Comment lines between the sentences count as
    refused text then: a binary stream has none."""
    stream = NmeaStream()
    lines = stream.feed(data + b"\n", 0.0)  # \n: the last line's end
    wall = 0.0
    while stream.pending:  # a frame that claims more bytes than the file has left: not a frame
        before, wall = stream.pending, wall + 1.0
        lines += stream.feed(b"", wall)
        if stream.pending >= before:
            break
    text = "\n".join(line for line, _ in lines)
    return (text + "\n").encode("ascii") if lines else b"", dict(stream.malformed)


def log_lines(data: bytes) -> Iterator[tuple[int, bytes | None]]:
    """(line number, its sentence or None for a text line), blank lines left out."""
    for lineno, raw in enumerate(data.splitlines(), start=1):
        line = raw.strip().lstrip(b"\xef\xbb\xbf") if lineno == 1 else raw.strip()
        if line:
            yield lineno, sentence_of(line)


def read_nmea_log(data: bytes, source: str, strict: bool = False) -> NmeaLog:
    """Every line of a log counted; the positions of the preferred sentence type, one per epoch.
    With `strict`, a bad line raises RouteImportError naming it."""
    found: dict[str, list[tuple[int, Position]]] = {kind: [] for kind in POSITION_KINDS}
    sentences: collections.Counter[str] = collections.Counter()
    no_fix: collections.Counter[str] = collections.Counter()
    bad: collections.Counter[str] = collections.Counter()
    first_bad: dict[str, int] = {}
    text_lines = 0
    for lineno, line in log_lines(data):
        if line is None:
            text_lines += 1
            continue
        try:
            sentence = parse_sentence(line)
        except NmeaError as exc:
            if exc.reason == "no fix":  # the receiver saying it has no position yet: not a bad line
                no_fix[_kind_of(line)] += 1
                continue
            if strict:
                raise RouteImportError(f"{source}:{lineno}: {exc.reason}: {exc}") from None
            bad[exc.reason] += 1
            first_bad.setdefault(exc.reason, lineno)
            continue
        sentences[address(sentence)] += 1
        if not isinstance(sentence, Other) and sentence.kind in found:
            found[sentence.kind].append((lineno, sentence))
    used = next((kind for kind in POSITION_KINDS if found[kind]), "GGA")
    fixes: list[tuple[int, Position]] = []
    same_epoch = 0
    for lineno, fix in found[used]:
        # receivers that send GPGGA and GNGGA of one epoch: the first of the epoch is kept
        last = fixes[-1][1] if fixes else None
        if last is not None and fix.time and fix.time == last.time and fix.talker != last.talker:
            same_epoch += 1
            continue
        fixes.append((lineno, fix))
    return NmeaLog(
        used=used,
        fixes=fixes,
        sentences=sentences,
        no_fix=no_fix,
        bad=bad,
        first_bad=first_bad,
        text_lines=text_lines,
        same_epoch=same_epoch,
    )


def _kind_of(line: bytes) -> str:
    """GGA, RMC, GLL of a no-fix line (its address passed the checks before the fix did)."""
    return line[3:6].decode("ascii", "replace")


def frame_for(log: NmeaLog, configured: UtmOrigin) -> tuple[UtmOrigin, str]:
    """The route's origin: the configured one when the drive's first fix lies within its reach
    (routes of one site share its frame), else the first fix itself."""
    first = log.fixes[0][1]
    try:
        LocalFrame(configured).project(first.lat, first.lon, None)
        return configured, "configured"
    except FrameError:
        altitude = next((f.altitude_m for _, f in log.fixes if f.altitude_m is not None), 0.0)
        return origin_at(first.lat, first.lon, altitude, reach_km=configured.reach_km), "first fix"


def project_fixes(log: NmeaLog, frame: LocalFrame, source: str, strict: bool = False) -> np.ndarray:
    """x, y, z of the log's fixes in the frame; fixes beyond its reach counted (or, with
    `strict`, an error); missing altitudes interpolated between their neighbours."""
    points = []
    hdop: list[float] = []
    rtk: list[bool] = []
    log.altitude_dropped = 0
    for lineno, fix in log.fixes:
        try:
            p = frame.project(fix.lat, fix.lon, fix.altitude_m)
        except FrameError as exc:
            if strict:
                raise RouteImportError(f"{source}:{lineno}: {exc.reason}: {exc}") from None
            log.far += 1
            continue
        z = math.nan if p.z is None else p.z
        fixed = isinstance(fix, Gga) and fix.quality == RTK_FIXED
        if isinstance(fix, Gga) and not fixed:
            log.non_rtk += 1
            if p.z is not None:  # metres of noise, and drift while the receiver converges
                log.altitude_dropped += 1
                z = math.nan
        points.append((p.x, p.y, z))
        hdop.append(fix.hdop if isinstance(fix, Gga) and fix.hdop is not None else math.nan)
        rtk.append(fixed)
    log.hdop, log.rtk = np.array(hdop, dtype=float), np.array(rtk, dtype=bool)
    xyz = np.array(points, dtype=float).reshape(-1, 3)
    missing = np.isnan(xyz[:, 2])
    log.no_altitude = int(missing.sum()) - log.altitude_dropped
    if missing.all():
        xyz[:, 2] = 0.0
    elif missing.any():
        index = np.arange(len(xyz))
        xyz[missing, 2] = np.interp(index[missing], index[~missing], xyz[~missing, 2])
    return xyz


# ---- geometry -------------------------------------------------------------------------------


def stood_still(points: np.ndarray, kept: np.ndarray, name: str, within_m: float) -> None:
    """Refuse a log whose fixes wander around one place: all within `within_m` of their centre, and
    their path (the kept points in order) over five times as long as the place is wide. A short
    drive goes straight, its path about as long as it is wide."""
    centre = points[:, :2].mean(axis=0)
    spread = float(np.max(np.hypot(points[:, 0] - centre[0], points[:, 1] - centre[1])))
    path = float(np.sum(np.hypot(np.diff(kept[:, 0]), np.diff(kept[:, 1]))))
    if spread < within_m and path > 5 * max(2 * spread, 1e-3):
        raise RouteImportError(
            f"{name}: not a drive: its {len(points)} points stay within {spread:.1f} m of their centre while "
            f"their path wanders {path:.0f} m: a receiver that stood still (route_import.stood_still_m "
            f"{within_m:g} m)"
        )


def drop_standstill(points: np.ndarray, min_step_m: float) -> np.ndarray:
    """Keep a point only if it lies at least min_step_m (horizontally) from the last kept one."""
    if len(points) == 0:
        return points
    keep = [0]
    last = points[0, :2]
    for i in range(1, len(points)):
        if math.hypot(points[i, 0] - last[0], points[i, 1] - last[1]) >= min_step_m:
            keep.append(i)
            last = points[i, :2]
    return points[keep]


def wander_radii(log: NmeaLog | None, count: int, settings: RouteImportSettings) -> np.ndarray:
    """How far each fix may wander while the receiver stands still: min_step_m for RTK fixes, a CSV
    and sentences without a fix quality (RMC, GLL); HDOP x uere_m (HDOP 1 when not given) for
    GGA fixes without RTK."""
    radii = np.full(count, settings.min_step_m)
    if log is not None and log.rtk is not None and log.hdop is not None and log.used == "GGA":
        hdop = np.where(np.isfinite(log.hdop), log.hdop, 1.0)
        radii = np.where(log.rtk, radii, np.maximum(radii, hdop * settings.uere_m))
    return radii


def collapse_standstill(points: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """Runs of consecutive fixes that stay within the receiver's wander of their running mean (the
    first fix's radius) become that mean: a car that waits, creeps or stands while the fixes jitter
    by metres leaves one point, not a knot of zig-zags whose curvature no vehicle could follow."""
    out = []
    i = 0
    while i < len(points):
        total = points[i].copy()
        j = i + 1
        while j < len(points):
            mean = total[:2] / (j - i)
            if math.hypot(points[j, 0] - mean[0], points[j, 1] - mean[1]) > radii[i]:
                break
            total += points[j]
            j += 1
        out.append(total / (j - i))
        i = j
    return np.array(out, dtype=float).reshape(-1, 3)


def limit_grade(s: np.ndarray, z: np.ndarray, max_grade: float) -> tuple[np.ndarray, float]:
    """z with its grade clipped to +-max_grade (the climb re-integrated along s, its mean kept),
    and the length of road whose grade was clipped."""
    ds = np.diff(s)
    dz = np.diff(z)
    clipped = np.abs(dz) > max_grade * ds + 1e-12
    if not clipped.any():
        return z, 0.0
    out = np.concatenate([[0.0], np.cumsum(np.clip(dz, -max_grade * ds, max_grade * ds))])
    return out + (float(np.mean(z)) - float(np.mean(out))), float(ds[clipped].sum())


def smooth(values: np.ndarray, spacing_m: float, window_m: float, polyorder: int) -> np.ndarray:
    """Savitzky-Golay over about window_m of evenly spaced samples (odd length, shrunk to fit
    a short route; left alone when too short to fit the polynomial)."""
    n = int(round(window_m / spacing_m))
    n = n + 1 if n % 2 == 0 else n
    n = min(n, len(values) if len(values) % 2 == 1 else len(values) - 1)
    if n <= polyorder or n < 3:
        return values.copy()
    # mode="interp": the ends are fitted by the same polynomial, not padded with mirror images
    from scipy.signal import savgol_filter  # ~1 s to import: only when a route is smoothed

    return savgol_filter(values, n, polyorder, mode="interp")


def resample_even(points: np.ndarray, spacing_m: float) -> np.ndarray:
    """Points at equal steps along the polyline, from its first to its last point: the step is
    the length divided by a whole number of steps, as close to spacing_m as that allows (a
    plain fixed-step resampling would leave a stub of a last segment, and a wild last yaw)."""
    step = np.hypot(np.diff(points[:, 0]), np.diff(points[:, 1]))
    points = points[np.concatenate([[True], step > 1e-9])]
    if len(points) < 2:
        raise RouteError("a route needs at least two distinct points")
    s = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(points[:, 0]), np.diff(points[:, 1])))])
    n = max(int(round(s[-1] / spacing_m)), 1)
    s_new = np.linspace(0.0, s[-1], n + 1)
    return np.column_stack([np.interp(s_new, s, points[:, k]) for k in range(points.shape[1])])


def build_route(
    points: np.ndarray, settings: RouteImportSettings, window_m: float | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """De-duplicated points -> (evenly spaced smoothed xyz, yaw); x, y smoothed over window_m
    (default smooth_window_m), z over the longer of z_window_m and that.

    The filter runs on a fine resampling (SMOOTHING_STEP_M), so that its window means the same
    length of road whatever the output spacing, and every fix inside the window counts."""
    window = settings.smooth_window_m if window_m is None else window_m
    fine = min(settings.spacing_m, SMOOTHING_STEP_M)
    even = resample_even(points, fine)
    smoothed = np.column_stack(
        [
            smooth(even[:, 0], fine, window, settings.smooth_polyorder),
            smooth(even[:, 1], fine, window, settings.smooth_polyorder),
            smooth(even[:, 2], fine, max(settings.z_window_m, window), settings.smooth_polyorder),
        ]
    )
    xyz = resample_even(smoothed, settings.spacing_m)
    yaw = np.arctan2(np.gradient(xyz[:, 1]), np.gradient(xyz[:, 0]))
    return xyz, yaw


def sharpest(xyz: np.ndarray) -> tuple[float, float]:
    """(largest |curvature|, its arc length) as a run will read the route (Route's curvature)."""
    route = Route("import", xyz[:, 0], xyz[:, 1], xyz[:, 2], False, np.full(len(xyz), 1.0))
    i = int(np.argmax(np.abs(route.curvature)))
    return float(abs(route.curvature[i])), float(route.s[i])


def fit_route(
    kept: np.ndarray, noise_m: float, settings: RouteImportSettings, max_curvature: float
) -> tuple[np.ndarray, np.ndarray, float, list[str]]:
    """The route through the kept fixes: (xyz, yaw, window used, notes for the summary).

    Fixes that wander by metres (no RTK) are smoothed over a window in proportion, and the
    window grows (x1.25 steps, up to max_window_m) while the path is sharper than the vehicle
    can turn: such a kink is the fixes' noise. RTK fixes are the road itself: a corner sharper
    than the vehicle turns is kept and reported."""
    noisy = noise_m > settings.min_step_m
    window = max(settings.smooth_window_m, settings.noisy_window_per_m * noise_m) if noisy else settings.smooth_window_m
    xyz, yaw = build_route(kept, settings, window)
    kappa, at = sharpest(xyz)
    while noisy and kappa > max_curvature and window < settings.max_window_m:
        window = min(window * 1.25, settings.max_window_m)
        xyz, yaw = build_route(kept, settings, window)
        kappa, at = sharpest(xyz)
    notes = []
    if noisy:
        notes.append(
            f"fixes without RTK wander ~{noise_m:.1f} m (HDOP x {settings.uere_m:g} m): standstills collapsed to "
            f"one point each, x, y smoothed over {window:.0f} m"
        )
    if kappa > max_curvature:
        notes.append(
            f"warning: a turn of radius {1 / kappa:.1f} m at s = {at:.0f} m is sharper than the vehicle "
            f"can steer (radius {1 / max_curvature:.1f} m)"
        )
    return xyz, yaw, window, notes


def write_route_csv(path: Path, xyz: np.ndarray, yaw: np.ndarray, comments: list[str]) -> None:
    """Written to a temporary file and renamed, so a failure never leaves half a route."""
    path.parent.mkdir(parents=True, exist_ok=True)
    lines = [f"# {c}" for c in comments] + ["x,y,z,yaw"]
    lines += [f"{x:.4f},{y:.4f},{z:.4f},{a:.5f}" for (x, y, z), a in zip(xyz, yaw)]
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "w") as f:
            f.write("\n".join(lines) + "\n")
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


# ---- the whole import -----------------------------------------------------------------------


@dataclass
class Recording:
    """What a recording gave: its points in the local frame and, from an NMEA log, the log itself
    and the frame's origin."""

    fmt: str
    points: np.ndarray
    log: NmeaLog | None = None
    origin: UtmOrigin | None = None
    origin_source: str = ""


@dataclass
class Fitted:
    """The route fitted through a recording's points, with what the fitting did."""

    kept: np.ndarray  # the points left after the standstills
    xyz: np.ndarray
    yaw: np.ndarray
    window_m: float
    noise_m: float  # 0 for RTK (or no quality given)
    notes: list[str]


def import_route(
    source: str | Path,
    output: str | Path | None = None,
    fmt: str = "auto",
    spacing_m: float | None = None,
    strict: bool = False,
    cfg: Mapping | None = None,
) -> ImportResult:
    """Read a recording, build the route, write it to `output` (if given)."""
    source = Path(source)
    if fmt not in FORMATS:
        raise RouteImportError(f"unknown format {fmt!r}; one of {', '.join(FORMATS)}")
    cfg = cfg if cfg is not None else config.current()
    settings = import_settings(cfg, spacing_m)
    recording = read_recording(source, fmt, strict, config.core(cfg).origin_utm)
    vehicle = config.load_vehicle(config.core(cfg).vehicle)
    fitted = fit_recording(recording, source.name, settings, vehicle.max_curvature)
    gap, closed = loop_closure(fitted.xyz, settings.loop_close_m)
    result = ImportResult(
        source=source.name,
        fmt=recording.fmt,
        points_in=len(recording.points),
        kept=len(fitted.kept),
        xyz=fitted.xyz,
        yaw=fitted.yaw,
        spacing_m=settings.spacing_m,
        closed_loop=closed,
        loop_gap_m=gap,
        log=recording.log,
        origin=recording.origin,
        origin_source=recording.origin_source,
        window_m=fitted.window_m,
        noise_m=fitted.noise_m,
        notes=fitted.notes,
    )
    if output is not None:
        write_result(result, Path(output), settings.road_width_m)
    return result


def import_settings(cfg: Mapping, spacing_m: float | None) -> RouteImportSettings:
    """The route_import section, with the spacing asked on the command line."""
    settings = config.section(cfg, "route_import", RouteImportSettings)
    if spacing_m is None:
        return settings
    if not (spacing_m > 0 and math.isfinite(spacing_m)):
        raise RouteImportError(f"spacing must be a positive number of metres, got {spacing_m}")
    return settings.model_copy(update={"spacing_m": float(spacing_m)})


def read_recording(source: Path, fmt: str, strict: bool, configured_origin: UtmOrigin) -> Recording:
    """The recording's points: an NMEA log's fixes (u-blox binary frames and a binary log's
    noise left out) projected in the route's frame, or a CSV's rows."""
    try:
        data = source.read_bytes()
    except OSError as exc:
        raise RouteImportError(f"{source}: cannot read: {exc.strerror}") from None
    name = source.name
    data, ubx_frames = strip_ubx(data)
    broken: dict[str, int] = {}
    if b"\x00" in data[:65536]:
        nul = data.index(bytes(1))
        data, broken = nmea_of_binary(data)
        if not data:
            raise RouteImportError(f"{name}: not a text file (byte {nul} is NUL), and no NMEA sentence in it")
    if fmt == "auto":
        detected = detect_format(data)
        if detected is None:
            raise RouteImportError(
                f"{name}: no points: neither NMEA sentences nor rows of x,y[,z] metres "
                f"in its first {DETECT_LINES} lines"
            )
        fmt = detected
    if fmt != "nmea":
        points = read_csv_points(data, name)
        if len(points) == 0:
            raise RouteImportError(f"{name}: no points (expected lines of x,y[,z] metres)")
        return Recording(fmt, points)
    log = read_nmea_log(data, name, strict)
    log.ubx_frames = ubx_frames
    log.broken_binary = broken
    if not log.fixes:
        detail = f" ({_counts(log.no_fix)} without a fix)" if log.no_fix else ""
        raise RouteImportError(f"{name}: no usable position (GGA, RMC or GLL) in the log{detail}")
    origin, origin_source = frame_for(log, configured_origin)
    points = project_fixes(log, LocalFrame(origin), name, strict)
    if len(points) == 0:
        raise RouteImportError(f"{name}: no fix within {origin.reach_km:g} km of the route's origin")
    return Recording(fmt, points, log, origin, origin_source)


def fit_recording(recording: Recording, name: str, settings: RouteImportSettings, max_curvature: float) -> Fitted:
    """Standstills dropped (RTK) or collapsed (wandering fixes), the route fitted through what is
    left, its grade limited."""
    points = recording.points
    radii = wander_radii(recording.log, len(points), settings)
    noise = float(np.median(radii))
    noisy = noise > settings.min_step_m
    kept = collapse_standstill(points, radii) if noisy else drop_standstill(points, settings.min_step_m)
    if len(kept) < 2:
        raise RouteImportError(
            f"{name}: the recording never moves: all {len(points)} points lie within "
            f"{settings.min_step_m:g} m of the first"
        )
    stood_still(points, drop_standstill(points, settings.min_step_m), name, settings.stood_still_m)
    noise_m = noise if noisy else 0.0
    xyz, yaw, window, notes = fit_route(kept, noise_m, settings, max_curvature)
    s = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(xyz[:, 0]), np.diff(xyz[:, 1])))])
    xyz[:, 2], clipped_m = limit_grade(s, xyz[:, 2], settings.max_grade)
    if clipped_m > 0:
        notes.append(f"grade limited to {settings.max_grade:.0%} over {clipped_m:.0f} m of the route")
    notes.append(f"road width {settings.road_width_m:g} m (route_import.road_width_m)")
    return Fitted(kept, xyz, yaw, window, noise_m, notes)


def loop_closure(xyz: np.ndarray, loop_close_m: float) -> tuple[float, bool]:
    """(the gap from the last point to the first, whether the drive was a loop)."""
    gap = float(math.hypot(xyz[-1, 0] - xyz[0, 0], xyz[-1, 1] - xyz[0, 1]))
    length = float(np.sum(np.hypot(np.diff(xyz[:, 0]), np.diff(xyz[:, 1]))))
    # a loop must be long compared with the gap, or a short back-and-forth would count
    return gap, gap <= loop_close_m and length > 10 * loop_close_m


def write_result(result: ImportResult, output: Path, road_width_m: float) -> None:
    """The route file, its header saying where it came from; `result.output` then names it."""
    comments = [
        f"ares route: source={result.source}, points={len(result.xyz)}, length_m={result.length_m:.2f}",
        f"format={result.fmt}, points_in={result.points_in}, kept={result.kept}, spacing_m={result.spacing_m:g}, "
        f"closed_loop={'yes (written as an open route)' if result.closed_loop else 'no'}",
        width_comment(road_width_m),
    ]
    if result.origin is not None:
        comments.append(origin_comment(result.origin))
    try:
        write_route_csv(output, result.xyz, result.yaw, comments)
    except OSError as exc:
        raise RouteImportError(f"{output}: cannot write: {exc.strerror}") from None
    result.output = str(output)
