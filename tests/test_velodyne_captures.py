"""Real Velodyne captures (tests/data/lidar, sources and licences in tests/data/README.md) through
the LiDAR driver's assembler and decoder, as `ares perception scan FILE.pcap` reads them: the
rotations, points per rotation and rate each file holds, against the sensor maker's viewer
(VeloView's own test figures) and an independent decoder (velodyne_decoder) on the same bytes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import velodyne_decoder as vd

from ares import cli
from ares.core.wire.pcap import CaptureCounts, udp_datagrams
from perception.scan_file import read_capture

LIDAR = Path(__file__).parent / "data" / "lidar"
VD_MODEL = {"VLP-16": vd.Model.VLP16, "HDL-32E": vd.Model.HDL32E, "VLP-32C": vd.Model.VLP32C}
VD_MODEL["VLS-128"] = vd.Model.AlphaPrime

# file, model, field of view, whole rotations, rate (Hz), factory bytes that disagree
CAPTURES = [
    ("VLP-16_early_20Hz.pcap", "VLP-16", None, 50, 20.0, {"0x21": 1902}),
    ("VLP-16_dual.pcap", "VLP-16", None, 4, 10.0, {}),
    ("HDL-32E.pcap", "HDL-32E", None, 11, 11.77, {}),
    ("VLP-32C_fov.pcap", "VLP-32C", (270.0, 90.0), 3, 10.0, {}),
    ("VLS-128.pcap", "VLS-128", None, 3, 10.0, {}),
]


def independent_points(path, model: str) -> int:
    """velodyne_decoder's points over the whole capture (its own cuts: per-scan counts differ, the
    sum does not). It refuses a factory byte that disagrees, so the early VLP-16's is set right."""
    packets = []
    for datagram in udp_datagrams(path):
        if datagram.port == 2368:
            payload = bytearray(datagram.payload)
            if model == "VLP-16":
                payload[1205] = 0x22
            packets.append(vd.VelodynePacket(datagram.time, np.frombuffer(bytes(payload), np.uint8)))
    decoder = vd.ScanDecoder(vd.Config(model=VD_MODEL[model], min_range=0.001, max_range=1000.0))
    _, cloud = decoder.decode(vd.PacketVector(packets))
    return len(cloud)


@pytest.mark.parametrize(("name", "model", "fov", "rotations", "rate", "factory"), CAPTURES)
def test_each_capture_cuts_into_its_rotations(name, model, fov, rotations, rate, factory):
    scan, summary = read_capture(LIDAR / name, model, frame=1, fov_deg=fov)
    assert summary.rotations == rotations and summary.lost == 0 and not summary.malformed
    assert summary.rate_hz == pytest.approx(rate, rel=0.005)
    assert summary.factory_bytes == factory
    assert len(scan.points) == summary.points_per_rotation[1]
    lasers = {"VLP-16": 16, "HDL-32E": 32, "VLP-32C": 32, "VLS-128": 128}[model]
    assert scan.ring.max() < lasers and len(np.unique(scan.ring)) >= lasers - 1  # a laser may see nothing


@pytest.mark.parametrize(("name", "model"), [(c[0], c[1]) for c in CAPTURES if c[2] is None])
def test_every_point_as_an_independent_decoder_finds_it(name, model):
    _, summary = read_capture(LIDAR / name, model)
    assert summary.points_total == independent_points(LIDAR / name, model)


def test_the_early_vlp16_as_veloview_cuts_it():
    """The issue's capture: an early VLP-16 (factory byte 0x21, the HDL-32E's) at 20 Hz. Before, every
    packet was refused and one more for azimuth 36000. VeloView reads 52 frames, frame 2 of 13,898
    points and frame 16 of 13,860; ours are cut at packet edges (37-38 packets, 384 returns each)."""
    counts = CaptureCounts()
    datagrams = list(udp_datagrams(LIDAR / "VLP-16_early_20Hz.pcap", counts))
    assert counts.frames == 2269 and sum(d.port == 8308 for d in datagrams) == 367  # its position packets
    _, summary = read_capture(LIDAR / "VLP-16_early_20Hz.pcap", "VLP-16")
    assert summary.rotations + summary.truncated == 52
    each = np.array(summary.points_per_rotation)
    assert abs(each[1] - 13_898) < 384 and abs(each[15] - 13_860) < 384
    assert np.mean(each) == pytest.approx((13_898 + 13_860) / 2, rel=0.005)


def test_perception_scan_of_a_capture(tmp_path, capsys):
    picture = tmp_path / "vlp32c.png"
    argv = ["perception", "scan", str(LIDAR / "VLP-32C_fov.pcap"), "--model", "VLP-32C", "--fov", "270", "90"]
    code = cli.main([*argv, "--frame", "2", "--json", "--out", str(picture)])
    out = capsys.readouterr().out
    assert code == 0, out
    report = json.loads(out.strip().splitlines()[-1])
    assert report["rings"] == {"method": "decoder", "count": 32}
    capture = report["capture"]
    assert capture["model"] == "VLP-32C" and capture["rotations"] == 3 and capture["frame"] == 2
    assert report["points"] == capture["points_per_rotation"]["each"][2] > 25_000
    assert report["points_after_filters"] > 0.8 * report["points"] and picture.stat().st_size > 10_000
    # a frame beyond the capture, and a model its bytes do not name
    assert cli.main([*argv, "--frame", "3", "--out", str(picture)]) == 2
    assert "frame 3 asked, the capture has 3 whole rotations" in capsys.readouterr().err


def test_a_file_that_is_no_capture(tmp_path):
    bad = tmp_path / "x.pcap"
    bad.write_bytes(b"not a capture at all, just text\n" * 4)
    with pytest.raises(ValueError, match="not a pcap or pcapng capture"):
        list(udp_datagrams(bad))
