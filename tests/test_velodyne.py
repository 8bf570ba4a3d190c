"""The Velodyne wire format (ares/core/wire/velodyne.py): packets encoded from a synthetic scene
decode to the cast points, agree with an independent decoder (PyPI velodyne_decoder), and the
rotation assembler counts malformed packets, lost packets, truncated rotations and the rate."""

from __future__ import annotations

import struct

import numpy as np
import pytest
import velodyne_decoder as vd

from ares.core.wire import velodyne as v

VD_MODEL = {"VLP-16": vd.Model.VLP16, "HDL-64E": vd.Model.HDL64E_S3}


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


@pytest.mark.parametrize(
    ("model", "mode"), [("VLP-16", "strongest"), ("VLP-16", "dual"), ("HDL-64E", "strongest"), ("HDL-64E", "dual")]
)
def test_agrees_with_velodyne_decoder(model, mode):
    cal, _, _, _, packets = encoded(model, mode)
    mine = v.decode(cal, packets)
    theirs = reference(cal, packets)
    assert mine.size == len(theirs) > 10_000
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


@pytest.mark.parametrize(("model", "mode"), [("VLP-16", "strongest"), ("VLP-16", "last"), ("HDL-64E", "strongest")])
def test_decode_gives_back_the_cast_points(model, mode):
    cal, pattern, nearest, _, packets = encoded(model, mode, phase_deg=0.37)
    assert len(packets) == pattern.packets and all(len(p) == v.PACKET_SIZE for p in packets)
    points = v.decode(cal, packets)
    slot = (points.firing, points.laser)
    cast = pattern.directions[slot] * nearest[slot][:, None]
    assert points.size == int((nearest > 0).sum())
    assert np.abs(np.stack([points.x, points.y, points.z], axis=1) - cast).max() <= 0.0011  # 2 mm steps
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
        corrupt(good, 202, struct.pack("<H", 36000)),  # block 2's azimuth past 359.99°
        corrupt(good, 1204, b"\x40"),  # unknown return mode
        corrupt(good, 1205, b"\x28"),  # not a VLP-16
    ]
    asm = v.RotationAssembler(cal, 10.0)
    finished = []
    for i, p in enumerate(bad + packets):
        finished += asm.add(p, float(i))
    assert asm.malformed == {
        "wrong size": 2,
        "bad block flag": 1,
        "azimuth > 35999": 1,
        "unknown return mode": 1,
        "unknown product": 1,
    }
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
