"""Receiver logs as receivers write them (tests/receiver_logs.py), imported with no options:
format told from the content, every line counted, the positions of the right sentence type used,
the route in a frame at its own origin anywhere on Earth, continuous across a UTM zone boundary.
"""

from __future__ import annotations

import dataclasses
import math
import subprocess
import sys

import numpy as np
import pytest

from ares.app import run_config, stack
from ares.app.route_import import detect_format, import_route
from ares.core import config
from ares.core.clock import ManualClock
from ares.core.geodesy import origin_at
from ares.core.membus import MemoryNetwork
from ares.core.messages import GnssSentences
from ares.core.route import Route, RouteError, origin_comment, read_origin
from perception.gnss_node import GnssNode
from tests.helpers.gnss import PLACES, short_road
from tests.helpers.receiver_logs import MARINE_LOGGER, OLD_GARMIN, TAGGED_GLL, UBLOX_F9P, Receiver, log_bytes, write_log
from tests.helpers.roads import deviations
from tests.helpers.stack import REPO

CFG = run_config.build()


CASES = [
    (UBLOX_F9P, "across 12 E"),
    (OLD_GARMIN, "hobart"),
    (MARINE_LOGGER, "across 150 E, south"),
    (TAGGED_GLL, "equator"),
    (UBLOX_F9P, "munich"),
]


def write(tmp_path, rx: Receiver, place: str) -> tuple[Route, bytes, str]:
    lat, lon, alt, heading = PLACES[place]
    truth = short_road(heading)
    data = log_bytes(write_log(truth, lat, lon, alt, rx), rx)
    path = tmp_path / f"{place.replace(' ', '_').replace(',', '')}.nmea"
    path.write_bytes(data)
    return truth, data, str(path)


@pytest.mark.parametrize("rx, place", CASES, ids=[f"{rx.name.split(':')[0]} @ {p}" for rx, p in CASES])
def test_a_receivers_log_imports_as_it_comes(tmp_path, rx, place):
    truth, data, path = write(tmp_path, rx, place)
    assert detect_format(data) == "nmea"
    result = import_route(path, tmp_path / "route.csv", cfg=CFG)
    log = result.log

    # the positions: GGA when there is one, else RMC, else GLL; one per epoch
    used = next(k for k in ("GGA", "RMC", "GLL") if k in rx.position_sentences)
    assert log.used == used
    if rx.also_gga_from:  # the second talker's GGA of each epoch (but where a glitch hit the first)
        assert len(log.fixes) - 3 <= log.same_epoch <= len(log.fixes)
    else:
        assert log.same_epoch == 0
    talkers = {k: 2 if k == "GGA" and rx.also_gga_from else 1 for k in rx.position_sentences}
    assert dict(log.no_fix) == {k: rx.no_fix_epochs * n for k, n in talkers.items()}
    assert log.text_lines == sum(1 for h in rx.header if h.strip())
    assert sum(log.bad.values()) == (_line_count(data, rx) // rx.corrupt_every if rx.corrupt_every else 0)
    assert set(log.bad) <= {"checksum"} and log.far == 0
    assert len(log.fixes) > 80

    # anywhere on Earth: a frame at the drive's first fix, continuous across a zone boundary
    lat, lon, alt, _ = PLACES[place]
    assert result.origin_source == "first fix"
    expected = origin_at(lat, lon, alt)
    assert (result.origin.zone, result.origin.hemisphere) == (expected.zone, expected.hemisphere)
    assert math.hypot(result.origin.easting - expected.easting, result.origin.northing - expected.northing) < 0.05
    if rx.altitude == "empty" or used != "GGA":
        assert log.no_altitude == len(log.fixes) and np.all(result.xyz[:, 2] == 0.0)
    else:
        assert abs(result.origin.altitude_m - alt) < (1.0 if rx.altitude == "integer" else 0.1)
    steps = np.hypot(*np.diff(result.xyz[:, :2], axis=0).T)
    assert steps.max() < 0.51 and steps.min() > 0.49

    # the road's own shape, within centimetres (the 2 Hz logs cut the hairpin a little)
    dist, _, _ = deviations(result.xyz, truth)
    assert math.sqrt(np.mean(dist**2)) < (0.02 if rx.hz >= 5 else 0.05) and dist.max() < 0.15
    assert result.length_m == pytest.approx(truth.length, rel=0.01)

    # the file carries its origin; the summary says what was used and what was skipped
    back = Route.from_csv(tmp_path / "route.csv")
    assert back.origin == result.origin == read_origin(tmp_path / "route.csv")
    summary = result.summary()
    assert f"{result.points_in} {used} fixes in" in summary and "origin (the first fix): UTM" in summary
    if rx.header:
        assert "comment or header lines" in summary
    if rx.instruments:
        assert "SDDPT" in summary and "HCHDG" in summary and "!AIVDM" in summary
    if rx.corrupt_every:
        assert "bad lines: checksum" in summary


def _line_count(data: bytes, rx: Receiver) -> int:
    return sum(1 for line in data.splitlines() if line.strip()) - sum(1 for h in rx.header if h.strip())


def test_the_cli_imports_a_log_with_no_options_and_prints_what_it_used_and_skipped(tmp_path):
    _, _, path = write(tmp_path, MARINE_LOGGER, "hobart")
    done = subprocess.run(
        [sys.executable, "-m", "ares.cli", "route", "import", path, "-o", str(tmp_path / "r.csv")],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 0, done.stderr
    out = done.stdout
    assert out.startswith("imported hobart.nmea -> ") and "RMC fixes in" in out
    assert "skipped, no position used:" in out and "GPGLL" in out and "positions taken from RMC" in out
    assert "skipped, no fix: GLL 3, RMC 3" in out and "skipped, comment or header lines: 2" in out
    assert "UTM 55S" in out and "warning: positions from RMC carry no fix quality" in out


def test_a_run_on_a_route_with_an_origin_uses_it(tmp_path):
    _, _, path = write(tmp_path, OLD_GARMIN, "hobart")
    import_route(path, tmp_path / "r.csv", cfg=CFG)
    cfg = stack.prepare((), {"route_file": str(tmp_path / "r.csv")}, 1.0)
    origin = read_origin(tmp_path / "r.csv")
    assert config.core(cfg).origin_utm == origin.model_copy(update={"reach_km": 100.0})
    assert (cfg["origin_utm"]["zone"], cfg["origin_utm"]["hemisphere"]) == (55, "S")
    # a route without one (a CSV of metres) runs in the configured frame
    (tmp_path / "plain.csv").write_text("x,y\n0,0\n50,0\n")
    assert stack.prepare((), {"route_file": str(tmp_path / "plain.csv")}, 1.0)["origin_utm"] == CFG["origin_utm"]


def test_the_origin_line_is_read_back_exactly_and_a_bad_one_is_a_clear_error(tmp_path):
    origin = origin_at(-33.9, 149.9993, 60.0)
    path = tmp_path / "r.csv"
    path.write_text(f"# {origin_comment(origin)}\nx,y\n0,0\n10,0\n")
    assert read_origin(path) == origin
    path.write_text("# origin: lat=-33.9, lon=149.9993, altitude_m=60\nx,y\n0,0\n10,0\n")  # zone from position
    assert read_origin(path).zone == 55
    for line, words in [
        ("lat=-33.9, lon=150.0", "needs altitude_m"),
        ("lat=x, lon=1, altitude_m=0", "float"),
        ("lat=1, lon=1, altitude_m=0, colour=red", "unknown origin key 'colour'"),
        ("lat=1, lon=1, altitude_m=0, easting=1", "disagree"),
        ("lat=89, lon=1, altitude_m=0", "no UTM coordinates"),
    ]:
        path.write_text(f"# origin: {line}\nx,y\n0,0\n10,0\n")
        with pytest.raises(RouteError, match=words):
            Route.from_csv(path)


def test_the_gnss_node_takes_a_receivers_habits_in_the_routes_frame():
    """Whole-second times, integer altitudes, empty geoid separations, other talkers and
    sentences: fixes, not rejections."""
    lat, lon, alt, heading = PLACES["hobart"]
    lines = write_log(short_road(heading), lat, lon, alt, dataclasses.replace(OLD_GARMIN, corrupt_every=0, header=[]))
    cfg = run_config.build(overrides={"origin_utm": origin_at(lat, lon, alt).model_dump()})
    network, clock = MemoryNetwork(), ManualClock()
    node = GnssNode(cfg, clock=clock, bus=network.bus("gnss", clock))
    node.setup()
    test = network.bus("test", clock)
    fixes = test.subscribe("gnss/fix", queue=2000)
    for k in range(0, len(lines), 4):  # four lines at a time, as a serial read gives them
        t = 1.0 + k / 10
        test.publish("sensors/gnss", GnssSentences(t=t, sentences=lines[k : k + 4]))
        clock.set(t)
        node.step_once(t)
    got = [f for _, f in fixes.drain()]
    gga_with_fix = sum(1 for line in lines if line.startswith("$GPGGA") and ",2,12," in line)
    assert len(got) == gga_with_fix > 30
    assert all(f.quality == 2 and f.z is not None and abs(f.z - round(f.z)) < 1e-9 for f in got)
    assert node.reader.total_rejected == node.reader.rejected["no fix"] == OLD_GARMIN.no_fix_epochs * 2
    node.bus.close()
