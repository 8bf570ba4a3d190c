"""UDP datagrams from a packet capture: the `.pcap` (classic) or `.pcapng` file a user recorded of
their sensor with tcpdump or Wireshark, read in place of a socket.

The file format is dpkt's to read (`dpkt.pcap.UniversalReader`: classic pcap in either byte order
and resolution, and pcapng); this module unwraps each frame down to UDP over IPv4 or IPv6, from
the link types captures come in: Ethernet (with VLAN tags), raw IP, Linux cooked (SLL, SLL2) and
BSD loopback. A frame that is not UDP (ARP, TCP, a GPS position packet on another port) is
skipped; one that is cut short (a snap length below the datagram) is counted as truncated. IP
fragments are not reassembled: a Velodyne's 1,206-byte payload never needs it.
"""

from __future__ import annotations

import ipaddress
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import dpkt  # type: ignore[import-untyped]

DLT_EN10MB, DLT_RAW, DLT_LINUX_SLL, DLT_NULL, DLT_LOOP = 1, 101, 113, 0, 108
DLT_IPV4, DLT_IPV6, DLT_LINUX_SLL2, DLT_RAW_OPENBSD = 228, 229, 276, 12
LINK_NAMES = {
    DLT_EN10MB: "Ethernet",
    DLT_RAW: "raw IP",
    DLT_RAW_OPENBSD: "raw IP",
    DLT_IPV4: "raw IPv4",
    DLT_IPV6: "raw IPv6",
    DLT_LINUX_SLL: "Linux cooked",
    DLT_LINUX_SLL2: "Linux cooked v2",
    DLT_NULL: "BSD loopback",
    DLT_LOOP: "BSD loopback",
}


@dataclass(frozen=True)
class Datagram:
    """One UDP datagram of a capture."""

    time: float  # the capture's timestamp, seconds (UTC epoch as the capturing machine knew it)
    source: str  # the sender's IP address
    source_port: int
    port: int  # the destination port
    payload: bytes


@dataclass
class CaptureCounts:
    frames: int = 0
    udp: int = 0
    skipped: Counter[str] = field(default_factory=Counter)  # by cause: "not UDP", "truncated", ...


def _ip_of(link: int, frame: bytes) -> dpkt.Packet | None:
    if link == DLT_EN10MB:
        return dpkt.ethernet.Ethernet(frame).data
    if link in (DLT_RAW, DLT_RAW_OPENBSD, DLT_IPV4, DLT_IPV6):
        version = frame[0] >> 4 if frame else 0
        return dpkt.ip.IP(frame) if version == 4 else dpkt.ip6.IP6(frame) if version == 6 else None
    if link == DLT_LINUX_SLL:
        return dpkt.sll.SLL(frame).data
    if link == DLT_LINUX_SLL2:
        return dpkt.sll2.SLL2(frame).data
    if link in (DLT_NULL, DLT_LOOP):
        return dpkt.loopback.Loopback(frame).data
    return None


def _address(raw: bytes) -> str:
    return str(ipaddress.ip_address(raw)) if len(raw) in (4, 16) else raw.hex()


def udp_datagrams(path: str | Path, counts: CaptureCounts | None = None) -> Iterator[Datagram]:
    """Every UDP datagram of the capture at `path`, in file order. Raises ValueError for a file that
    is not a capture, or whose link type is not one listed in LINK_NAMES."""
    counts = counts if counts is not None else CaptureCounts()
    path = Path(path)
    try:
        handle = path.open("rb")
    except OSError as exc:
        raise ValueError(f"{path}: cannot open the capture: {exc.strerror or exc}") from None
    with handle:
        try:
            reader = dpkt.pcap.UniversalReader(handle)
        except (ValueError, dpkt.dpkt.NeedData, dpkt.dpkt.UnpackError) as exc:
            raise ValueError(f"{path}: not a pcap or pcapng capture ({exc})") from None
        link = reader.datalink()
        if link not in LINK_NAMES:
            raise ValueError(f"{path}: link type {link} (not Ethernet, raw IP, Linux cooked or loopback)")
        records = iter(reader)
        while True:
            try:
                stamp, frame = next(records)
            except StopIteration:
                return
            except (dpkt.dpkt.NeedData, dpkt.dpkt.UnpackError, ValueError):  # a file cut mid-record
                counts.skipped["truncated file"] += 1
                return
            counts.frames += 1
            try:
                ip = _ip_of(link, bytes(frame))
            except (dpkt.dpkt.NeedData, dpkt.dpkt.UnpackError, IndexError):
                counts.skipped["truncated"] += 1
                continue
            udp = getattr(ip, "data", None)
            if ip is None or not isinstance(udp, dpkt.udp.UDP):
                counts.skipped["not UDP"] += 1
                continue
            payload = bytes(udp.data)
            if udp.ulen and len(payload) < udp.ulen - 8:
                counts.skipped["truncated"] += 1  # the snap length cut it
                continue
            counts.udp += 1
            yield Datagram(float(stamp), _address(ip.src), int(udp.sport), int(udp.dport), payload)


class CapturePlayer:
    """A capture played in place of a socket: `due(elapsed_s)` gives the datagrams (to `port`, from
    `source` if set) whose capture time is at most `elapsed_s` after the capture's first one.
    The file is read as it plays, never whole. With `loop`, it starts again at its end, a
    millisecond after its last datagram (`loops` counts the restarts); without, `finished`
    turns true once the last datagram is out."""

    LOOP_GAP_S = 1e-3

    def __init__(self, path: str | Path, port: int | None = None, source: str | None = None, loop: bool = False):
        self.path = Path(path)
        self.port = port
        self.source = source
        self.loop = loop
        self.counts = CaptureCounts()
        self.other: Counter[str] = Counter()  # datagrams to other ports or from other senders, by "address:port"
        self.loops = 0
        self.finished = False
        self.first_time: float | None = None
        self._shift = 0.0  # elapsed seconds the passes before this one took
        self._last_time = 0.0  # the capture time of the latest datagram given
        self._next: Datagram | None = None
        self._given_this_pass = 0
        self._new_pass = False
        self._stream = udp_datagrams(self.path, self.counts)
        self._next = self._pull()  # opens the file now: a missing or bad one raises ValueError here
        if self._next is not None:
            self.first_time = self._next.time

    def _pull(self) -> Datagram | None:
        for datagram in self._stream:
            if (self.port is None or datagram.port == self.port) and (
                self.source is None or datagram.source == self.source
            ):
                return datagram
            self.other[f"{datagram.source}:{datagram.port}"] += 1
        return None

    def play_time(self, datagram: Datagram) -> float:
        """When `datagram` plays, in seconds after the first datagram's play."""
        first = self.first_time
        assert first is not None  # set by the first datagram pulled
        return datagram.time - first + self._shift

    def due(self, elapsed_s: float, limit: int = 100_000) -> list[Datagram]:
        out: list[Datagram] = []
        while len(out) < limit and not self.finished:
            if self._next is None:
                self._next = self._pull()
                if self._next is None:
                    if not self.loop or self._given_this_pass == 0:
                        self.finished = True
                        break
                    self._given_this_pass = 0
                    first = self.first_time
                    assert first is not None  # a pass gave datagrams
                    self._shift += self._last_time - first + self.LOOP_GAP_S
                    self._stream = udp_datagrams(self.path, self.counts)
                    self._new_pass = True
                    continue
                if self.first_time is None:
                    self.first_time = self._next.time
            if self.play_time(self._next) > elapsed_s:
                break
            out.append(self._next)
            if self._new_pass:  # the pass counts once its first datagram plays
                self.loops += 1
                self._new_pass = False
            self._given_this_pass += 1
            self._last_time = self._next.time
            self._next = None
        return out
