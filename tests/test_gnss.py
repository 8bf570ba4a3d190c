"""GGA (+ GST) -> UTM -> local frame (perception/gnss.py), and the gnss node on the in-memory bus."""

from __future__ import annotations

import json
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ares.app import run_config
from ares.core import config
from ares.core.clock import ManualClock
from ares.core.config import UtmOrigin
from ares.core.geodesy import LocalFrame, origin_at
from ares.core.membus import MemoryNetwork
from ares.core.messages import GnssSentences
from ares.core.nmea_framing import sentence as nmea_sentence
from ares.core.route import Route
from perception.gnss import GnssError, GnssParams, GnssProjector, pair_epochs
from perception.gnss_node import GnssNode
from perception.nmea_parser import NmeaError, parse_sentence
from simulator.params import SimGnssParams
from simulator.sensors import GnssSensor
from simulator.vehicle import VehicleState

SIM_GNSS = SimGnssParams()
ROUTE = Route.from_tour("default")
FRAME = LocalFrame(UtmOrigin())
PROJECTOR = GnssProjector(FRAME, GnssParams())


def sentences_at(x: float, y: float, z: float = 0.0, t: float = 0.0, s: float = 0.0) -> list[str]:
    gnss = GnssSensor(ROUTE, SIM_GNSS, FRAME, noise=False)
    return gnss.measure(VehicleState(t=t, x=x, y=y, z=z, s=s))["sentences"]


def fix_of(lines: list[str], t: float = 0.0):
    ((gga, gst),) = pair_epochs([parse_sentence(line) for line in lines])
    return PROJECTOR.fix(gga, gst, t=t)


def gga_with(body_fields: dict[int, str]) -> str:
    """A simulator GGA at the origin with some fields replaced (1 = time ... 14 = station)."""
    fields = sentences_at(10.0, 20.0)[0][1:].split("*")[0].split(",")
    for i, v in body_fields.items():
        fields[i] = v
    return nmea_sentence(",".join(fields))


# ---- projection -------------------------------------------------------------------------------


@settings(max_examples=150, deadline=None)
@given(x=st.floats(-5000, 5000), y=st.floats(-5000, 5000), z=st.floats(-50, 300), t=st.floats(0, 86000))
def test_simulator_to_local_frame_round_trip_within_a_millimetre(x, y, z, t):
    fix = fix_of(sentences_at(x, y, z, t), t=t)
    assert abs(fix.x - x) < 1e-3 and abs(fix.y - y) < 1e-3 and abs(fix.z - z) < 1e-3
    assert fix.t == t and fix.zone == 30 and fix.hemisphere == "N"
    assert fix.easting == pytest.approx(440000.0 + fix.x) and fix.northing == pytest.approx(4474000.0 + fix.y)
    assert fix.rtk and fix.quality == 4 and fix.satellites == 16 and fix.hdop == 0.7


def test_gst_sigmas_give_the_variances():
    lines = sentences_at(1.0, 2.0)
    fix = fix_of(lines)
    rtk_sigma, alt_sigma = SIM_GNSS.rtk_sigma_m, SIM_GNSS.rtk_sigma_alt_m
    assert fix.var_x == pytest.approx(rtk_sigma**2) and fix.var_y == pytest.approx(rtk_sigma**2)
    assert fix.var_z == pytest.approx(alt_sigma**2)
    # GST fields 6, 7, 8: sigma latitude (-> y), longitude (-> x), altitude
    gst = nmea_sentence(lines[1][1:].split("*")[0].rsplit(",", 3)[0] + ",0.100,0.200,0.300")
    fix = fix_of([lines[0], gst])
    assert (fix.var_x, fix.var_y, fix.var_z) == pytest.approx((0.04, 0.01, 0.09))


def test_without_a_gst_of_the_same_epoch_the_variances_come_from_the_fix_quality():
    gga, gst = (parse_sentence(line) for line in sentences_at(1.0, 2.0, t=5.0))
    _, other_epoch = (parse_sentence(line) for line in sentences_at(1.0, 2.0, t=5.2))
    rtk = PROJECTOR.fix(gga, None)
    assert rtk.rtk and (rtk.var_x, rtk.var_y) == (5e-5, 5e-5) and rtk.var_z == pytest.approx(4 * 5e-5)
    assert PROJECTOR.fix(gga, other_epoch).var_x == 5e-5  # a GST of another time is not used
    for quality in ("1", "2", "5"):
        fix = PROJECTOR.fix(parse_sentence(gga_with({6: quality})), None)
        assert not fix.rtk and fix.quality == int(quality)
        assert (fix.var_x, fix.var_y, fix.var_z) == (0.5, 0.5, 2.0)


def test_variances_and_origin_come_from_config_even_after_the_json_round_trip():
    origin = {"zone": 30, "hemisphere": "N", "easting": 440010.0, "northing": 4474020.0, "altitude_m": 600.0}
    cfg = json.loads(
        json.dumps(
            run_config.build(
                overrides={
                    "gnss": {
                        "variance_m2": {"4": 1e-4, "5": 0.01},
                        "default_variance_m2": 0.9,
                        "vertical_variance_factor": 1.0,
                    },
                    "origin_utm": origin,
                }
            )
        )
    )
    projector = GnssProjector(LocalFrame(config.core(cfg).origin_utm), config.section(cfg, "gnss", GnssParams))
    assert projector.frame.origin == UtmOrigin(**origin)
    gga = parse_sentence(sentences_at(10.0, 20.0, 5.0)[0])
    fix = projector.fix(gga)
    assert abs(fix.x) < 1e-3 and abs(fix.y) < 1e-3 and fix.z == pytest.approx(55.0)
    assert fix.var_x == 1e-4
    assert projector.fix(parse_sentence(gga_with({6: "5"}))).var_x == 0.01
    assert projector.fix(parse_sentence(gga_with({6: "2"}))).var_z == 0.9


@pytest.mark.parametrize(
    "lat, lon, reason",
    [
        ("4024.0000000", "00900.0000000", "far from origin"),  # 9 deg W: zone 29, ~450 km away
        ("4024.0000000", "01000.0000000", "far from origin"),  # wrong hemisphere of longitude (E): zone 32
        ("8500.0000000", "00342.0000000", "utm range"),  # beyond UTM's 84 deg N
    ],
)
def test_a_fix_far_from_the_sites_origin_is_rejected(lat, lon, reason):
    ew = "E" if lon.startswith("010") else "W"
    gga = parse_sentence(gga_with({2: lat, 4: lon, 5: ew}))
    with pytest.raises(GnssError) as info:
        PROJECTOR.fix(gga)
    assert info.value.reason == reason and isinstance(info.value, NmeaError)


def test_a_southern_fix_is_rejected_for_a_northern_origin():
    gga = parse_sentence(gga_with({3: "S"}))
    with pytest.raises(GnssError, match="km from the site's origin") as info:
        PROJECTOR.fix(gga)
    assert info.value.reason == "far from origin"


@pytest.mark.parametrize(
    "lat, lon, dlat, dlon",
    [
        (52.3, 11.998, 0.0, 1e-5),  # eastwards across 12 E: zone 32 into 33
        (-33.9, 149.998, 0.0, 1e-5),  # across 150 E in the south: zone 55 into 56
        (0.002, 27.0, -1e-5, 0.0),  # southwards across the equator
        (-0.002, -36.0, 1e-5, 0.0),  # northwards across it
    ],
)
def test_fixes_across_a_zone_boundary_or_the_equator_stay_continuous(lat, lon, dlat, dlon):
    """The frame stays in the origin's zone and hemisphere: a drive across a zone boundary or
    the equator moves on smoothly, with no jump of hundreds of kilometres."""
    frame = LocalFrame(origin_at(lat, lon, 30.0))
    points = [frame.project(lat + i * dlat, lon + i * dlon, None) for i in range(400)]  # ~0.4 km
    assert {p.zone for p in points} == {frame.zone} and all(p.z is None for p in points)
    steps = [math.hypot(b.x - a.x, b.y - a.y) for a, b in zip(points, points[1:])]
    assert 0.5 < min(steps) and max(steps) / min(steps) < 1.0001
    assert frame.to_latlon(points[-1].x, points[-1].y) == pytest.approx((lat + 399 * dlat, lon + 399 * dlon), abs=1e-8)


def test_pairing_takes_the_gst_of_the_same_time_in_either_order():
    gga1, gst1 = (parse_sentence(line) for line in sentences_at(0, 0, t=1.0))
    gga2, gst2 = (parse_sentence(line) for line in sentences_at(0, 0, t=1.2))
    assert pair_epochs([gst1, gga1]) == [(gga1, gst1)]
    assert pair_epochs([gga1, gst1, gga2, gst2]) == [(gga1, gst1), (gga2, gst2)]
    assert pair_epochs([gga2, gst1]) == [(gga2, None)]
    assert pair_epochs([gga1], earlier_gst=gst1) == [(gga1, gst1)]
    assert pair_epochs([gga2], earlier_gst=gst1) == [(gga2, None)]


def test_a_misspelt_gnss_setting_is_refused_naming_it():
    with pytest.raises(
        config.ConfigError, match=r"default_variance: unknown key \(did you mean 'default_variance_m2'\?\)"
    ):
        config.section({"gnss": {"default_variance": 0.9}}, "gnss", GnssParams)


# ---- the node, on the in-memory bus ------------------------------------------------------------------


@pytest.fixture
def gnss_node():
    """A gnss node on a MemoryNetwork with a ManualClock; yields (node, clock, test bus)."""
    network, clock = MemoryNetwork(), ManualClock()
    node = GnssNode(run_config.build(), clock=clock, bus=network.bus("gnss", clock))
    node.setup()
    yield node, clock, network.bus("test", clock)
    node.bus.close()


def step_with(node: GnssNode, clock: ManualClock, bus, t: float, lines: list[str]) -> None:
    bus.publish("sensors/gnss", GnssSentences(t=t, sentences=lines))
    clock.set(t)
    node.step_once(t)


def test_gnss_node_publishes_fixes_for_good_lines_and_survives_bad_ones(gnss_node):
    node, clock, bus = gnss_node
    fixes = bus.subscribe("gnss/fix", queue=200)
    events = bus.subscribe("events", queue=200)
    gga, _ = sentences_at(12.5, -7.25, 3.0, t=1.0)
    corrupt = [
        gga[:-2] + ("00" if gga[-2:] != "00" else "01"),  # checksum
        gga[:30],  # truncated
        "\x00\xff garbage",  # framing
        gga_with({2: "4099.0000000"}),  # latitude
        gga_with({6: "0"}),  # no fix
        gga_with({2: "4024.0000000", 4: "00900.0000000"}),  # far from origin
        nmea_sentence("GPRMC,100000.00,A,4024.0,N,00342.0,W,0.0,0.0,010124,,,A"),  # not used, not bad
    ]
    for i in range(5):
        t = 10.0 + i
        lines = sentences_at(1.0 * i, 2.0, 0.0, t=t)
        step_with(node, clock, bus, t, corrupt[: 1 + i] + lines + corrupt[1 + i :])
    got = [msg for _, msg in fixes.drain()]
    assert [f.t for f in got] == [10.0, 11.0, 12.0, 13.0, 14.0]  # only the good lines, in order
    for i, f in enumerate(got):
        assert f.x == pytest.approx(1.0 * i, abs=1e-3) and f.y == pytest.approx(2.0, abs=1e-3)
        assert f.var_x == pytest.approx(SIM_GNSS.rtk_sigma_m**2)  # paired with its GST

    # five messages carried the same bad lines: one event per reason (at most one per 10 s)
    rejections = [e for _, e in events.drain() if e.kind == "nmea_rejected"]
    assert all(e.source == "gnss" for e in rejections)
    assert sorted(e.data["reason"] for e in rejections) == sorted(
        {"checksum", "framing", "latitude", "no fix", "far from origin"}
    )
    assert all(e.data["count"] == 1 for e in rejections)

    # still alive and well after the garbage; 10 s after the first, a reason is reported again
    step_with(node, clock, bus, 20.0, sentences_at(-3.0, 4.0, t=20.0) + corrupt[:1])
    ((_, last),) = fixes.drain()
    assert last.t == 20.0 and last.x == pytest.approx(-3.0, abs=1e-3)
    ((_, again),) = events.drain()
    assert again.data["reason"] == "checksum" and again.data["count"] == 6
