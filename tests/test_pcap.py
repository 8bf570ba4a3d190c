"""Packet captures read in place of a socket (ares/core/wire/pcap.py): a real capture's datagrams
come back the same from the link types and file formats captures come in (classic pcap and
pcapng, Ethernet, raw IP, Linux cooked), and a CapturePlayer plays them by their capture times."""

from __future__ import annotations

from pathlib import Path

import dpkt
import pytest

from ares.core.wire.pcap import CaptureCounts, CapturePlayer, udp_datagrams

REAL = Path(__file__).parent / "data" / "lidar" / "VLP-32C_fov.pcap"


def rewrite(path: Path, link: int, pcapng: bool, datagrams) -> None:
    """The datagrams again, framed for `link`, in the other formats tcpdump and Wireshark write."""
    with path.open("wb") as handle:
        writer = (dpkt.pcapng.Writer if pcapng else dpkt.pcap.Writer)(handle, snaplen=65535, linktype=link)
        for d in datagrams:
            udp = dpkt.udp.UDP(sport=d.source_port, dport=d.port, data=d.payload)
            udp.ulen = len(udp)
            ip = dpkt.ip.IP(src=bytes(map(int, d.source.split("."))), dst=b"\xff" * 4, p=17, data=udp)
            ip.len = len(ip)
            if link == 101:  # raw IP
                frame = bytes(ip)
            elif link == 113:  # Linux cooked
                frame = bytes(
                    dpkt.sll.SLL(type=0, ethtype=0x0800, hlen=6, hdr=b"\x60\x76\x88\x00\x00\x01\x00\x00", data=ip)
                )
            else:
                frame = bytes(dpkt.ethernet.Ethernet(src=b"\x60\x76\x88\x00\x00\x01", dst=b"\xff" * 6, data=ip))
            writer.writepkt(frame, ts=d.time)


@pytest.mark.parametrize(("link", "pcapng"), [(1, True), (101, False), (113, False), (113, True)])
def test_the_same_datagrams_from_every_framing(tmp_path, link, pcapng):
    original = list(udp_datagrams(REAL))
    path = tmp_path / f"capture.{'pcapng' if pcapng else 'pcap'}"
    rewrite(path, link, pcapng, original)
    again = list(udp_datagrams(path))
    assert [d.payload for d in again] == [d.payload for d in original] and len(original) == 303
    assert [d.port for d in again] == [2368] * 303 and again[0].source == original[0].source
    assert [d.time for d in again] == pytest.approx([d.time for d in original], abs=1e-6)


def test_a_capture_cut_short_and_frames_that_are_not_udp(tmp_path):
    data = REAL.read_bytes()
    cut = tmp_path / "cut.pcap"
    cut.write_bytes(data[: len(data) // 2 + 100])  # a capture stopped mid-frame
    counts = CaptureCounts()
    got = list(udp_datagrams(cut, counts))
    assert 140 < len(got) < 160 and counts.skipped == {"truncated": 1}  # the last frame, cut
    mixed = tmp_path / "mixed.pcap"
    with mixed.open("wb") as handle:
        writer = dpkt.pcap.Writer(handle)
        writer.writepkt(bytes(dpkt.ethernet.Ethernet(type=0x0806, data=b"\x00" * 28)), ts=1.0)  # ARP
        tcp = dpkt.ip.IP(p=6, data=dpkt.tcp.TCP(sport=1, dport=2))
        writer.writepkt(bytes(dpkt.ethernet.Ethernet(data=tcp)), ts=1.1)
    counts = CaptureCounts()
    assert list(udp_datagrams(mixed, counts)) == [] and counts.skipped == {"not UDP": 2}
    with pytest.raises(ValueError, match="cannot open the capture"):
        list(udp_datagrams(tmp_path / "none.pcap"))


def test_a_player_plays_by_capture_time_and_loops():
    first = list(udp_datagrams(REAL))
    span = first[-1].time - first[0].time
    player = CapturePlayer(REAL, port=2368, loop=True)
    assert player.due(0.0) == first[:1]
    assert len(player.due(span / 2)) == sum(span / 2 >= d.time - first[0].time > 0 for d in first)
    rest = player.due(span + 1e-9)
    assert player.loops == 0 and rest[-1] == first[-1]
    again = player.due(2 * span + 1e-3 + 1e-9)  # the second pass, right after the first
    assert player.loops == 1 and [d.payload for d in again] == [d.payload for d in first]
    assert not player.finished
    once = CapturePlayer(REAL, port=2368)
    assert len(once.due(1e9)) == 303 and once.due(2e9) == [] and once.finished
    other = CapturePlayer(REAL, port=2369)
    assert other.due(1e9) == [] and other.finished and other.other == {f"{first[0].source}:2368": 303}
