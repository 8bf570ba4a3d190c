"""The Velodyne wire format (ares/core/wire/velodyne.py): packets encoded from a synthetic scene
decode to the cast points, agree with an independent decoder (PyPI velodyne_decoder), and the
rotation assembler counts malformed packets, lost packets, truncated rotations and the rate."""

from __future__ import annotations

import struct

import numpy as np
import pytest
import velodyne_decoder as vd
from scipy.spatial import cKDTree

from ares.core.wire import velodyne as v

VD_MODEL = {
    "VLP-16": vd.Model.VLP16,
    "HDL-32E": vd.Model.HDL32E,
    "VLP-32C": vd.Model.VLP32C,
    "HDL-64E": vd.Model.HDL64E_S3,
    "VLS-128": vd.Model.AlphaPrime,
}
EVERY_MODE = [(model, mode) for model in v.MODELS for mode in ("strongest", "dual")]


def scene(directions: np.ndarray, height: float = 1.8) -> tuple[np.ndarray, np.ndarray]:
    """Ranges along each ray to a ground plane `height` below and a vertical cylinder (radius 1 m
    at x 6, y -3), 0 beyond 80 m: (nearest, the plane's where the cylinder hides it)."""
    d = directions.astype(np.float64)
    dz = d[..., 2]
    t_plane = np.where(dz < -1e-3, -height / np.minimum(dz, -1e-3), np.inf)
    cx, cy, radius = 6.0, -3.0, 1.0
    a = d[..., 0] ** 2 + d[..., 1] ** 2
    b = -2 * (d[..., 0] * cx + d[..., 1] * cy)
    disc = b * b - 4 * a * (cx * cx + cy * cy - radius * radius)
    t_cyl = np.where(disc > 0, (-b - np.sqrt(np.maximum(disc, 0))) / (2 * a), np.inf)
    nearest = np.minimum(t_plane, t_cyl)
    nearest = np.where(nearest < 80, nearest, 0.0)
    behind = np.where((t_cyl < t_plane) & (t_plane < 80), t_plane, nearest)
    return nearest, behind


def encoded(model: str, mode: str, first_us: int = 123_456, phase_deg: float = 0.0):
    cal = v.load_calibration(model)
    pattern = v.firing_pattern(cal, 10.0, mode, phase_deg=phase_deg)
    nearest, behind = scene(pattern.directions)
    intensity = (np.arange(nearest.size).reshape(nearest.shape) % 256) / 255.0
    packets = v.encode_rotation(
        cal, pattern, nearest, intensity, pattern.timestamps_us(first_us), last_distance_m=behind
    )
    return cal, pattern, nearest, behind, packets


def reference(cal: v.Calibration, packets: list[bytes]) -> np.ndarray:
    """velodyne_decoder's points (x, y, z, intensity, time, column, ring, return), same calibration file."""
    decoder = vd.ScanDecoder(
        vd.Config(model=VD_MODEL[cal.model], calibration=vd.Calibration.read(cal.path), min_range=0.001)
    )
    _, cloud = decoder.decode(vd.PacketVector([vd.VelodynePacket(0.0, np.frombuffer(p, np.uint8)) for p in packets]))
    return cloud


@pytest.mark.parametrize(("model", "mode"), EVERY_MODE)
def test_agrees_with_velodyne_decoder(model, mode):
    cal, pattern, _, _, packets = encoded(model, mode)
    mine = v.decode(cal, packets)
    theirs = reference(cal, packets)
    assert mine.size == len(theirs) > 10_000
    if model == "VLS-128":
        # velodyne_decoder turns the VLS-128's first packet at rate 0 (it has no packet before it)
        # and times it by the newer firmware's channel until it has seen two: beyond that first
        # packet, every point is the same to the float
        xyz = np.stack([mine.x, mine.y, mine.z], axis=1)
        distance, nearest = cKDTree(theirs[:, :3]).query(xyz)
        later = mine.firing >= pattern.firings_per_packet
        assert distance[later].max() < 1e-3 and distance[~later].max() < 0.2
        assert np.array_equal(mine.ring, theirs[nearest, 6].astype(np.uint8))
        return
    # the same ROS frame and ring convention (0 = lowest laser): match point for point by firing
    # time (each (packet, laser) fires at its own instant), ring and return
    order_theirs = np.lexsort((theirs[:, 7], theirs[:, 6], theirs[:, 4]))
    order_mine = np.lexsort((mine.returns, mine.ring, mine.time))
    theirs = theirs[order_theirs]
    xyz = np.stack([mine.x, mine.y, mine.z], axis=1)[order_mine]
    assert np.abs(xyz - theirs[:, :3]).max() < 1e-3
    assert np.array_equal(mine.ring[order_mine], theirs[:, 6].astype(np.uint8))
    assert np.array_equal(mine.returns[order_mine], theirs[:, 7].astype(np.uint8))
    assert np.allclose(mine.intensity[order_mine] * 255, theirs[:, 3], atol=1e-3)
    if mode == "dual":
        assert set(np.unique(mine.returns)) == {v.STRONGEST, v.LAST, v.BOTH}


@pytest.mark.parametrize(("model", "mode"), [(model, "strongest") for model in v.MODELS] + [("VLP-16", "last")])
def test_decode_gives_back_the_cast_points(model, mode):
    cal, pattern, nearest, _, packets = encoded(model, mode, phase_deg=0.37)
    assert len(packets) == pattern.packets and all(len(p) == v.PACKET_SIZE for p in packets)
    points = v.decode(cal, packets)
    slot = (points.firing, points.laser)
    cast = pattern.directions[slot] * nearest[slot][:, None]
    assert points.size == int((nearest > 0).sum())
    half_step = cal.distance_resolution / 2 + 1e-4  # 2 mm steps (the 32C's and the 128's: 4 mm)
    assert np.abs(np.stack([points.x, points.y, points.z], axis=1) - cast).max() <= half_step
    assert np.array_equal(np.round(points.azimuth * 100).astype(np.int32), pattern.azimuth_cdeg[slot])
    assert np.array_equal(points.ring, cal.ring[points.laser])
    assert points.returns[0] == (v.LAST if mode == "last" else v.STRONGEST)
    # ring 0 is the lowest laser, the top ring the highest
    elevation = np.degrees(np.arcsin(points.z / np.linalg.norm(np.stack([points.x, points.y, points.z], 1), axis=1)))
    top = points.ring == cal.lasers - 1
    assert elevation[points.ring == 0].max() < elevation[top].min()


def test_calibrations_match_the_simulated_sensor():
    from ares.core.config.vehicle import LIDAR_MODELS

    for model, sim in (("VLP-16", "vlp16"), ("HDL-64E", "hdl64e")):
        cal = v.load_calibration(model)
        angles = np.sort(np.degrees(cal.vert_correction))
        assert np.allclose(angles, LIDAR_MODELS[sim].elevations_deg(), atol=1e-6)
        assert np.array_equal(np.sort(cal.ring), np.arange(cal.lasers))


@pytest.mark.parametrize(
    ("model", "lasers", "bottom", "top"),
    [("HDL-32E", 32, -30.67, 10.67), ("VLP-32C", 32, -25.0, 15.0), ("VLS-128", 128, -25.0, 15.0)],
)
def test_the_other_models_calibrations(model, lasers, bottom, top):
    """The field of view of each model's manual, every laser a ring of its own."""
    cal = v.load_calibration(model)
    assert cal.lasers == lasers == v.MODEL_SPECS[model].lasers
    angles = np.degrees(cal.vert_correction)
    assert angles.min() == pytest.approx(bottom, abs=0.01) and angles.max() == pytest.approx(top, abs=0.01)
    assert np.array_equal(np.sort(cal.ring), np.arange(lasers)) and not cal.advanced


def test_bad_calibration_file(tmp_path):
    bad = tmp_path / "cal.yaml"
    bad.write_text("lasers:\n  - {laser_id: 0, rot_correction: 0, vert_correction: 0}\nnum_lasers: 1\n")
    with pytest.raises(ValueError, match="a VLP-16 has 16"):
        v.load_calibration("VLP-16", bad)
    with pytest.raises(ValueError, match="no such"):
        v.load_calibration("VLP-16", tmp_path / "missing.yaml")


def stream(model: str, mode: str, rotations: int, rate_hz: float = 10.0):
    """Packets of consecutive rotations with continuous timestamps."""
    cal = v.load_calibration(model)
    pattern = v.firing_pattern(cal, rate_hz, mode)
    nearest, _ = scene(pattern.directions)
    intensity = np.full(nearest.shape, 0.4)
    out = []
    first_us = 3_599_000_000  # across the top of the hour
    for k in range(rotations):
        start = first_us + round(k * 1e6 / rate_hz)
        out += v.encode_rotation(cal, pattern, nearest, intensity, pattern.timestamps_us(start))
    return cal, pattern, out


def test_assembler_cuts_rotations_without_waiting_for_the_next():
    cal, pattern, packets = stream("VLP-16", "strongest", 3)
    asm = v.RotationAssembler(cal, 10.0)
    finished = []
    for i, p in enumerate(packets):
        got = asm.add(p, 1000.0 + i * 1e-3)
        if got:
            assert (i + 1) % pattern.packets == 0  # out with its last packet
        finished += got
    assert len(finished) == 3
    single = v.decode(cal, packets[: pattern.packets])
    for rot in finished:
        assert rot.packets == pattern.packets and not rot.truncated
        assert rot.points.size == single.size
        assert rot.coverage_deg == pytest.approx(360.0, abs=0.05)
        assert rot.rate_hz == pytest.approx(10.0, rel=1e-3)
    assert finished[1].timestamp_us == (3_599_000_000 + 100_000) % v.HOUR_US
    assert asm.lost == 0 and asm.truncated == 0 and not asm.malformed
    assert asm.measured_rate_hz == pytest.approx(10.0, rel=1e-3)


def test_assembler_counts_lost_packets_and_truncated_rotations():
    cal, pattern, packets = stream("HDL-64E", "strongest", 3)
    n = pattern.packets
    kept = packets[:10] + packets[13:n] + packets[n + 200 :]  # 3 lost mid-rotation, 200 across the cut
    asm = v.RotationAssembler(cal, 10.0)
    finished = [r for i, p in enumerate(kept) for r in asm.add(p, float(i))]
    assert asm.lost == 203
    assert [r.truncated for r in finished] == [False, True, False]  # the second has under 1/3 of a turn
    assert asm.truncated == 1
    assert finished[0].coverage_deg == pytest.approx(360.0, abs=0.05)
    assert finished[0].packets == n - 3


def test_assembler_starting_mid_rotation_and_dual_mode():
    cal, pattern, packets = stream("VLP-16", "dual", 2)
    n = pattern.packets
    asm = v.RotationAssembler(cal, 10.0)
    finished = [r for i, p in enumerate(packets[n // 2 :]) for r in asm.add(p, float(i))]
    assert [r.truncated for r in finished] == [True, False]
    assert finished[1].return_mode == "dual" and finished[1].packets == n
    assert asm.lost == 0


def test_rotation_rate_measured():
    cal, _, packets = stream("VLP-16", "strongest", 3, rate_hz=5.0)
    asm = v.RotationAssembler(cal, 10.0)
    finished = [r for i, p in enumerate(packets) for r in asm.add(p, float(i))]
    assert len(finished) == 3
    assert asm.measured_rate_hz == pytest.approx(5.0, rel=1e-3)


def corrupt(packet: bytes, offset: int, value: bytes) -> bytes:
    return packet[:offset] + value + packet[offset + len(value) :]


def test_malformed_packets_counted_by_cause():
    cal, pattern, packets = stream("VLP-16", "strongest", 1)
    good = packets[0]
    bad = [
        good[:1000],  # short
        good + b"\x00",  # long
        corrupt(good, 100, b"\xff\xdd"),  # block 1's flag: a VLP-16 has no lower block
        corrupt(good, 202, struct.pack("<H", 36001)),  # block 2's azimuth past 360°
        corrupt(good, 1204, b"\x40"),  # unknown return mode
    ]
    asm = v.RotationAssembler(cal, 10.0)
    finished = []
    for i, p in enumerate(bad + packets):
        finished += asm.add(p, float(i))
    assert asm.malformed == {"wrong size": 2, "bad block flag": 1, "azimuth > 36000": 1, "unknown return mode": 1}
    assert [cause for cause, _ in asm.refused][:2] == ["wrong size", "wrong size"]
    assert len(finished) == 1 and finished[0].packets == pattern.packets  # the good ones untouched
    hdl = v.load_calibration("HDL-64E")
    _, cause, _ = v.check_packet(
        "HDL-64E",
        corrupt(
            v.encode_rotation(
                hdl,
                p := v.firing_pattern(hdl, 10.0),
                np.zeros((p.firings, 64)),
                np.zeros((p.firings, 64)),
                p.timestamps_us(0),
            )[0],
            0,
            b"\x00\x00",
        ),
    )
    assert cause == "bad block flag"


def test_the_configured_model_decides_whatever_the_factory_byte_says():
    """Early VLP-16s write the HDL-32E's factory byte (0x21): counted and reported once, decoded as
    the VLP-16 it is configured to be. Before: every packet refused ("unknown product")."""
    cal, pattern, packets = stream("VLP-16", "strongest", 2)
    early = [corrupt(p, 1205, b"\x21") for p in packets]
    asm = v.RotationAssembler(cal, 10.0)
    finished = [r for i, p in enumerate(early) for r in asm.add(p, float(i))]
    assert len(finished) == 2 and not asm.malformed
    assert finished[0].points.size == v.decode(cal, packets[: pattern.packets]).size
    assert asm.factory_bytes == {0x21: len(packets)}
    assert asm.notices == [("factory byte 0x21", "factory byte 0x21 says HDL-32E; decoding as the configured VLP-16")]
    assert v.factory_mismatch("VLP-16", 0x24).startswith("factory byte 0x24 says Puck Hi-Res")
    assert v.factory_mismatch("HDL-64E", 0x21) is None  # its byte there is a status byte
    assert v.factory_mismatch("VLS-128", 0xA1) is None


def test_azimuth_36000_is_0():
    cal, pattern, packets = stream("VLP-16", "strongest", 1)
    first = packets[0]
    assert struct.unpack_from("<H", first, 2)[0] == 0
    header, cause, _ = v.check_packet("VLP-16", corrupt(first, 2, struct.pack("<H", 36000)))
    assert cause == "" and header is not None and header.first_azimuth == 0
    same = v.decode(cal, [corrupt(first, 2, struct.pack("<H", 36000))])
    assert np.array_equal(same.x, v.decode(cal, [first]).x)


def test_a_stalled_azimuth_is_cut_by_packet_count():
    """A sensor whose azimuth stops (every block at one azimuth, packet after packet): before, the
    assembler held all 20,000 packets and gave 0 rotations; now it cuts at max_packets, holds no
    more, and reports it once."""
    cal, pattern, packets = stream("VLP-16", "strongest", 1)
    stuck = packets[10]
    for block in range(v.BLOCKS):
        stuck = corrupt(stuck, 100 * block + 2, struct.pack("<H", 12345))
    asm = v.RotationAssembler(cal, 10.0)
    timestamp = struct.unpack_from("<I", stuck, 1200)[0]
    finished = []
    for i in range(20_000):
        packet = corrupt(stuck, 1200, struct.pack("<I", (timestamp + round(i * 1327.1)) % v.HOUR_US))
        finished += asm.add(packet, float(i))
        assert len(asm._pending.payloads) < asm.max_packets
    assert asm.max_packets == 377  # 2.5 dual-mode rotations at 10 Hz
    assert asm.azimuth_stalls == 20_000 // asm.max_packets
    assert all(r.truncated for r in finished) and len(finished) == asm.azimuth_stalls
    assert [cause for cause, _ in asm.notices] == ["azimuth stalled"]
    # turning again: whole rotations, and the next stall is reported anew
    finished = [r for i, p in enumerate(stream("VLP-16", "strongest", 3)[2]) for r in asm.add(p, float(i))]
    assert sum(not r.truncated for r in finished) >= 2


def test_a_field_of_view_cuts_at_its_start_and_hides_no_loss():
    """A sensor set to send 270°..90° only: rotations from 270° round to 90°, the hidden half no loss."""
    cal, pattern, packets = stream("VLP-32C", "strongest", 4)
    az = np.array([struct.unpack_from("<H", p, 2)[0] for p in packets])
    shown = (az >= 27000) | (az < 9000)
    asm = v.RotationAssembler(cal, 10.0, fov_deg=(270.0, 90.0))
    finished = [r for i, p in enumerate(np.array(packets, dtype=object)[shown]) for r in asm.add(p, float(i))]
    whole = [r for r in finished if not r.truncated]
    assert len(whole) >= 3 and asm.lost == 0
    assert all(r.coverage_deg == pytest.approx(180.0, abs=2.5) for r in whole)  # within a packet
    assert all(r.rate_hz == pytest.approx(10.0, rel=1e-2) for r in whole)
    plain = v.RotationAssembler(cal, 10.0)  # the same packets, no field of view set: the hidden half lost
    [plain.add(p, 0.0) for p in np.array(packets, dtype=object)[shown]]
    assert plain.lost > 100


def test_a_sensor_turning_slower_than_configured_is_not_cut():
    """Configured 20 Hz, turning at 5 Hz in dual mode: four times the packets a rotation was thought
    to have, but the azimuth turns: whole rotations, no stall, and the true rate measured."""
    cal, pattern, packets = stream("VLP-16", "dual", 3, rate_hz=5.0)
    asm = v.RotationAssembler(cal, 20.0)
    finished = [r for i, p in enumerate(packets) for r in asm.add(p, float(i))]
    assert [r.truncated for r in finished] == [False, False, False] and asm.azimuth_stalls == 0
    assert asm.measured_rate_hz == pytest.approx(5.0, rel=1e-3)
