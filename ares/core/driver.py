"""What every device driver shares: its counts, its status on the bus, and one log line per cause.

A driver (the `drivers` package) reads a device's wire format and publishes the topics the
simulator publishes in simulation. Bad input on a wire (a corrupt packet, a wrong checksum, a frame
with an unknown id, a truncated rotation) is counted by cause and logged the first time each cause
occurs, then every `LOG_EVERY`-th time: a noisy device neither floods the log nor stops the driver.
Once a second (stack time) each device's counts go out on `drivers/status`, with the latency from
the wire to the bus (wall seconds: from the kernel's receive time, or the read's, to the put).
"""

from __future__ import annotations

import logging
import time
from collections import Counter, deque
from typing import ClassVar, cast

import numpy as np

from ares.core.bus import Publisher
from ares.core.messages import DriverStatus
from ares.core.node import Node, Output
from ares.core.schema import Msg

LOG_EVERY = 1000
MAX_STAMP_AGE_S = 2.0  # a device time further back than this: the device's clock is off, stamp on receipt
LATENCY_WINDOW = 4096  # the latest latencies the percentiles are taken over


def device_stamp(now: float, utc_epoch: float, device_time: float | None, period_s: float) -> float:
    """The drivers' stamp rule: the stack time of data whose device time is `device_time` (the NMEA
    time of day, mod 86400 s; a Velodyne packet's µs past the hour, mod 3600 s): the latest stack
    time not after `now` with that calendar time (the clock's utc_epoch is the calendar time of
    stack time 0). `now` when the data carries no time or the result is over MAX_STAMP_AGE_S old."""
    if device_time is None:
        return now
    age = ((utc_epoch + now) % period_s - device_time) % period_s
    return now if age > MAX_STAMP_AGE_S else now - age


class DeviceAges:
    """How old a device's data is when read, from the time it carries (`period_s`: a day for an
    NMEA time of day): its calendar time against the stack clock's. A device clock that disagrees
    for good (the smallest age over the last `window_s` beyond `tolerance_s` either way: a computer
    without time sync) is reported as an offset, but ages stay the stack clock's: a stream that is
    late for good looks exactly like a clock that is off, and an old position taken as new is the
    worse mistake. Data from the future (a device clock ahead) is not old: it counts as read now."""

    def __init__(self, period_s: float, tolerance_s: float, window_s: float):
        self.period_s = period_s
        self.tolerance_s = tolerance_s
        self.window_s = window_s
        self._seen: deque[tuple[float, float]] = deque()  # (stack time, raw age)

    def raw_age(self, now: float, utc_epoch: float, device_time: float) -> float:
        """now's calendar time less the device's, within ± half a period (negative: from the future)."""
        half = self.period_s / 2
        return ((utc_epoch + now) % self.period_s - device_time + half) % self.period_s - half

    def observe(self, now: float, raw_ages: list[float]) -> None:
        for raw in raw_ages:
            self._seen.append((now, raw))
        while self._seen and self._seen[0][0] < now - self.window_s:
            self._seen.popleft()

    @property
    def clock_offset_s(self) -> float | None:
        """The device clock's offset from the stack clock's, when it is beyond the tolerance."""
        if not self._seen:
            return None
        freshest = min(raw for _, raw in self._seen)
        return freshest if abs(freshest) > self.tolerance_s else None

    def age(self, now: float, utc_epoch: float, device_time: float | None) -> float | None:
        if device_time is None:
            return None
        return self.raw_age(now, utc_epoch, device_time)


class WireCounters:
    """One device's counts: received, published, lost, malformed and skipped by cause, latencies."""

    def __init__(self, device: str, log: logging.Logger):
        self.device = device
        self.log = log
        self.received = 0
        self.published = 0
        self.lost = 0
        self.malformed: Counter[str] = Counter()
        self.skipped: Counter[str] = Counter()
        self.latencies_s: deque[float] = deque(maxlen=LATENCY_WINDOW)
        self.connected = False
        self.detail = ""
        self._problems: Counter[str] = Counter()

    def got(self, n: int = 1) -> None:
        self.received += n

    def put(self, read_wall: float | None = None, n: int = 1) -> None:
        """`n` messages published; `read_wall` the wall time (time.time()) their bytes arrived."""
        self.published += n
        if read_wall is not None:
            latency = max(time.time() - read_wall, 0.0)
            self.latencies_s.append(latency)

    def missing(self, n: int, why: str) -> None:
        if n <= 0:
            return
        self.lost += n
        self.problem(f"lost: {why}", f"{n} missing")

    def refuse(self, cause: str, detail: str = "") -> None:
        """A malformed packet, frame or line: counted under `cause`, logged once per cause."""
        self.malformed[cause] += 1
        n = self.malformed[cause]
        if n == 1 or n % LOG_EVERY == 0:
            self.log.warning("%s: refused (%s, %d so far)%s", self.device, cause, n, f": {detail}" if detail else "")

    def skip(self, cause: str, n: int = 1) -> None:
        self.skipped[cause] += n

    def problem(self, cause: str, detail: str = "") -> None:
        """A device-level problem (gone, silent, reopened): logged once per cause, then every LOG_EVERY-th."""
        self._problems[cause] += 1
        n = self._problems[cause]
        if n == 1 or n % LOG_EVERY == 0:
            self.log.warning("%s: %s (%d so far)%s", self.device, cause, n, f": {detail}" if detail else "")

    def percentile_ms(self, q: float) -> float | None:
        """Over the latest LATENCY_WINDOW latencies: bounded memory (before, every sample of a run
        was kept as well, about 220 MB a day for a CAN bus at 80 frames a second, and never read)."""
        if not self.latencies_s:
            return None
        return round(float(np.percentile(np.fromiter(self.latencies_s, dtype=float), q)) * 1e3, 3)

    def status(self, t: float, driver: str) -> DriverStatus:
        return DriverStatus(
            t=t,
            driver=driver,
            device=self.device,
            connected=self.connected,
            received=self.received,
            published=self.published,
            lost=self.lost,
            malformed=dict(self.malformed),
            skipped=dict(self.skipped),
            latency_p50_ms=self.percentile_ms(50),
            latency_p99_ms=self.percentile_ms(99),
            detail=self.detail,
        )


class DriverNode(Node):
    """Base of the device drivers: `self.wires` holds each device's counters, published on
    drivers/status every `status_period_s` of stack time."""

    status_period_s: ClassVar[float] = 1.0
    driver_status = Output("drivers/status", rate=1.0, doc="each device's counts: in, out, lost, malformed, latency")

    def __init__(self, *args, **kwargs) -> None:  # type: ignore[no-untyped-def]
        super().__init__(*args, **kwargs)
        self.wires: dict[str, WireCounters] = {}
        self._status_due = -float("inf")

    def wire(self, device: str) -> WireCounters:
        if device not in self.wires:
            self.wires[device] = WireCounters(device, self.log)
        return self.wires[device]

    def report(self, now: float, force: bool = False) -> None:
        """Each device's status, once per status period (call at the end of step)."""
        if not force and now < self._status_due:
            return
        self._status_due = now + self.status_period_s
        out = cast(Publisher[Msg], self.driver_status)
        for counters in self.wires.values():
            out.put(counters.status(now, self.name))
