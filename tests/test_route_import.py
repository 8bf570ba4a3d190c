"""`ares route import` / `ares route record` (ares/app/route_import.py): recorded drives -> route files.

The NMEA logs here are "driven" by sampling a route at 5 Hz along a speed profile (slow in
curves, a 60 s wait at a stop) through the simulator's own GNSS model with its RTK noise.
"""

from __future__ import annotations

import math
import os
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from ares import cli
from ares.app import run_config
from ares.app.route_import import (
    RouteImportError,
    RouteImportSettings,
    collapse_standstill,
    detect_format,
    drop_standstill,
    import_route,
    limit_grade,
    project_fixes,
    read_nmea_log,
    resample_even,
)
from ares.core import config
from ares.core.bus import Bus
from ares.core.clock import WallClock
from ares.core.config import load_vehicle
from ares.core.geodesy import LocalFrame
from ares.core.localhost import free_port
from ares.core.messages import GnssSentences
from ares.core.nmea_framing import sentence as nmea_sentence
from ares.core.route import Route, RouteError
from simulator.params import SimParams
from simulator.sensors import GnssSensor
from simulator.vehicle import VehicleState
from tests.helpers.receiver_logs import drive_times
from tests.helpers.roads import deviations, road
from tests.helpers.stack import REPO

CFG = run_config.build()
SIM_GNSS = config.section(CFG, "sim", SimParams).gnss
FRAME = LocalFrame(config.core(CFG).origin_utm)
TOUR = Route.from_tour("default")
# the tour's geometry without its rtk_loss zones: a route is recorded with RTK corrections
TOUR_GEOMETRY = Route(name="tour geometry", x=TOUR.x, y=TOUR.y, z=TOUR.z, closed=True, width=TOUR.width)
STOP_S, WAIT_S, HZ = 300.0, 60.0, 5.0


# ---- making recordings ---------------------------------------------------------------------------


def drive_log(
    route: Route, seed: int = 3, stop_s: float | None = STOP_S, wait_s: float = WAIT_S, hz: float = HZ, **profile
) -> list[str]:
    """NMEA (GGA + GST) of a drive from s = 0 to the end through the simulator's GNSS model,
    recorded at `hz`, waiting wait_s at stop_s."""
    times, s = drive_times(route, hz, stop_s, wait_s, **profile)
    gnss = GnssSensor(route, SIM_GNSS, FRAME, rng=np.random.default_rng(seed), noise=True)
    lines = []
    for ti, si in zip(times, s):
        x, y, z, _ = route.point_at(si)
        lines += gnss.measure(VehicleState(t=float(ti), x=x, y=y, z=z, s=float(si)))["sentences"]
    return lines


# a campus service road, ~470 m: bends of 12-30 m radius, a hairpin of 14 m, a gentle hill
CAMPUS_ROAD = [
    ("L", 40),
    ("A", 25, 90),
    ("L", 35),
    ("A", 14, -180),
    ("L", 30),
    ("A", 30, 60),
    ("L", 45),
    ("A", 12, 90),
    ("L", 40),
    ("A", 20, -75),
    ("L", 60),
]


def campus_road_truth() -> Route:
    xy = road(CAMPUS_ROAD, start=(-80.0, -60.0))
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])
    z = 4.0 * np.sin(math.pi * s / s[-1])  # over a low hill: grades under 3 %
    return Route(name="campus road", x=xy[:, 0], y=xy[:, 1], z=z, closed=False, width=np.full(len(xy), 5.0))


def write_campus_road_csv(path: Path, every_m: float = 1.0) -> Route:
    """The campus road as a CSV of x,y,z every `every_m` metres (a few hundred points)."""
    truth = campus_road_truth()
    s = np.linspace(0.0, truth.s[-1], int(truth.s[-1] / every_m) + 1)
    rows = ["x,y,z"] + [
        f"{np.interp(v, truth.s, truth.x):.3f},{np.interp(v, truth.s, truth.y):.3f},"
        f"{np.interp(v, truth.s, truth.z):.3f}"
        for v in s
    ]
    path.write_text("\n".join(rows) + "\n")
    return truth


# ---- measuring routes ----------------------------------------------------------------------------


def angle_diff(a, b):
    return np.angle(np.exp(1j * (np.asarray(a) - np.asarray(b))))


@pytest.fixture(scope="module")
def tour_import(tmp_path_factory):
    directory = tmp_path_factory.mktemp("tour")
    log = directory / "tour_drive.nmea"
    log.write_text("\n".join(drive_log(TOUR_GEOMETRY)) + "\n")
    out = directory / "tour_route.csv"
    return log, import_route(log, out, cfg=CFG), out


# ---- NMEA import -----------------------------------------------------------------------------------


def test_nmea_log_of_the_tour_gives_its_geometry_within_centimetres(tour_import):
    _, result, out = tour_import
    dist, yaw_true, z_true = deviations(result.xyz, TOUR_GEOMETRY)
    assert math.sqrt(np.mean(dist**2)) < 0.01 and dist.max() < 0.03
    assert np.abs(angle_diff(result.yaw, yaw_true)).max() < 0.03  # yaw from adjacent poses
    assert np.abs(result.xyz[:, 2] - z_true).max() < 0.05  # z kept (the tour climbs 10 m)
    # and no stretch is missing: every point of the tour lies on the imported route
    back = Route.from_csv(out)
    covered, _, _ = deviations(np.column_stack([TOUR_GEOMETRY.x, TOUR_GEOMETRY.y]), back, start_s=0.0)
    assert covered.max() < 0.03
    assert back.length == pytest.approx(TOUR_GEOMETRY.length, rel=0.002)


def test_the_standstill_is_de_duplicated(tour_import):
    log, result, _ = tour_import
    raw = project_fixes(read_nmea_log(log.read_bytes(), log.name), FRAME, log.name)
    assert result.points_in == len(raw)
    assert result.points_in - result.kept >= WAIT_S * HZ - 5  # the 60 s wait, ~300 fixes
    stop = np.array(TOUR_GEOMETRY.point_at(STOP_S)[:2])
    at_stop = lambda pts: int(np.sum(np.hypot(*(pts[:, :2] - stop).T) < 0.05))  # noqa: E731
    assert at_stop(raw) >= WAIT_S * HZ
    kept = drop_standstill(raw, 0.1)
    assert len(kept) == result.kept and at_stop(kept) <= 1
    assert np.hypot(*np.diff(kept[:, :2], axis=0).T).min() >= 0.1
    # around the stop the route is as straight as the road (no tangle of noise)
    back = Route.from_csv(tour_import[2])
    near = np.abs(back.s - STOP_S) < 5.0
    assert np.abs(back.curvature[near]).max() < 0.03


def test_the_written_file_is_an_evenly_spaced_open_route_with_its_summary(tour_import):
    log, result, out = tour_import
    text = out.read_text().splitlines()
    assert text[0].startswith(f"# ares route: source={log.name}, points={len(result.xyz)}, length_m=")
    assert "x,y,z,yaw" in text
    step = np.hypot(*np.diff(result.xyz[:, :2], axis=0).T)
    assert step == pytest.approx(0.5, abs=0.005)
    assert result.closed_loop and result.loop_gap_m < 1.0
    summary = result.summary()
    assert f"{result.points_in} GGA fixes in, {result.kept} kept" in summary
    assert "origin (the configured one)" in summary and result.origin == config.core(CFG).origin_utm
    assert Route.from_csv(out).origin == result.origin
    assert "closed loop detected" in summary and "open route" in summary and "length 15" in summary
    assert not Route.from_csv(out).closed


def test_noise_free_log_lands_on_the_geometry_and_no_stop_means_nothing_to_drop(tmp_path):
    line = Route(
        name="line",
        x=np.array([0.0, 50.0]),
        y=np.array([0.0, 20.0]),
        z=np.zeros(2),
        closed=False,
        width=np.full(2, 4.0),
    )
    gnss = GnssSensor(line, SIM_GNSS, FRAME, noise=False)
    lines = []
    for i in range(60):
        x, y, z, _ = line.point_at(i * 0.9)
        lines += gnss.measure(VehicleState(t=i * 0.2, x=x, y=y, z=z))["sentences"]
    path = tmp_path / "line.nmea"
    path.write_text("\n".join(lines))
    result = import_route(path, cfg=CFG)
    assert result.kept == result.points_in == 60 and not result.closed_loop
    dist, _, _ = deviations(result.xyz, line)
    assert dist.max() < 1e-3 and np.abs(angle_diff(result.yaw, math.atan2(20, 50))).max() < 1e-3


# ---- CSV import ------------------------------------------------------------------------------------


def test_csv_of_a_campus_road_keeps_its_geometry(tmp_path):
    src = tmp_path / "campus_road.csv"
    truth = write_campus_road_csv(src)
    result = import_route(src, tmp_path / "route.csv", cfg=CFG)
    assert 300 <= result.points_in <= 600 and result.fmt == "csv" and not result.closed_loop
    dist, yaw_true, z_true = deviations(result.xyz, truth)
    # points every metre on a 12 m arc are chords 1 cm inside it: the import may not add much
    assert math.sqrt(np.mean(dist**2)) < 0.01 and dist.max() < 0.02
    # (the smoothing eases the jump of curvature where a straight meets an arc: ~1 deg there)
    assert np.abs(angle_diff(result.yaw, yaw_true)).max() < 0.03
    assert result.length_m == pytest.approx(truth.length, rel=0.002)
    assert np.abs(result.xyz[:, 2] - z_true).max() < 0.02
    assert Route.from_csv(tmp_path / "route.csv").length == pytest.approx(result.length_m, rel=1e-3)


@pytest.mark.parametrize("radius", [8.0, 12.0])
def test_corners_are_not_cut(tmp_path, radius):
    xy = road([("L", 30), ("A", radius, 90), ("L", 30)], step=0.1)
    src = tmp_path / "corner.csv"
    src.write_text("\n".join(f"{x:.4f},{y:.4f}" for x, y in xy))
    truth = Route(name="corner", x=xy[:, 0], y=xy[:, 1], z=np.zeros(len(xy)), closed=False, width=np.full(len(xy), 4.0))
    dist, _, _ = deviations(import_route(src, cfg=CFG).xyz, truth)
    assert dist.max() < 0.01


def test_rtk_noise_is_smoothed_away(tmp_path):
    rng = np.random.default_rng(5)
    x = np.arange(0.0, 150.0, 0.2)  # a slow drive: a fix every 0.2 m
    src = tmp_path / "noisy.csv"
    src.write_text("\n".join(f"{a:.4f},{b:.4f}" for a, b in zip(x, rng.normal(0.0, 0.007, len(x)))))
    result = import_route(src, cfg=CFG)
    inner = result.xyz[6:-6]
    assert math.sqrt(np.mean(inner[:, 1] ** 2)) < 0.0035  # 7 mm of noise -> under half
    assert np.abs(result.yaw[6:-6]).max() < 0.02


def test_drop_standstill_keeps_order_and_spacing():
    pts = np.array(
        [[0, 0, 0], [0.05, 0, 0], [0.02, 0.03, 0], [0.3, 0, 0], [0.35, 0, 0], [0.15, 0, 0], [1, 0, 0.5]], float
    )
    kept = drop_standstill(pts, 0.1)
    assert kept.tolist() == [[0, 0, 0], [0.3, 0, 0], [0.15, 0, 0], [1, 0, 0.5]]
    even = resample_even(np.array([[0, 0, 0], [10.2, 0, 1.0]], float), 0.5)
    assert len(even) == 21 and np.diff(even[:, 0]) == pytest.approx(0.51) and even[-1, 2] == 1.0


def test_route_from_csv_reads_yaw_column_and_comments(tmp_path):
    path = tmp_path / "r.csv"
    path.write_text(
        "# ares route: source=x, points=3, length_m=20\n# another comment\nx,y,z,yaw\n"
        "0,0,0,0\n10,0,1,0.785\n10,10,2,1.571\n"
    )
    route = Route.from_csv(path)
    assert route.length == pytest.approx(20.0) and route.point_at(15.0)[:3] == pytest.approx((10.0, 5.0, 1.5))
    path.write_text("x,y,z,yaw\n0,0,0,0\n10,0,1\n")
    with pytest.raises(RouteError, match=":3: expected 4 finite"):
        Route.from_csv(path)
    path.write_text("x,y,z,yaw\n0,0,0,0\n10,0,1,nan\n")
    with pytest.raises(RouteError, match=":3: expected 4 finite"):
        Route.from_csv(path)


# ---- bad files ---------------------------------------------------------------------------------------


def good_lines(n: int = 20) -> list[str]:
    gnss = GnssSensor(TOUR, SIM_GNSS, FRAME, noise=False)
    out = []
    for i in range(n):
        x, y, z, _ = TOUR.point_at(30.0 + i)
        out += gnss.measure(VehicleState(t=i * 0.2, x=x, y=y, z=z, s=30.0 + i))["sentences"]
    return out


def with_field(sentence: str, index: int, value: str) -> str:
    fields = sentence[1 : sentence.index("*")].split(",")
    fields[index] = value
    return nmea_sentence(",".join(fields))


@pytest.mark.parametrize(
    "bad, lineno, words",
    [
        (lambda g: g[:-2] + ("00" if g[-2:] != "00" else "01"), 7, "checksum"),
        (lambda g: g[:25], 9, "framing"),
        (lambda g: with_field(g, 2, "4099.0000000"), 5, "latitude"),
        (lambda g: with_field(g, 4, "01000.0000000"), 11, "far from origin"),
        (lambda g: with_field(g, 7, "x"), 3, "satellites"),
    ],
)
def test_a_bad_nmea_line_is_counted_and_skipped_or_with_strict_named(tmp_path, bad, lineno, words):
    lines = good_lines()
    lines[lineno - 1] = bad(lines[lineno - 1])  # odd lines are GGA, even ones GST
    src = tmp_path / "drive.nmea"
    src.write_text("\n".join(lines) + "\n")
    with pytest.raises(RouteImportError, match=f"drive.nmea:{lineno}: {words}"):
        import_route(src, tmp_path / "out.csv", strict=True, cfg=CFG)
    assert not (tmp_path / "out.csv").exists()  # nothing half-written
    result = import_route(src, tmp_path / "out.csv", cfg=CFG)
    if words == "far from origin":
        assert result.log.far == 1 and not result.log.bad
        assert "fixes beyond the frame's reach: 1" in result.summary()
    else:
        assert dict(result.log.bad) == {words: 1}
        assert f"skipped, bad lines: {words} 1 (first: line {lineno})" in result.summary()
    assert Route.from_csv(tmp_path / "out.csv").length > 15.0


def test_other_sentences_no_fix_and_blank_lines_are_not_errors(tmp_path):
    lines = good_lines(10)
    rmc = nmea_sentence("GPRMC,100000.00,A,4024.0,N,00342.0,W,0.0,0.0,010124,,,A")
    no_fix = nmea_sentence("GPGGA,095959.00,,,,,0,00,99.99,,,,,,")
    src = tmp_path / "drive.nmea"
    src.write_text("\n".join([no_fix, "", rmc] + lines + ["  "]) + "\r\n")
    result = import_route(src, cfg=CFG)
    assert result.points_in == 10 and dict(result.log.no_fix) == {"GGA": 1}
    assert result.log.sentences == {"GPGGA": 10, "GPGST": 10, "GPRMC": 1} and not result.log.bad
    summary = result.summary()
    assert "skipped, no fix: GGA 1" in summary and "GPRMC 1 (GPRMC: positions taken from GGA)" in summary


@pytest.mark.parametrize(
    "text, words",
    [
        ("x,y\n0,0\n1,banana\n", "bad.csv:3: expected numbers"),
        ("0,0\n1,2,3,4,5\n", "bad.csv:2: expected 2 or 3 numbers"),
        ("0,0\nnan,1\n", "bad.csv:2: not a finite number"),
        ("", "no points"),
        ("# only a comment\nx,y\n", "no points"),
        ("0,0\n0.01,0.02\n0.03,0\n", "never moves"),
        (nmea_sentence("GPGGA,,,,,,0,00,99.99,,,,,,") + "\n", "no usable position.*GGA 1 without a fix"),
        ("# a logger's header\n" + nmea_sentence("GPGSV,1,1,01,03,03,111,00") + "\n", "no usable position"),
        ("# a logger's header, nothing else\n", "neither NMEA sentences nor rows"),
    ],
)
def test_bad_files_get_a_clear_error(tmp_path, text, words):
    src = tmp_path / ("bad.nmea" if text.startswith("$") else "bad.csv")
    src.write_text(text)
    with pytest.raises(RouteImportError, match=words):
        import_route(src, tmp_path / "out.csv", cfg=CFG)


def test_binary_and_missing_files(tmp_path):
    src = tmp_path / "bin.csv"
    src.write_bytes(b"\x00\xff\xfe\x01" * 10)
    with pytest.raises(RouteImportError, match="not a text file"):
        import_route(src, cfg=CFG)
    with pytest.raises(RouteImportError, match="cannot read"):
        import_route(tmp_path / "missing.nmea", cfg=CFG)


def test_format_detection():
    assert detect_format(b"\n\n$GPGGA,...") == "nmea"
    assert detect_format(b"x,y\n0,0\n") == "csv"
    assert detect_format(b"") is None and detect_format(b"# just words\n") is None
    header = "Logger v2.1 \u2014 Bootsfahrt M\u00fcnchen\r\n# port COM3 @ 38400\r\n".encode()
    assert detect_format(header + b"$GPGGA,1*00\r\n$GPRMC,2*00\r\n") == "nmea"
    assert detect_format(b"\xef\xbb\xbfx,y\n# c\n0,0\n1,1\n$GPGGA,x*00\n") == "csv"  # rows win
    assert detect_format(b"2024-05-01T09:47:36Z $GNGGA,1*00\n\\s:GPS1*5A\\$GPRMC,2*00\n") == "nmea"
    assert detect_format(b"1795427250.125,$GNGGA,1*00\n1795427250.250;COM3;$GNRMC,2*00\n") == "nmea"


# ---- configuration: the route_import section ------------------------------------------------------


def test_the_route_import_section_sets_the_spacing_and_the_argument_overrides_it(tmp_path):
    src = tmp_path / "road.csv"
    write_campus_road_csv(src)
    coarse = run_config.build(overrides={"route_import": {"spacing_m": 2.0}})
    assert config.section(coarse, "route_import", RouteImportSettings).spacing_m == 2.0
    assert import_route(src, cfg=coarse).step_m == pytest.approx(2.0, rel=0.01)
    assert import_route(src, cfg=coarse, spacing_m=1.0).step_m == pytest.approx(1.0, rel=0.01)


def test_a_bad_route_import_setting_is_refused_naming_the_key():
    with pytest.raises(config.ConfigError, match=r"route_import\.spacing: unknown key \(did you mean 'spacing_m'\?\)"):
        run_config.build(overrides={"route_import": {"spacing": 1.0}})
    with pytest.raises(config.ConfigError, match=r"route_import\.smooth_polyorder: .*less than or equal to 5"):
        run_config.build(overrides={"route_import": {"smooth_polyorder": 9}})


# ---- the command line -----------------------------------------------------------------------------


@pytest.fixture
def no_run_config(monkeypatch):
    monkeypatch.delenv(config.RUN_CONFIG_ENV, raising=False)


def test_cli_imports_nmea_and_csv(tmp_path, tour_import, capsys, no_run_config):
    log, _, _ = tour_import
    out = tmp_path / "routes" / "tour.csv"
    assert cli.main(["route", "import", str(log), "-o", str(out)]) == 0
    line = capsys.readouterr().out
    assert line.startswith(f"imported {log.name} -> {out}: ") and " kept " in line and "closed loop" in line
    assert Route.from_csv(out).length > 1500

    src = tmp_path / "road.csv"
    write_campus_road_csv(src)
    out2 = tmp_path / "road_route.csv"
    assert cli.main(["route", "import", str(src), "-o", str(out2), "--format", "csv", "--spacing", "1"]) == 0
    assert "every 1.00 m" in capsys.readouterr().out
    assert np.diff(Route.from_csv(out2).s).max() <= 0.25 + 1e-9  # read back: 0.25 m samples


def test_cli_errors_exit_non_zero_with_the_line(tmp_path, capsys, no_run_config):
    lines = good_lines(5)
    lines[2] = lines[2][:-2] + ("00" if lines[2][-2:] != "00" else "01")
    src = tmp_path / "drive.nmea"
    src.write_text("\n".join(lines))
    assert cli.main(["route", "import", str(src), "-o", str(tmp_path / "o.csv"), "--strict"]) == 1
    assert "ares: error: drive.nmea:3: checksum" in capsys.readouterr().err
    assert cli.main(["route", "import", str(src), "-o", str(tmp_path / "o.csv")]) == 0
    assert "skipped, bad lines: checksum 1 (first: line 3)" in capsys.readouterr().out
    assert cli.main(["route", "import", str(src), "-o", str(tmp_path / "o.csv"), "--format", "csv"]) == 1
    assert "drive.nmea:1: expected numbers" in capsys.readouterr().err
    assert cli.main(["route", "import", str(tmp_path / "nope.nmea"), "-o", str(tmp_path / "o.csv")]) == 1
    assert "cannot read" in capsys.readouterr().err
    assert cli.main(["route", "import", str(src)]) == 2  # -o is required
    assert cli.main(["route", "import", str(src), "-o", "x.csv", "--spacing", "-1"]) == 2


def env_without_run_config() -> dict:
    env = {k: v for k, v in os.environ.items() if k != config.RUN_CONFIG_ENV}
    env["PYTHONPATH"] = str(REPO)
    return env


def ares(*argv: str, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "ares.cli", *argv],
        cwd=REPO,
        env=env_without_run_config(),
        capture_output=True,
        text=True,
        timeout=timeout,
        stdin=subprocess.DEVNULL,
    )


def test_cli_exit_code_as_a_process(tmp_path):
    src = tmp_path / "bad.csv"
    src.write_text("x,y\n0,0\n1,banana\n")
    done = ares("route", "import", str(src), "-o", str(tmp_path / "o.csv"))
    assert done.returncode == 1 and "ares: error: bad.csv:3: expected numbers" in done.stderr
    assert not (tmp_path / "o.csv").exists()


@pytest.mark.stack
@pytest.mark.timeout(60)
def test_route_record_writes_what_arrives_on_sensors_gnss(router, port, tmp_path):
    """End to end on purpose: `ares route record` is a client of a real router, which the
    in-memory bus cannot stand in for."""
    bus = Bus(router, "test", WallClock())
    stop = threading.Event()
    line = Route(
        name="line", x=np.array([0.0, 100.0]), y=np.zeros(2), z=np.zeros(2), closed=False, width=np.full(2, 4.0)
    )
    gnss = GnssSensor(line, SIM_GNSS, FRAME, rng=np.random.default_rng(2), noise=True)
    published: list[str] = []

    def feed() -> None:  # the simulated receiver, 20 Hz, driving east at 10 m/s
        i = 0
        while not stop.is_set():
            t = i * 0.05
            sentences = gnss.measure(VehicleState(t=t, x=i * 0.5))["sentences"]
            published.extend(sentences)
            bus.publish("sensors/gnss", GnssSentences(t=t, sentences=sentences))
            i += 1
            time.sleep(0.05)

    feeder = threading.Thread(target=feed, daemon=True)
    feeder.start()
    log = tmp_path / "recorded.nmea"
    try:
        done = ares("route", "record", str(log), "--seconds", "2", "--router", f"tcp/127.0.0.1:{port}")
    finally:
        stop.set()
        feeder.join()
        bus.close()
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("recorded ")
    lines = log.read_text().splitlines()
    # what arrived while recording, one sentence a line, nothing lost or reordered in between
    start = published.index(lines[0])
    assert lines == published[start : start + len(lines)]
    fixes = project_fixes(read_nmea_log(log.read_bytes(), log.name), FRAME, log.name)
    result = import_route(log, tmp_path / "recorded_route.csv", cfg=CFG)
    assert np.abs(result.xyz[:, 1]).max() < 0.03
    assert result.length_m == pytest.approx(fixes[-1, 0] - fixes[0, 0], abs=0.05)


def test_route_record_without_a_stack_is_a_clear_error(tmp_path):
    done = ares(
        "route", "record", str(tmp_path / "x.nmea"), "--seconds", "1", "--router", f"tcp/127.0.0.1:{free_port()}"
    )
    assert done.returncode == 1 and "no Zenoh router reachable" in done.stderr


def _ubx(cls: int, ident: int, payload: bytes) -> bytes:
    body = bytes([cls, ident, len(payload) & 0xFF, len(payload) >> 8]) + payload
    a = b = 0
    for byte in body:
        a, b = (a + byte) & 0xFF, (b + ((a + byte) & 0xFF)) & 0xFF
    return b"\xb5\x62" + body + bytes([a, b])


def test_ubx_frames_between_the_sentences_are_skipped_and_counted(tmp_path):
    """A u-blox receiver sends its binary frames (NAV-PVT, with NULs in them) and its NMEA on one
    port: the frames are taken out, the NMEA used as if alone."""
    lines = good_lines(40)
    plain, mixed = tmp_path / "plain.nmea", tmp_path / "ublox.nmea"
    plain.write_text("\r\n".join(lines) + "\r\n")
    frames = [_ubx(0x01, 0x07, bytes(range(92))), _ubx(0x01, 0x35, b"\x00" * 20), _ubx(0x0A, 0x09, b"")]
    data = b"".join(line.encode() + b"\r\n" + frames[i % 3] for i, line in enumerate(lines))
    mixed.write_bytes(data)
    alone, together = import_route(plain, cfg=CFG), import_route(mixed, cfg=CFG)
    assert together.log.ubx_frames == len(lines) and together.points_in == alone.points_in
    assert np.allclose(together.xyz, alone.xyz)
    assert f"UBX) frames between the sentences: {len(lines)}" in "\n".join(together.log.report())
    # a broken frame (its checksum wrong) and one cut by the file's end: skipped and counted as the
    # GNSS driver counts them, every sentence kept (before: "not a text file (byte 380 is NUL)")
    broken = bytearray(frames[0])
    broken[-1] ^= 0xFF
    mixed.write_bytes(data[:380] + bytes(broken) + data[380:] + frames[0][:40])
    again = import_route(mixed, cfg=CFG)
    assert again.points_in == alone.points_in and np.allclose(again.xyz, alone.xyz)
    assert again.log.broken_binary and sum(again.log.broken_binary.values()) >= 2
    assert "binary that is no whole frame" in "\n".join(again.log.report())


def test_a_receiver_that_stood_still_is_not_a_route(tmp_path):
    """150 GGA fixes of a receiver that never moved, wandering a metre or two (no RTK): refused,
    not imported as a route of a few decimetres."""
    rng = np.random.default_rng(7)
    lat0, lon0 = 40.4, -3.7
    lines = []
    for i in range(150):
        north, east = rng.normal(0.0, 1.0, 2)  # metres
        lat = lat0 + north / 111_320.0
        lon = lon0 + east / (111_320.0 * math.cos(math.radians(lat0)))
        lat_text = f"{int(lat):02d}{(lat - int(lat)) * 60:011.8f}"
        lon_text = f"{int(-lon):03d}{(-lon - int(-lon)) * 60:011.8f}"
        hhmmss = f"10{i // 60:02d}{i % 60:02d}.00"
        lines.append(nmea_sentence(f"GPGGA,{hhmmss},{lat_text},N,{lon_text},W,1,08,1.2,650.0,M,50.0,M,,"))
    src = tmp_path / "static.nmea"
    src.write_text("\r\n".join(lines) + "\r\n")
    with pytest.raises(RouteImportError, match=r"not a drive: its 150 points stay within [0-9.]+ m") as refused:
        import_route(src, cfg=CFG)
    assert "stood still" in str(refused.value)


# ---- logs without RTK: metres of noise, a drifting altitude ----------------------------------------


def gga_log(xy: np.ndarray, altitude: np.ndarray, quality: int, hdop: float) -> str:
    """GGA sentences at 1 Hz of points in the configured frame (FRAME)."""
    lines = []
    for i, ((east, north), alt) in enumerate(zip(xy, altitude)):
        lat, lon = FRAME.to_latlon(float(east), float(north))
        lat_text = f"{int(lat):02d}{(lat - int(lat)) * 60:011.8f}"
        lon_text = f"{int(abs(lon)):03d}{(abs(lon) - int(abs(lon))) * 60:011.8f}"
        hhmmss = f"12{i // 60:02d}{i % 60:02d}.00"
        east_west = "E" if lon >= 0 else "W"
        fields = f"{quality},05,{hdop:.1f},{alt:.1f},M,46.3,M,,"
        lines.append(nmea_sentence(f"GPGGA,{hhmmss},{lat_text},N,{lon_text},{east_west},{fields}"))
    return "\r\n".join(lines) + "\r\n"


def town_drive_without_rtk(rng) -> tuple[np.ndarray, Route]:
    """A drive of a town corner at 1 Hz, as an autonomous receiver logs it: 8 m/s, slowing to 2 m/s
    round a 10 m corner, a 30 s wait after it; fixes wander ~1 m (correlated, as such errors are)."""
    truth_xy = road([("L", 120), ("A", 10.0, 90), ("L", 120)], step=0.05)
    truth = Route("truth", truth_xy[:, 0], truth_xy[:, 1], np.zeros(len(truth_xy)), False, np.full(len(truth_xy), 5.0))
    s, t = [0.0], 0.0
    while s[-1] < truth.length:
        corner = 110.0 < s[-1] < 150.0
        s.append(min(s[-1] + (2.0 if corner else 8.0), truth.length))
        if abs(s[-1] - 160.0) < 4.0 and t == 0.0:
            s += [s[-1]] * 30  # the wait
            t = 1.0
    xy = np.array([truth.point_at(v)[:2] for v in s])
    walk = np.cumsum(rng.normal(0.0, 0.4, (len(xy), 2)), axis=0)  # a random walk, scaled to +-1 m
    return xy + walk / np.abs(walk).max(), truth


def test_a_log_without_rtk_gets_a_route_the_vehicle_can_steer_flat_and_near_the_road(tmp_path):
    rng = np.random.default_rng(11)
    xy, truth = town_drive_without_rtk(rng)
    altitude = 500.0 + 4.0 * np.arange(len(xy)) + rng.normal(0.0, 20.0, len(xy))  # converging: +4 m/s
    src = tmp_path / "town.nmea"
    src.write_text(gga_log(xy, altitude, quality=1, hdop=2.5))
    result = import_route(src, tmp_path / "town.csv", cfg=CFG)
    route = Route.from_csv(tmp_path / "town.csv")
    vehicle = load_vehicle(config.core(CFG).vehicle)
    assert np.abs(route.curvature).max() <= vehicle.max_curvature
    assert np.all(route.z == 0.0)  # the altitude is not used: no 400 % grades
    assert result.kept < len(xy) - 25  # the 30 s wait: one point
    # rounded and smoothed, within the receiver's metre of the road (nearest points: no projection hints)
    dist = np.min(np.hypot(result.xyz[:, None, 0] - truth.x, result.xyz[:, None, 1] - truth.y), axis=1)
    assert dist.max() < 2.0
    summary = result.summary()
    assert "fixes without RTK wander ~2.5 m" in summary and "smoothed over" in summary
    assert f"altitude of the {len(xy)} fixes without RTK not used" in summary and "the route is flat" in summary
    assert "road width 5.5 m" in summary and route.width[0] == pytest.approx(5.5)


def test_an_rtk_corner_sharper_than_the_vehicle_turns_is_kept_and_reported(tmp_path):
    """RTK fixes are the road: a 6 m corner stays 6 m (the shuttle turns no tighter than ~8.7 m), and
    the summary says so."""
    xy = road([("L", 30), ("A", 6.0, 90), ("L", 30)], step=0.1)
    src = tmp_path / "tight.csv"
    src.write_text("\n".join(f"{x:.4f},{y:.4f}" for x, y in xy))
    result = import_route(src, cfg=CFG)
    radius = 1.0 / np.abs(Route("r", *result.xyz.T, False, np.full(len(result.xyz), 4.0)).curvature).max()
    assert radius == pytest.approx(6.0, rel=0.1)
    assert re.search(
        r"warning: a turn of radius [56]\.\d m at s = 3\d m is sharper than the vehicle can steer", result.summary()
    )


def test_collapse_standstill_makes_a_wait_one_point_and_leaves_a_drive():
    wait = np.array([[10.0, 0.0, 0.0], [11.0, 0.5, 0.0], [10.2, -0.8, 0.0], [9.6, 0.3, 0.0]])
    drive = np.array([[0.0, 0.0, 0.0], [5.0, 0.0, 0.0]])
    after = np.array([[15.0, 0.0, 0.0], [20.0, 0.0, 0.0]])
    points = np.vstack([drive, wait, after])
    kept = collapse_standstill(points, np.full(len(points), 2.0))
    assert kept.tolist() == drive.tolist() + [wait.mean(axis=0).tolist()] + after.tolist()
    assert len(collapse_standstill(points, np.full(len(points), 0.1))) == len(points)  # RTK: nothing to merge


def test_limit_grade_bounds_a_climb_and_leaves_a_plausible_road():
    s = np.arange(0.0, 100.0, 0.5)
    ramp = 0.5 * s  # 50 %
    limited, clipped_m = limit_grade(s, ramp, 0.15)
    assert np.abs(np.diff(limited) / np.diff(s)).max() <= 0.15 + 1e-9 and clipped_m == pytest.approx(99.5)
    hill = 3.0 * np.sin(s / 30.0)  # at most 10 %
    assert limit_grade(s, hill, 0.15) == (hill, 0.0)


def test_the_road_width_comment_is_written_and_read_back(tmp_path):
    src = tmp_path / "line.csv"
    src.write_text("0,0\n50,0\n")
    import_route(src, tmp_path / "out.csv", cfg=CFG)
    assert "# road: width_m=5.5" in (tmp_path / "out.csv").read_text()
    assert Route.from_csv(tmp_path / "out.csv").width[0] == pytest.approx(5.5)
    assert Route.from_csv(src).width[0] == pytest.approx(4.0)  # a plain CSV: 4 m, as before
    import_route(src, tmp_path / "wide.csv", cfg=run_config.build(overrides={"route_import": {"road_width_m": 7.0}}))
    assert Route.from_csv(tmp_path / "wide.csv").width[0] == pytest.approx(7.0)
    (tmp_path / "bad.csv").write_text("# road: width_m=-1\n0,0\n1,0\n")
    with pytest.raises(RouteError, match="road width must be a positive number"):
        Route.from_csv(tmp_path / "bad.csv")
