"""GNSS driver: the receiver's NMEA from a serial port, a TCP stream or gpsd, onto sensors/gnss.

The receiver (core section `vehicle_io.gnss`) is read without blocking at `rate_hz`: a serial
port or pseudo-terminal through pyserial, a receiver's NMEA server over TCP, or gpsd's NMEA
pass-through (ares.core.wire.gpsd). The bytes are framed into sentences (ares.core.wire.nmea_stream:
UBX frames skipped, binary garbage, over-long lines and non-ASCII bytes refused by cause) and
grouped by receiver epoch: one GnssSentences message per epoch (a GGA and its GST together), as
the simulator publishes them, so the gnss node (perception.gnss_node) reads either the same way.
The fields are not parsed here beyond the time of day: a bad checksum or a nonsensical field is
the gnss node's to refuse. The other way, the RTK corrections the NTRIP client publishes
(`gnss/rtcm`, whole RTCM 3 frames) are written to the same port (serial or TCP), as a receiver
takes them; gpsd gives its clients no way to write to its device (give gpsd the caster instead).

Each message is stamped with the epoch's time of day mapped to stack time (the drivers' stamp
rule, nmea_stream.stamp). An epoch older than `max_fix_age_s` when it is read (a stream held up,
then a burst of old epochs) is dropped and counted as stale, never stamped as new: a localization
fed an old position as now is a safety defect. Ages are judged against the stack clock; a receiver
clock that disagrees with it for good (a computer without time sync: the smallest age of the last
`clock_window_s` beyond `max_fix_age_s`) is reported, and its fixes are still judged by the stack
clock: behind it, every one is dropped (a stream late for good looks the same). A receiver absent, gone (a read
error, the connection closed) or silent for `silent_after_s` is closed and reopened every
`reopen_s`, each cause logged once.
"""

from __future__ import annotations

import os
import select
import time
from typing import Protocol

import serial

from ares.core.config import GnssDevice, Params, param
from ares.core.driver import DeviceAges, DriverNode
from ares.core.messages import GnssSentences
from ares.core.node import Input, Output
from ares.core.wire.gpsd import GPSD_PORT, GpsdClient, TcpStream
from ares.core.wire.nmea_stream import DAY_S, MAX_LINE, Epoch, EpochGroups, NmeaStream

DEVICE = "gnss"
RTCM_BACKLOG = 16384  # corrections held for a port with no room: some seconds of a base station's


class GnssDriverParams(Params):
    rate_hz: float = param(50.0, "loop rate: each loop reads what the receiver has sent", unit="Hz", gt=0)
    reopen_s: float = param(0.5, "an absent, gone or silent receiver is reopened this often (wall)", unit="s", gt=0)
    epoch_hold_s: float = param(
        0.05,
        "an epoch's sentences are published this long (wall) after its last one, unless the next "
        "epoch's first sentence, or a drained port with its GGA and GST, says so sooner",
        unit="s",
        ge=0,
    )
    max_line: int = param(MAX_LINE, "longer lines are refused (NMEA's limit is 82 characters)", unit="B", gt=10)
    max_fix_age_s: float = param(
        0.5, "an epoch older than this when it is read is dropped and counted (never stamped as new)", unit="s", gt=0
    )
    clock_window_s: float = param(
        10.0,
        "the receiver's clock is judged off from the stack clock's by the freshest epoch of this long",
        unit="s",
        gt=0,
    )


class _Port(Protocol):
    def read(self) -> bytes: ...
    def close(self) -> None: ...


class _SerialPort:
    """A serial port or pseudo-terminal, read without waiting."""

    def __init__(self, device: str, baud: int):
        self.port = serial.Serial(device, baud, timeout=0)
        self.port.reset_input_buffer()  # what waited in the port before we opened it is stale
        self.device = device
        self.path = os.path.realpath(device)

    def read(self) -> bytes:
        chunks: list[bytes] = []
        while True:
            data = self.port.read(65536)  # timeout=0: what is there, at once
            if not data:
                break
            chunks.append(data)
        if not chunks and os.path.realpath(self.device) != self.path:
            raise serial.SerialException(f"{self.device} now leads to another device")
        return b"".join(chunks)

    def write(self, data: bytes) -> int:
        """What fits in the port's buffer now, without waiting; how much that was. (pyserial's own
        write spins until everything is written, whatever its write_timeout: a stalled receiver or
        flow control would hold the driver's step.)"""
        fd = self.port.fileno()
        _, writable, _ = select.select([], [fd], [], 0)
        if not writable:
            return 0
        try:
            return os.write(fd, data)
        except (BlockingIOError, InterruptedError):
            return 0

    def close(self) -> None:
        self.port.close()


class GnssDriver(DriverNode):
    """The GNSS receiver's NMEA (serial, TCP or gpsd) -> sensors/gnss, one message per epoch."""

    name = "gnss_driver"
    Params = GnssDriverParams
    wire_inputs = ("wire/gnss",)
    sentences = Output("sensors/gnss", doc="the NMEA sentences of each receiver epoch, stamped with its time")
    rtcm_in = Input(
        "gnss/rtcm", queue=64, doc="RTK corrections (RTCM 3, from the NTRIP client): written to the receiver's port"
    )

    def setup(self) -> None:
        gnss = self.core.vehicle_io.gnss
        if gnss is None:
            raise RuntimeError("gnss_driver: vehicle_io.gnss is not set: there is no receiver to read")
        self.device: GnssDevice = gnss
        self.wire_counts = self.wire(DEVICE)
        self.stream = self._framer()
        self.epochs = EpochGroups(self.params.epoch_hold_s)
        self.ages = DeviceAges(DAY_S, self.params.max_fix_age_s, self.params.clock_window_s)
        self.port: _Port | None = None
        self._gpsd: GpsdClient | None = None
        self._next_open = 0.0  # monotonic
        self._last_byte = 0.0  # monotonic
        self._ubx_seen = 0
        self._rtcm_backlog = bytearray()  # corrections the port had no room for yet
        self.wire_counts.detail = self._where()

    def _framer(self) -> NmeaStream:
        return NmeaStream(max_line=self.params.max_line, on_refuse=self.wire_counts.refuse)

    def _where(self) -> str:
        d = self.device
        if d.source == "serial":
            return f"serial {d.device} at {d.baud} bit/s"
        port = d.port or GPSD_PORT
        return f"{d.source} {d.host}:{port}" + (f" ({d.device})" if d.source == "gpsd" and d.device else "")

    def teardown(self) -> None:
        self._close()

    # ---- the device ------------------------------------------------------------------------------
    def _open(self) -> None:
        d = self.device
        self._next_open = time.monotonic() + self.params.reopen_s
        try:
            if d.source == "serial":
                assert d.device is not None  # GnssDevice requires it for a serial source
                self.port = _SerialPort(d.device, d.baud)
            elif d.source == "tcp":
                assert d.port is not None  # GnssDevice requires it for a TCP source
                self.port = TcpStream(d.host, d.port)
            else:
                self._gpsd = GpsdClient(d.host, d.port or GPSD_PORT, d.device, on_refuse=self.wire_counts.refuse)
                self.port = self._gpsd
        except (OSError, serial.SerialException) as exc:
            absent = isinstance(exc, FileNotFoundError) or "No such file" in str(exc)
            self.wire_counts.problem("absent" if absent else "cannot open", f"{self._where()}: {exc}")
            return
        self.stream = self._framer()
        self.ages = DeviceAges(DAY_S, self.params.max_fix_age_s, self.params.clock_window_s)  # a new device's clock
        self._rtcm_backlog.clear()  # what waited for the last device is no good to this one
        self._ubx_seen = 0
        self._last_byte = time.monotonic()
        self.log.info("reading the GNSS receiver: %s", self._where())

    def _close(self, cause: str | None = None, detail: str = "") -> None:
        if cause is not None:
            self.wire_counts.problem(cause, f"{self._where()}: {detail}" if detail else self._where())
        if self.port is not None:
            try:
                self.port.close()
            except (OSError, serial.SerialException):
                pass
        self.port = None
        self._gpsd = None
        self.wire_counts.connected = False
        self._next_open = time.monotonic() + self.params.reopen_s

    # ---- the loop ----------------------------------------------------------------------------------
    def step(self, now: float) -> None:
        if self.port is None and time.monotonic() >= self._next_open:
            self._open()
        if self.port is not None:
            self._read(now)
        epoch = self.epochs.due(time.time(), drained=True)
        if epoch is not None:
            self._publish([epoch], now)
        self._forward_corrections()
        self.report(now)

    def _forward_corrections(self) -> None:
        """The NTRIP client's RTCM frames to the receiver, through the port the NMEA comes from."""
        chunks = [msg for _, msg in self.rtcm_in.drain()]
        if not chunks:
            return
        counts = self.wire("gnss/rtcm")
        frames = sum(msg.frames for msg in chunks)
        counts.got(frames)
        if self.port is None:
            counts.skip("receiver closed", frames)
            return
        if self._gpsd is not None:  # gpsd has no way for a client to write to its device
            counts.skip("gpsd: give gpsd the caster itself (gpsd ntrip://...)", frames)
            return
        if len(self._rtcm_backlog) > RTCM_BACKLOG:  # the receiver takes nothing: old corrections are no use
            counts.skip("receiver's port full", 1)
            self._rtcm_backlog.clear()
        self._rtcm_backlog += b"".join(msg.data.tobytes() for msg in chunks)
        try:
            if isinstance(self.port, TcpStream):
                sent = self.port.send_some(bytes(self._rtcm_backlog))
            else:
                assert isinstance(self.port, _SerialPort)  # serial is the only other port
                sent = self.port.write(bytes(self._rtcm_backlog))
        except (OSError, serial.SerialException) as exc:
            counts.skip("write failed", frames)
            counts.problem("write failed", f"{self._where()}: {exc}")
            self._rtcm_backlog.clear()
            return
        del self._rtcm_backlog[:sent]  # the rest goes at the next step, never waited for
        counts.put(n=frames)  # handed to the port (the bytes it had no room for yet are `waiting`)
        counts.connected = sent > 0 or not self._rtcm_backlog
        counts.detail = f"RTCM to {self._where()}: {counts.published} frames, {len(self._rtcm_backlog)} bytes waiting"

    def _read(self, now: float) -> None:
        assert self.port is not None
        try:
            data = self.port.read()
        except (OSError, serial.SerialException) as exc:
            self._close("gone", str(exc))
            return
        read_wall = time.time()
        if not data:
            if time.monotonic() - self._last_byte > self.device.silent_after_s:
                self._close("silent", f"no byte for {self.device.silent_after_s:g} s")
            return
        self._last_byte = time.monotonic()
        self.wire_counts.connected = True
        if self._gpsd is not None:
            self.wire_counts.detail = self._gpsd.detail
        lines = self.stream.feed(data, read_wall)
        self.wire_counts.got(len(lines))
        if self.stream.ubx_frames > self._ubx_seen:
            self.wire_counts.skip("ubx", self.stream.ubx_frames - self._ubx_seen)
            self._ubx_seen = self.stream.ubx_frames
        done = [epoch for line, wall in lines if (epoch := self.epochs.add(line, wall)) is not None]
        self._publish(done, now)

    def _publish(self, epochs: list[Epoch], now: float) -> None:
        """The epochs completed by one read, in order, each judged by its own age on the stack
        clock; the read's freshest also tells whether the receiver's clock is off (reported)."""
        if not epochs:
            return
        utc_epoch = self.clock.utc_epoch
        self.ages.observe(now, [self.ages.raw_age(now, utc_epoch, e.tod) for e in epochs if e.tod is not None])
        offset = self.ages.clock_offset_s
        if offset is not None:
            consequence = "every fix looks stale and is dropped" if offset > 0 else "fixes are stamped as read"
            self.wire_counts.problem(
                "receiver clock",
                f"its time is {-offset:+.2f} s from the stack clock's: {consequence}; set the computer's clock "
                "(NTP, or chrony or gpsd from this receiver)",
            )
        for epoch in epochs:
            age = self.ages.age(now, utc_epoch, epoch.tod)
            if age is not None and age > self.params.max_fix_age_s:
                self.wire_counts.skip("stale")
                self.wire_counts.problem("stale", f"an epoch {age:.2f} s old when read: dropped, not stamped as new")
                continue
            t = now - max(age, 0.0) if age is not None else now  # no time of day: as read
            self.sentences.put(GnssSentences(t=t, sentences=epoch.lines))
            self.wire_counts.put(epoch.read_wall)
