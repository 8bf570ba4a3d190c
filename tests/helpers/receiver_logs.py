"""NMEA logs as real receivers and loggers write them, for route-import tests.

Written from the NMEA 0183 sentence formats (GGA, RMC, GLL, GSA, GSV, VTG, ZDA; instruments'
DPT, HDG, MWV; proprietary $PUBX / $PGRME; AIS !AIVDM; NMEA 4 tag blocks), with the habits of
different receivers: a header and comment lines (some not ASCII), CRLF line ends, whole-second
times, integer or missing altitudes, empty geoid separations, no-fix lines before the first fix,
the same epoch from two talkers, timestamp prefixes, the odd corrupted line.

A drive is a route in local metres driven along a speed profile (slow in curves, ramps in and
out of rest); `Receiver` says how one kind of receiver reports it, and `write_log` places the
drive on the Earth at a latitude and longitude and returns the log's lines.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ares.core.geodesy import LocalFrame, origin_at
from ares.core.nmea_framing import sentence
from ares.core.route import Route


def drive_times(
    route: Route,
    hz: float,
    stop_s: float | None = None,
    wait_s: float = 0.0,
    cruise: float = 3.5,
    lateral_accel: float = 0.35,
    accel: float = 0.5,
) -> tuple[np.ndarray, np.ndarray]:
    """(t, s) sampled at `hz` for a drive from s = 0 to the end: speed limited by the curvature
    and by accel/decel ramps, starting and ending at rest, waiting wait_s at stop_s."""
    ds = 0.25
    s = np.arange(0.0, route.length, ds)
    k = np.abs(np.interp(s, route.s, route.curvature))
    v = np.clip(np.sqrt(lateral_accel / np.maximum(k, 1e-9)), 1.0, cruise)
    stop_i = int(stop_s / ds) if stop_s is not None else None
    v[0] = v[-1] = 0.0
    if stop_i is not None:
        v[stop_i] = 0.0
    for i in range(1, len(s)):  # accelerate out of every stop...
        v[i] = min(v[i], math.sqrt(v[i - 1] ** 2 + 2 * accel * ds))
    for i in range(len(s) - 2, -1, -1):  # ...and brake into it
        v[i] = min(v[i], math.sqrt(v[i + 1] ** 2 + 2 * accel * ds))
    t = np.concatenate([[0.0], np.cumsum(ds / ((v[1:] + v[:-1]) / 2))])
    if stop_i is not None:  # the wait: time passes, s does not
        t[stop_i + 1 :] += wait_s
        s, t = np.insert(s, stop_i + 1, s[stop_i]), np.insert(t, stop_i + 1, t[stop_i] + wait_s)
    times = np.arange(0.0, t[-1], 1.0 / hz)
    return times, np.interp(times, t, s)


@dataclass
class Receiver:
    """How one receiver (and the logger behind it) writes a drive."""

    name: str
    talker: str = "GN"
    hz: float = 5.0
    time_decimals: int = 2  # 0: hhmmss, as older receivers send
    quality: int = 4  # GGA fix quality while driving
    altitude: str = "decimal"  # "decimal", "integer" or "empty"
    geoid: str = "47.0,M"  # the geoid separation and its unit, as sent ("" -> ",")
    position_sentences: tuple[str, ...] = ("RMC", "GGA")  # in the order sent each epoch
    also_gga_from: str | None = None  # a second talker sending the same epoch's GGA
    others: tuple[str, ...] = ("VTG", "GSA", "GSV", "GLL", "ZDA")
    instruments: bool = False  # depth, heading, wind and AIS lines between the fixes
    proprietary: str | None = None  # "PUBX" (u-blox) or "PGRME" (Garmin)
    header: list[str] = field(default_factory=list)
    prefix: str = ""  # "time": each line after an ISO timestamp; "tag": a tag block
    no_fix_epochs: int = 3  # epochs without a fix before the first
    corrupt_every: int = 0  # every n-th line has a broken checksum (0: none)
    crlf: bool = True
    noise_m: float = 0.005  # RTK: millimetres


def _lat(value: float) -> tuple[str, str]:
    a = abs(value)
    return f"{int(a):02d}{(a - int(a)) * 60:011.8f}", "N" if value >= 0 else "S"


def _lon(value: float) -> tuple[str, str]:
    a = abs(value)
    return f"{int(a):03d}{(a - int(a)) * 60:011.8f}", "E" if value >= 0 else "W"


def _hhmmss(t: float, decimals: int) -> str:
    t = t % 86400.0
    h, m = int(t // 3600), int(t % 3600 // 60)
    sec = t - h * 3600 - m * 60
    if decimals == 0:
        return f"{h:02d}{m:02d}{int(sec):02d}"
    return f"{h:02d}{m:02d}{sec:0{3 + decimals}.{decimals}f}"


def _epoch(
    rx: Receiver, t: float, lat: float | None, lon: float | None, alt: float, speed: float, course: float, date: str
) -> list[str]:
    """The sentences of one epoch (bodies, without '$' and checksum)."""
    time = _hhmmss(t, rx.time_decimals)
    out = []
    fix = lat is not None
    la, ns = _lat(lat) if fix else ("", "")
    lo, ew = _lon(lon) if fix else ("", "")
    alt_text = {"decimal": f"{alt:.1f}", "integer": f"{round(alt)}", "empty": ""}[rx.altitude] if fix else ""
    knots = speed / 0.514444
    for kind in rx.position_sentences:
        if kind == "GGA":
            q = rx.quality if fix else 0
            geoid = rx.geoid if fix else ","
            gga = (
                f"GGA,{time},{la},{ns},{lo},{ew},{q},{12 if fix else 0:02d},{0.7 if fix else 99.99},"
                f"{alt_text},{'M' if alt_text else ''},{geoid},{'1.0' if q == 4 else ''},{'0001' if q == 4 else ''}"
            )
            out.append(rx.talker + gga)
            if rx.also_gga_from:
                out.append(rx.also_gga_from + gga)
        elif kind == "RMC":
            status, mode = ("A", "R" if rx.quality == 4 else "A") if fix else ("V", "N")
            out.append(f"{rx.talker}RMC,{time},{status},{la},{ns},{lo},{ew},{knots:.3f},{course:.2f},{date},,,{mode}")
        elif kind == "GLL":
            out.append(f"{rx.talker}GLL,{la},{ns},{lo},{ew},{time},{'A' if fix else 'V'},{'D' if fix else 'N'}")
    for kind in rx.others:
        if kind == "VTG":
            out.append(f"{rx.talker}VTG,{course:.2f},T,,M,{knots:.3f},N,{speed * 3.6:.3f},K,{'D' if fix else 'N'}")
        elif kind == "GSA":
            out.append(f"{rx.talker}GSA,A,{3 if fix else 1},02,05,07,13,15,20,29,,,,,,1.32,0.70,1.12")
        elif kind == "GSV":
            out += [
                "GPGSV,3,1,10,02,45,123,44,05,60,240,46,07,12,310,38,13,33,045,41",
                "GPGSV,3,2,10,15,20,170,40,20,70,300,47,29,25,080,42,30,05,200,",
                "GPGSV,3,3,10,36,30,150,39,49,32,210,40",
                "GLGSV,1,1,03,65,40,050,43,72,15,260,36,81,55,130,45",
            ]
        elif kind == "ZDA":
            out.append(f"{rx.talker}ZDA,{time},{date[:2]},{date[2:4]},20{date[4:]},00,00")
    if rx.proprietary == "PUBX":
        out.append(
            f"PUBX,00,{time},{la},{ns},{lo},{ew},{alt_text},{'R2' if fix else 'NF'},0.01,0.02,0.0,0.00,0.0,,"
            f"0.70,1.12,0.80,12,0,0"
        )
    elif rx.proprietary == "PGRME":
        out.append("PGRME,2.3,M,3.5,M,4.2,M")
    return out


def _instruments(t: float, course: float) -> list[str]:
    lines = [
        f"SDDPT,{4.0 + math.sin(t / 7):.1f},0.3",
        f"HCHDG,{course:.1f},,,2.1,E",
        f"WIMWV,{(course + 40) % 360:.1f},R,{5 + math.sin(t / 3):.1f},N,A",
    ]
    return [sentence(body) for body in lines]


AIS = "!AIVDM,1,1,,A,13aEOK?P00PD2wVMdLDRhgvL289?,0*26"


def write_log(
    route: Route,
    lat0: float,
    lon0: float,
    alt0: float,
    rx: Receiver,
    seed: int = 5,
    start_utc_s: float = 9 * 3600 + 47 * 60 + 30,
    date: str = "231126",
) -> list[str]:
    """The log of `route` (local metres) driven with its start at lat0, lon0, alt0, as `rx` writes it."""
    frame = LocalFrame(origin_at(lat0, lon0, alt0))
    rng = np.random.default_rng(seed)
    times, s = drive_times(route, rx.hz)
    bodies: list[list[str]] = []
    for k in range(rx.no_fix_epochs):
        bodies.append(
            [
                sentence(b)
                for b in _epoch(rx, start_utc_s - (rx.no_fix_epochs - k) / rx.hz, None, None, 0.0, 0.0, 0.0, date)
            ]
        )
    for i, (ti, si) in enumerate(zip(times, s)):
        x, y, z, yaw = route.point_at(float(si))
        ex, ey = rng.normal(0.0, rx.noise_m, 2)
        lat, lon = frame.to_latlon(x + ex, y + ey)
        speed = 0.0 if i == 0 else float(s[i] - s[i - 1]) * rx.hz
        course = math.degrees(math.pi / 2 - yaw) % 360.0
        epoch = [sentence(b) for b in _epoch(rx, start_utc_s + ti, lat, lon, alt0 + z, speed, course, date)]
        if rx.instruments:
            epoch += _instruments(ti, course) + ([AIS] if i % 10 == 0 else [])
        bodies.append(epoch)
    lines = list(rx.header)
    n = 0
    for k, epoch in enumerate(bodies):
        for line in epoch:
            n += 1
            if rx.corrupt_every and n % rx.corrupt_every == 0:
                line = line[:-2] + ("00" if line[-2:] != "00" else "01")  # a serial glitch
            if rx.prefix == "time":
                seconds = start_utc_s + (k - rx.no_fix_epochs) / rx.hz
                line = (
                    f"2026-11-23T{_hhmmss(seconds, 0)[:2]}:{_hhmmss(seconds, 0)[2:4]}:{_hhmmss(seconds, 0)[4:]}Z {line}"
                )
            elif rx.prefix == "tag":
                tag = f"s:logger,c:{1795427250 + k // 5}"
                line = f"\\{tag}*{_xor(tag)}\\{line}"
            lines.append(line)
    return lines


def _xor(text: str) -> str:
    cs = 0
    for ch in text:
        cs ^= ord(ch)
    return f"{cs:02X}"


def log_bytes(lines: list[str], rx: Receiver) -> bytes:
    """The file as the logger wrote it (CRLF or LF; UTF-8, so a header may hold any character)."""
    end = "\r\n" if rx.crlf else "\n"
    return (end.join(lines) + end).encode("utf-8")


# ---- the receivers of the tests ------------------------------------------------------------------

UBLOX_F9P = Receiver(
    "u-blox F9P, RTK, with a u-center header",
    talker="GN",
    hz=5.0,
    proprietary="PUBX",
    header=[
        "u-center 23.08 log — Fahrt über den Campus (Prüfung Nr. 3)",
        "# receiver: ZED-F9P HPG 1.32, 5 Hz",
        "# port: COM7 @ 115200 baud",
        "",
    ],
    also_gga_from="GP",
    corrupt_every=997,
)

OLD_GARMIN = Receiver(
    "an older receiver: whole seconds, integer altitude, no geoid, DGPS",
    talker="GP",
    hz=1.0,
    time_decimals=0,
    quality=2,
    altitude="integer",
    geoid=",",
    position_sentences=("GGA", "RMC"),
    others=("GSA", "GSV"),
    proprietary="PGRME",
    header=["Track log exported 23.11.2026", "Séance d'essai — parcours côtier"],
    crlf=True,
    corrupt_every=503,
)

MARINE_LOGGER = Receiver(
    "a multiplexing logger: RMC and GLL only, instruments, AIS, timestamps before each line",
    talker="GP",
    hz=2.0,
    position_sentences=("RMC", "GLL"),
    others=("VTG",),
    instruments=True,
    prefix="time",
    header=["; NMEA multiplexer log", "; inputs: GPS, echo sounder, compass, anemometer, AIS"],
    crlf=False,
)

TAGGED_GLL = Receiver(
    "NMEA 4 tag blocks, GLL positions only, no altitude",
    talker="GA",
    hz=5.0,
    position_sentences=("GLL",),
    others=("ZDA",),
    prefix="tag",
    header=[],
    no_fix_epochs=2,
)
