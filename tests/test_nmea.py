"""The strict NMEA parser (perception/nmea_parser.py): differential against pynmea2 on valid sentences
(GGA in every form the standard allows, RMC, GLL, GST), fuzzing with malformed ones (nothing but
NmeaError escapes, nothing malformed yields a fix), and one hand-written case per rejection
reason."""

from __future__ import annotations

import collections

import numpy as np
import pynmea2
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from ares.core.config import UtmOrigin
from ares.core.geodesy import LocalFrame
from ares.core.nmea_framing import checksum
from ares.core.nmea_framing import sentence as nmea_sentence
from ares.core.route import Route
from perception.nmea_parser import Gga, Gll, Gst, NmeaError, NmeaReader, Other, Rmc, parse_sentence
from simulator.params import SimGnssParams
from simulator.sensors import GnssSensor
from simulator.vehicle import VehicleState

ROUTE = Route.from_tour("default")
FRAME = LocalFrame(UtmOrigin())
GGA_BODY = "GPGGA,092750.000,5321.6802,N,00630.3372,W,1,8,1.03,61.7,M,55.2,M,,"
GGA = nmea_sentence(GGA_BODY)
GST = nmea_sentence("GNGST,092750.000,0.010,0.009,0.008,45.0,0.007,0.006,0.015")
FUZZ = settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def with_field(sentence: str, index: int, value: str) -> str:
    """The sentence with field `index` (0 = the address) replaced, checksum recomputed."""
    fields = sentence[1 : sentence.index("*")].split(",")
    fields[index] = value
    return nmea_sentence(",".join(fields))


def reject_reason(line) -> str:
    with pytest.raises(NmeaError) as info:
        parse_sentence(line)
    return info.value.reason


# ---- strategies of valid sentences ----------------------------------------------------------


def decimals(max_digits: int = 7):
    return st.integers(0, max_digits).flatmap(
        lambda n: st.just("") if n == 0 else st.text("0123456789", min_size=n, max_size=n).map(lambda d: "." + d)
    )


TALKERS = ["GP", "GN", "GL", "GA", "GB", "BD", "GQ", "GI", "II", "IN"]


def hhmmss(draw) -> str:
    return (
        f"{draw(st.integers(0, 23)):02d}{draw(st.integers(0, 59)):02d}{draw(st.integers(0, 59)):02d}{draw(decimals(3))}"
    )


def lat_lon(draw) -> tuple[str, str, str, str]:
    lat = f"{draw(st.integers(0, 89)):02d}{draw(st.integers(0, 59)):02d}.{draw(st.integers(0, 10**7 - 1)):07d}"
    lon = f"{draw(st.integers(0, 179)):03d}{draw(st.integers(0, 59)):02d}.{draw(st.integers(0, 10**4 - 1))}"
    return lat, draw(st.sampled_from("NS")), lon, draw(st.sampled_from("EW"))


@st.composite
def valid_gga(draw, nulls: bool = False) -> str:
    """A GGA with a fix; with `nulls`, the fields a receiver may leave empty sometimes are."""
    empty = (lambda: draw(st.booleans())) if nulls else (lambda: False)
    talker = draw(st.sampled_from(TALKERS))
    time = "" if empty() else hhmmss(draw)
    lat, ns, lon, ew = lat_lon(draw)
    quality = draw(st.integers(1, 8))
    sats = draw(st.integers(0, 99))
    sats = "" if empty() else f"{sats:02d}" if draw(st.booleans()) else str(sats)
    hdop = "" if empty() else f"{draw(st.integers(0, 99))}{draw(decimals(2))}"
    alt = f"{draw(st.sampled_from(['', '-']))}{draw(st.integers(0, 999))}{draw(decimals(3))}"
    alt = ("", draw(st.sampled_from(["", "M"]))) if empty() else (alt, "M")
    geoid = draw(
        st.one_of(
            st.just(("", "")),
            st.just(("", "M")),
            st.tuples(st.integers(-100, 100).map(lambda g: f"{g}.{abs(g) % 10}"), st.just("M")),
        )
    )
    age, station = draw(st.sampled_from([("", ""), ("1.0", "0001"), ("2", "1023")]))
    body = (
        f"{talker}GGA,{time},{lat},{ns},{lon},{ew},{quality},{sats},{hdop},{alt[0]},{alt[1]},{geoid[0]},"
        f"{geoid[1]},{age},{station}"
    )
    return nmea_sentence(body)


@st.composite
def valid_rmc(draw) -> str:
    lat, ns, lon, ew = lat_lon(draw)
    speed = "" if draw(st.booleans()) else f"{draw(st.integers(0, 99))}{draw(decimals(3))}"
    course = "" if draw(st.booleans()) else f"{draw(st.integers(0, 359))}{draw(decimals(2))}"
    date = f"{draw(st.integers(1, 28)):02d}{draw(st.integers(1, 12)):02d}{draw(st.integers(0, 99)):02d}"
    variation = draw(st.sampled_from([",", "2.1,E", "0.5,W"]))
    tail = draw(st.sampled_from(["", ",A", ",D", ",R", ",F", ",A,V", ",D,S"]))
    return nmea_sentence(
        f"{draw(st.sampled_from(TALKERS))}RMC,{hhmmss(draw)},A,{lat},{ns},{lon},{ew},{speed},"
        f"{course},{date},{variation}{tail}"
    )


@st.composite
def valid_gll(draw) -> str:
    lat, ns, lon, ew = lat_lon(draw)
    tail = draw(
        st.sampled_from(["", f",{hhmmss(draw)}", f",{hhmmss(draw)},A", f",{hhmmss(draw)},A,A", f",{hhmmss(draw)},A,D"])
    )
    return nmea_sentence(f"{draw(st.sampled_from(TALKERS))}GLL,{lat},{ns},{lon},{ew}{tail}")


@st.composite
def valid_gst(draw) -> str:
    talker = draw(st.sampled_from(["GP", "GN", "GL", "GA", "GB"]))
    time = f"{draw(st.integers(0, 23)):02d}{draw(st.integers(0, 59)):02d}{draw(st.integers(0, 59)):02d}.00"
    sig = [f"{draw(st.integers(0, 99))}{draw(decimals(4))}" for _ in range(6)]
    orient = f"{draw(st.integers(0, 359))}.{draw(st.integers(0, 9))}"
    return nmea_sentence(f"{talker}GST,{time},{sig[0]},{sig[1]},{sig[2]},{orient},{sig[3]},{sig[4]},{sig[5]}")


def assert_same_as_pynmea2(line: str, parsed) -> None:
    ref = pynmea2.parse(line, check=True)
    optional = lambda text, kind: kind(text) if text else None  # noqa: E731
    if isinstance(parsed, (Gga, Rmc, Gll)):
        assert ref.sentence_type == parsed.kind
        assert parsed.lat == pytest.approx(ref.latitude, abs=1e-9)
        assert parsed.lon == pytest.approx(ref.longitude, abs=1e-9)
    if isinstance(parsed, Gga):
        assert parsed.quality == int(ref.gps_qual)
        assert parsed.satellites == optional(ref.num_sats, int)
        assert parsed.hdop == optional(ref.horizontal_dil, float)
        assert parsed.altitude_m == ref.altitude
    elif isinstance(parsed, Rmc):
        assert parsed.speed_knots == ref.spd_over_grnd and parsed.course_deg == ref.true_course
    elif isinstance(parsed, Gll):
        assert parsed.time == (ref.data[4] if len(ref.data) > 4 else "")
    else:
        assert ref.sentence_type == "GST"
        assert (parsed.sigma_lat_m, parsed.sigma_lon_m, parsed.sigma_alt_m) == (
            ref.std_dev_latitude,
            ref.std_dev_longitude,
            ref.std_dev_altitude,
        )


# ---- differential: valid sentences -----------------------------------------------------------


@settings(max_examples=400, deadline=None)
@given(line=valid_gga())
def test_valid_gga_agrees_with_pynmea2(line):
    parsed = parse_sentence(line)
    assert isinstance(parsed, Gga)
    assert_same_as_pynmea2(line, parsed)
    assert -90 <= parsed.lat <= 90 and -180 <= parsed.lon <= 180


@settings(max_examples=200, deadline=None)
@given(line=valid_gst())
def test_valid_gst_agrees_with_pynmea2(line):
    parsed = parse_sentence(line)
    assert isinstance(parsed, Gst)
    assert_same_as_pynmea2(line, parsed)


@settings(max_examples=150, deadline=None)
@given(
    x=st.floats(-5000, 5000),
    y=st.floats(-5000, 5000),
    z=st.floats(-50, 300),
    t=st.floats(0, 86400 * 2),
    s=st.floats(0, ROUTE.length - 1),
)
def test_the_simulators_sentences_agree_with_pynmea2(x, y, z, t, s):
    gnss = GnssSensor(ROUTE, SimGnssParams(), FRAME, rng=np.random.default_rng(1), noise=True)  # RTK and float fixes
    for line in gnss.measure(VehicleState(t=t, x=x, y=y, z=z, s=s))["sentences"]:
        assert_same_as_pynmea2(line, parse_sentence(line))


def test_line_endings_lower_case_checksum_and_bytes_are_accepted():
    assert parse_sentence(GGA + "\r\n") == parse_sentence(GGA)
    assert parse_sentence(GGA + "\n") == parse_sentence(GGA)
    assert parse_sentence(GGA[:-2] + GGA[-2:].lower()) == parse_sentence(GGA)
    assert parse_sentence((GGA + "\r\n").encode()) == parse_sentence(GGA)
    gga = parse_sentence(GGA)
    assert gga.time == "092750.000" and gga.seconds_of_day == 9 * 3600 + 27 * 60 + 50
    assert gga.lat == pytest.approx(53 + 21.6802 / 60) and gga.lon == pytest.approx(-(6 + 30.3372 / 60))
    assert (gga.quality, gga.satellites, gga.hdop, gga.altitude_m, gga.geoid_separation_m) == (1, 8, 1.03, 61.7, 55.2)
    assert gga.dgps_age_s is None and gga.dgps_station is None
    gst = parse_sentence(GST)
    assert gst.talker == "GN" and (gst.sigma_lat_m, gst.sigma_lon_m, gst.sigma_alt_m) == (0.007, 0.006, 0.015)


# ---- hand-written rejections, one per reason ---------------------------------------------------


@pytest.mark.parametrize(
    "line, reason, words",
    [
        ("", "framing", "empty"),
        ("GPGGA,1*00", "framing", "'$'"),
        (GGA.replace("*", "#"), "framing", "'*'"),
        (GGA[:-1], "framing", "two hex digits"),
        (GGA[:-2] + "ZZ", "framing", "two hex digits"),
        (GGA + "\r\n\r\n", "framing", "control"),
        ("$" + "A" * 300 + "*00", "framing", "characters"),
        (nmea_sentence(GGA_BODY.replace("N", "Ñ")), "framing", "non-ASCII"),
        (b"$GPGGA,\xff*00", "framing", "ASCII"),
        (nmea_sentence("gpgga,1,2"), "framing", "address"),
        (GGA[:-2] + ("00" if GGA[-2:] != "00" else "01"), "checksum", "does not match"),
        (GGA.replace("5321.6802", "5321.6803"), "checksum", "does not match"),  # checksum kept
        (nmea_sentence("GPRMC,092750.000,V,,,,,,,280511,,,N"), "no fix", "status V"),
        (nmea_sentence("GPRMC,092750.000,A,5321.6802,N,00630.3372,W,0.02,31.66,280511,,,N"), "no fix", "mode N"),
        (nmea_sentence("GPRMC,092750.000,X,5321.6802,N,00630.3372,W,0.02,31.66,280511,,"), "status", "A or V"),
        (nmea_sentence("GPRMC,092750.000,A,5321.6802,N,00630.3372,W,0.02,31.66,280511"), "field count", "11, 12 or 13"),
        (nmea_sentence("GPRMC,092750.000,A,5321.6802,N,00630.3372,W,0.02,31.66,321399,,"), "date", "ddmmyy"),
        (nmea_sentence("GPRMC,092750.000,A,5321.6802,N,00630.3372,W,0.02,361.0,280511,,"), "course", "360"),
        (nmea_sentence("GPRMC,092750.000,A,5321.6802,N,00630.3372,W,0.02,31.66,280511,1.0,X"), "variation", "E or W"),
        (nmea_sentence("GPRMC,092750.000,A,5321.6802,N,00630.3372,W,0.02,31.66,280511,,,Q"), "mode", "mode indicator"),
        (nmea_sentence("GPGLL,5321.6802,N,00630.3372,W,092750.000,V,N"), "no fix", "status V"),
        (nmea_sentence("GPGLL,5321.6802,N,00630.3372,W,092750.000,A,N"), "no fix", "mode N"),
        (nmea_sentence("GPGLL,5321.6802,N,00630.3372"), "field count", "4 to 7"),
        (nmea_sentence("GPGLL,,,,,092750.000,A,A"), "latitude", "ddmm"),
        (nmea_sentence(GGA_BODY + ",extra"), "field count", "14 fields"),
        (nmea_sentence("GPGST,092750.000,0.01,0.01"), "field count", "8 fields"),
        (with_field(GGA, 6, "0"), "no fix", "no fix"),
        (nmea_sentence("GPGGA,,,,,,0,00,99.99,,,,,,"), "no fix", "no fix"),  # a receiver still searching
        (with_field(GGA, 6, "9"), "quality", "fix quality"),
        (with_field(GGA, 1, "246000"), "time", "time out of range"),
        (with_field(GGA, 1, "12:00:00"), "time", "hhmmss"),
        (with_field(GGA, 2, "9100.0000"), "latitude", "latitude out of range"),
        (with_field(GGA, 2, "4060.0000"), "latitude", "latitude out of range"),
        (with_field(GGA, 2, "53.216802"), "latitude", "ddmm.mmmm"),
        (with_field(GGA, 3, "X"), "latitude", "hemisphere"),
        (with_field(GGA, 4, "18000.0001"), "longitude", "longitude out of range"),
        (with_field(GGA, 5, ""), "longitude", "hemisphere"),
        (with_field(GGA, 7, "100"), "satellites", "0-99"),
        (with_field(GGA, 8, "-1.0"), "hdop", "HDOP"),
        (with_field(GGA, 8, "nan"), "hdop", "HDOP"),
        (with_field(GGA, 9, "inf"), "altitude", "altitude"),
        (with_field(GGA, 9, "1e3"), "altitude", "altitude"),
        (with_field(GGA, 9, "99999"), "altitude", "outside"),
        (with_field(GGA, 10, "F"), "altitude", "unit"),
        (with_field(GGA, 11, "300.0"), "geoid", "geoid"),
        (with_field(GGA, 12, "F"), "geoid", "unit"),
        (with_field(GGA, 13, "-1"), "dgps", "age"),
        (with_field(GGA, 14, "1024"), "dgps", "station"),
        (with_field(GST, 6, ""), "sigma", "latitude sigma"),
        (with_field(GST, 8, "-0.1"), "sigma", "altitude sigma"),
        (with_field(GST, 7, "9" * 400), "framing", "characters"),
        (with_field(GST, 5, "400"), "orientation", "orientation"),
    ],
)
def test_each_rejection_has_its_reason_and_names_the_field(line, reason, words):
    with pytest.raises(NmeaError) as info:
        parse_sentence(line)
    assert info.value.reason == reason
    assert words in str(info.value)


@pytest.mark.parametrize(
    "line, expected",
    [
        # what a real receiver's log holds beside its fixes: parsed, checked, not an error
        (nmea_sentence("GPGSV,3,1,11,03,03,111,00,04,15,270,00,06,01,010,00,13,06,292,00"), Other("GP", "GSV")),
        (nmea_sentence("GNGSA,A,3,10,07,05,02,29,04,08,13,,,,,1.72,1.03,1.38"), Other("GN", "GSA")),
        (nmea_sentence("GPVTG,054.7,T,034.4,M,005.5,N,010.2,K"), Other("GP", "VTG")),
        (nmea_sentence("GPZDA,201530.00,04,07,2002,00,00"), Other("GP", "ZDA")),
        (nmea_sentence("SDDPT,3.4,0.0"), Other("SD", "DPT")),
        (nmea_sentence("HCHDG,101.1,,,7.1,W"), Other("HC", "HDG")),
        (nmea_sentence("WIMWV,214.8,R,0.1,K,A"), Other("WI", "MWV")),
        (nmea_sentence("PUBX,00,081350.00,4717.113210,N"), Other("", "PUBX")),
        (nmea_sentence("PGRME,15.0,M,45.0,M,25.0,M"), Other("", "PGRME")),
        ("!AIVDM,1,1,,A,13aEOK?P00PD2wVMdLDRhgvL289?,0*26", Other("", "!AIVDM")),
    ],
)
def test_sentences_without_a_position_are_recognised_not_rejected(line, expected):
    assert parse_sentence(line) == expected


def test_position_forms_from_any_talker_with_null_fields():
    # whole seconds, an integer altitude, no geoid separation (its unit kept), no HDOP: all allowed
    gga = parse_sentence(nmea_sentence("INGGA,094736,4807.038,N,01131.000,E,1,,,545,M,,M,,"))
    assert (gga.talker, gga.seconds_of_day, gga.altitude_m, gga.geoid_separation_m, gga.hdop, gga.satellites) == (
        "IN",
        9 * 3600 + 47 * 60 + 36,
        545.0,
        None,
        None,
        None,
    )
    no_altitude = parse_sentence(nmea_sentence("GNGGA,094736.00,3351.5040,S,15112.8110,E,4,12,0.6,,,,,,"))
    assert no_altitude.altitude_m is None and no_altitude.lat == pytest.approx(-(33 + 51.504 / 60))
    whole_minutes = parse_sentence(nmea_sentence("GPGGA,094736,4807,N,01131,E,1,08,0.9,545.4,M,47.0,M,,"))
    assert whole_minutes.lat == pytest.approx(48 + 7 / 60)
    rmc = parse_sentence(nmea_sentence("GARMC,123519,A,4807.038,N,01131.000,E,022.4,084.4,230394,003.1,W"))
    assert isinstance(rmc, Rmc) and rmc.date == "230394" and rmc.altitude_m is None
    gll = parse_sentence(nmea_sentence("BDGLL,4916.45,N,12311.12,W"))  # the oldest form: no time
    assert isinstance(gll, Gll) and gll.time == "" and gll.lon == pytest.approx(-(123 + 11.12 / 60))


@settings(max_examples=300, deadline=None)
@given(line=st.one_of(valid_gga(nulls=True), valid_rmc(), valid_gll()))
def test_every_valid_form_of_the_position_sentences_agrees_with_pynmea2(line):
    assert_same_as_pynmea2(line, parse_sentence(line))


def test_a_number_too_big_for_a_float_is_rejected(monkeypatch):
    # 400 digits read as float('inf'): even past the line-length guard, no infinite sigma gets out
    from perception import nmea_parser as nmea

    monkeypatch.setattr(nmea, "MAX_LINE_CHARS", 1000)
    with pytest.raises(NmeaError, match="not finite") as info:
        parse_sentence(with_field(GST, 7, "9" * 400))
    assert info.value.reason == "sigma"


# ---- fuzzing: malformed lines -------------------------------------------------------------------

BAD_FIELDS = {  # field index (0 = address) -> values that must be refused, with the reason
    1: (["246000", "126000", "120060.00", "12000", "1200000", "ab0000", "nan", "-12000"], "time"),
    2: (["", "9100.0", "4060.0", "400.0", "-4025.1", "4025.1e1", "9000.0001", "inf", "40 25.1"], "latitude"),
    3: (["", "E", "n", "X", "NN"], "latitude"),
    4: (["", "18100.0", "00360.0", "0036.0", "nan", "+00342.1"], "longitude"),
    5: (["", "N", "w", "EW"], "longitude"),
    6: (["", "9", "-1", "10", "a", "4.0"], "quality"),
    7: (["100", "-1", "1.5", "x", "1e1"], "satellites"),
    8: (["-0.5", "nan", "inf", "1e3", "Infinity", "0x1"], "hdop"),
    9: (["nan", "-inf", "1e3", "99999", "-5000", "--1", "1.2.3"], "altitude"),
    10: (["", "F", "m", "MM"], "altitude"),
    11: (["nan", "500", "x", "1e1"], "geoid"),
    12: (["F", "", "m"], "geoid"),
    13: (["-1", "nan", "x", "1e1"], "dgps"),
    14: (["1024", "-1", "x", "12345", "1.0"], "dgps"),
}


@FUZZ
@given(line=valid_gga(), data=st.data())
def test_a_bad_field_with_a_valid_checksum_is_rejected_for_that_field(line, data):
    index = data.draw(st.sampled_from(sorted(BAD_FIELDS)))
    values, reason = BAD_FIELDS[index]
    value = data.draw(st.sampled_from(values))
    fields = line[1 : line.index("*")].split(",")
    if index == 12:  # a wrong geoid unit counts only when a separation is given
        assume(fields[11] != "")
    bad = with_field(line, index, value)
    assert reject_reason(bad) == reason


@FUZZ
@given(line=st.one_of(valid_gga(), valid_gst()), cut=st.integers(0, 200))
def test_a_truncated_sentence_is_rejected(line, cut):
    assert reject_reason(line[: min(cut, len(line) - 1)]) in {"framing", "checksum"}


@FUZZ
@given(
    line=st.one_of(valid_gga(), valid_gst()),
    pos=st.integers(1, 200),
    char=st.characters(codec="ascii", exclude_characters="\r\n"),
)
def test_a_changed_character_without_a_new_checksum_is_rejected(line, pos, char):
    pos = min(pos, line.index("*") - 1)  # in the body: the checksum covers it
    assume(line[pos] != char)
    changed = line[:pos] + char + line[pos + 1 :]
    assert reject_reason(changed) in {"framing", "checksum"}


@FUZZ
@given(line=st.one_of(valid_gga(), valid_gst()), data=st.data())
def test_a_field_added_or_removed_is_a_field_count_error(line, data):
    fields = line[1 : line.index("*")].split(",")
    if data.draw(st.booleans()):
        fields.insert(data.draw(st.integers(1, len(fields))), data.draw(st.sampled_from(["", "1", "M"])))
    else:
        fields.pop(data.draw(st.integers(1, len(fields) - 1)))
    assert reject_reason(nmea_sentence(",".join(fields))) == "field count"


@FUZZ
@given(line=st.one_of(valid_gga(), valid_gst()), data=st.data())
def test_random_field_text_with_a_valid_checksum_never_escapes_and_never_lies(line, data):
    """Replace a field by arbitrary printable text: either NmeaError, or a sentence that pynmea2
    reads the same way (the replacement happened to be valid)."""
    fields = line[1 : line.index("*")].split(",")
    index = data.draw(st.integers(1, len(fields) - 1))
    fields[index] = data.draw(
        st.text(
            st.characters(codec="ascii", min_codepoint=32, max_codepoint=126, exclude_characters="$*,"), max_size=12
        )
    )
    mutated = nmea_sentence(",".join(fields))
    try:
        parsed = parse_sentence(mutated)
    except NmeaError as exc:
        assert exc.reason != "internal", exc
        return
    assert_same_as_pynmea2(mutated, parsed)


@FUZZ
@given(
    raw=st.one_of(
        st.binary(max_size=120),
        st.text(max_size=120),
        st.text(st.sampled_from("$GPGAST,*0123456789.NSEWM-\r\n"), max_size=90),
    )
)
def test_random_bytes_and_text_raise_only_nmea_errors(raw):
    try:
        parsed = parse_sentence(raw)
    except NmeaError as exc:
        assert exc.reason != "internal", exc
        return
    pytest.fail(f"random input parsed as {parsed!r}")  # would need a valid checksum and fields


@settings(max_examples=100, deadline=None)
@given(
    lines=st.lists(
        st.one_of(
            valid_gga().map(lambda s: (s, None)),
            valid_gst().map(lambda s: (s, None)),
            st.sampled_from(list(BAD_FIELDS)).flatmap(
                lambda i: st.sampled_from(BAD_FIELDS[i][0][:3]).map(
                    lambda v, i=i: (with_field(GGA, i, v), BAD_FIELDS[i][1])
                )
            ),
            st.just((GGA[:-2] + "00", "checksum")),
            st.just((GGA[:20], "framing")),
        ),
        max_size=20,
    )
)
def test_the_reader_counts_every_line_by_reason(lines):
    reader = NmeaReader()
    out = list(reader.read(line for line, _ in lines))
    expected_rejects = collections.Counter(reason for _, reason in lines if reason is not None)
    assert reader.rejected == expected_rejects
    assert len(out) == reader.total_accepted == sum(1 for _, reason in lines if reason is None)
    assert reader.total_accepted + reader.total_rejected == len(lines)
    if expected_rejects:
        assert reader.last_error is not None


def test_checksum_is_the_xor_between_dollar_and_star():
    # GGA_BODY is a sentence from a real receiver's manual, with its checksum 76
    assert checksum(GGA_BODY) == "76"
    assert GGA == f"${GGA_BODY}*76"
