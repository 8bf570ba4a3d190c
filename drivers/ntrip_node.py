"""The NTRIP client: RTK corrections from a caster (vehicle_io.ntrip) to the receiver, and their state.

Both papers get their centimetre fixes from differential corrections: the ARES vehicle asks an
NTRIP caster for them over 4G (ARES §3.1, §3.8.1); without them the receiver never reaches an RTK
fix, the odometry score stays low and the shuttle drives on road reactive control everywhere.

Each step polls the connection without blocking (ares.core.wire.ntrip: rev 1 or 2, basic
authentication, the source table when the mount point is unknown, the receiver's GGA sent upstream
every `gga_interval_s` for VRS casters, reconnection with a doubling back-off). The whole,
CRC-checked RTCM 3 frames go out on `gnss/rtcm`, which the GNSS driver writes to the receiver's
own port (serial or TCP). Once a second `gnss/corrections` says where the corrections stand: the
link's state, the age of the newest frame, the frames by message number, the outages, the station.
The link's counts go on `drivers/status` as device "ntrip".
"""

from __future__ import annotations

import time

import numpy as np

from ares.core.config import NtripCaster, Params, param
from ares.core.driver import DriverNode
from ares.core.messages import CorrectionsStatus, RtcmData
from ares.core.node import Input, Output
from ares.core.wire.ntrip import CONNECTING, REQUESTED, STREAMING, NtripClient, NtripSettings

DEVICE = "ntrip"


class NtripClientParams(Params):
    rate_hz: float = param(20.0, "loop rate: each loop reads what the caster sent", unit="Hz", gt=0)


class NtripClientNode(DriverNode):
    """RTCM 3 from an NTRIP caster -> gnss/rtcm (for the receiver) and gnss/corrections (their state)."""

    name = "ntrip_client"
    Params = NtripClientParams
    params: NtripClientParams

    sentences = Input("sensors/gnss", doc="the receiver's NMEA: its latest GGA goes upstream to a VRS caster")
    rtcm = Output("gnss/rtcm", doc="whole, checked RTCM 3 frames, for the receiver's port")
    corrections = Output("gnss/corrections", rate=1.0, doc="the corrections' link, age, frames and outages")

    def setup(self) -> None:
        caster = self.core.vehicle_io.ntrip
        if caster is None:
            raise RuntimeError("ntrip_client: vehicle_io.ntrip is not set: there is no caster to ask")
        self.caster: NtripCaster = caster
        self.counters = self.wire(DEVICE)
        self._gga: str | None = None
        # the section's fields are the client's settings, one for one
        self.client = NtripClient(NtripSettings(**caster.model_dump()), gga=lambda: self._gga)
        self.source = f"ntrip {self.client.where}"
        self._last_frame_t: float | None = None  # stack time of the newest frame
        self._station: int | None = None
        self._corrections_due = -float("inf")

    def teardown(self) -> None:
        self.client.close()

    def step(self, now: float) -> None:
        latest = self.sentences.latest
        if latest is not None:
            gga = next((s for s in reversed(latest.sentences) if s[3:6] == "GGA"), None)
            self._gga = gga or self._gga
        frames = self.client.poll(time.monotonic())
        read_wall = time.time()
        self.counters.got(len(frames))
        for cause, text in self.client.events:
            self.counters.problem(cause, text)
        self.client.events.clear()
        for cause, n in self.client.malformed.items():
            if n > self.counters.malformed.get(cause, 0):
                self.counters.refuse(cause, f"{n - self.counters.malformed.get(cause, 0)} more")
                self.counters.malformed[cause] = n
        if frames:
            data = np.frombuffer(b"".join(f.raw for f in frames), dtype=np.uint8)
            self.rtcm.put(RtcmData(t=now, frames=len(frames), data=data))
            self.counters.put(read_wall, n=len(frames))
            self._last_frame_t = now
            self._station = next((f.station_id for f in reversed(frames) if f.station_id is not None), self._station)
        self.counters.connected = self.client.state == STREAMING
        self.counters.detail = self._detail()
        if now >= self._corrections_due:
            self._corrections_due = now + 1.0
            self.corrections.put(self.status(now))
        self.report(now)

    def status(self, now: float) -> CorrectionsStatus:
        client = self.client
        link = {STREAMING: "streaming", CONNECTING: "connecting", REQUESTED: "connecting"}.get(client.state)
        if link is None:
            cause = client.last_error.split(":")[0]
            link = cause if cause in ("unauthorized", "no mount point") else "down"
            link = "no mount point" if cause == "no such mount point" else link
        return CorrectionsStatus(
            t=now,
            source=self.source,
            link=link,  # type: ignore[arg-type]  # one of the Literal's values by construction
            age_s=round(now - self._last_frame_t, 3) if self._last_frame_t is not None else None,
            frames=client.frames,
            by_type={str(k): v for k, v in sorted(client.by_type.items())},
            outages=client.outages,
            station_id=self._station,
            detail=client.last_error if client.state != STREAMING else f"streaming since connect {client.connects}",
        )

    def _detail(self) -> str:
        c = self.client
        types = ", ".join(f"{k} {v}" for k, v in sorted(c.by_type.items()))
        state = c.state if c.state != "idle" else f"down ({c.last_error}; again in {c.retry_in_s:.1f} s)"
        return (
            f"{self.source}: {state}; {c.frames} frames ({types or 'none'}), {c.outages} outages, {c.gga_sent} GGA sent"
        )
