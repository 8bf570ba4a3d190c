"""GNSS receiver node (ARES §3.1): raw NMEA in, validated fixes in UTM and the local frame out.

Events: "nmea_rejected", at most once per reason per gnss.event_period_s, with the counts.

Each line is parsed strictly (perception.nmea_parser); a GGA is paired with the GST of the same time
from the same message (either order) or, failing that, the latest GST of an earlier message
with that time; then projected (perception.gnss). A rejected line is counted by reason and
logged (the first of each reason, then every 100th): a bad line costs that line only, and the
node keeps running.
"""

from __future__ import annotations

from ares.core.geodesy import LocalFrame
from ares.core.messages import EventLevel
from ares.core.node import Input, Node, Output
from perception.gnss import GnssParams, GnssProjector, pair_epochs
from perception.nmea_parser import Gga, Gst, NmeaError, NmeaReader

LOG_EVERY = 100  # after the first of a reason, log every this many


class GnssNode(Node):
    """Receiver NMEA in, validated fixes in UTM and the local frame out (ARES §3.1)."""

    name = "gnss"
    Params = GnssParams
    sentences = Input("sensors/gnss", queue="queue", doc="the raw NMEA lines of each read from the receiver")
    fixes = Output("gnss/fix", doc="one per accepted GGA, stamped with its sensor message's t")

    def setup(self) -> None:
        self.projector = GnssProjector(LocalFrame(self.core.origin_utm), self.params)
        self.reader = NmeaReader()
        self.event_period_s = self.params.event_period_s
        self.published = 0
        self._last_gst: Gst | None = None
        self._last_event: dict[str, float] = {}  # reason -> stack time of its last event

    def step(self, now: float) -> None:
        for _topic, msg in self.sentences.drain():
            parsed = []
            for line in msg.sentences:
                sentence = self.reader.parse(line)
                if sentence is None:
                    self._rejected(line, self.reader.last_error, now)
                else:
                    parsed.append(sentence)
            for gga, gst in pair_epochs(parsed, self._last_gst):
                self._publish(gga, gst, msg.t, now)
            gsts = [s for s in parsed if isinstance(s, Gst)]
            if gsts:
                self._last_gst = gsts[-1]

    def _publish(self, gga: Gga, gst: Gst | None, t: float, now: float) -> None:
        try:
            fix = self.projector.fix(gga, gst, t=t)
        except NmeaError as exc:  # a well-formed fix the site cannot use (far from the origin)
            self.reader.reject(exc)
            self._rejected(f"{gga.talker}GGA {gga.time} {gga.lat:.6f},{gga.lon:.6f}", exc, now)
            return
        self.fixes.put(fix)
        self.published += 1

    def _rejected(self, line, error: NmeaError | None, now: float) -> None:
        if error is None:
            return
        reason = error.reason
        n = self.reader.rejected[reason]
        last = self._last_event.get(reason)
        if last is None or now - last >= self.event_period_s:
            self._last_event[reason] = now
            level = EventLevel.INFO if reason == "no fix" else EventLevel.WARNING
            # (the event is logged too: that covers the first line of each reason)
            self.event(
                "nmea_rejected",
                f"NMEA line rejected ({reason}, {n} so far): {error}: {line!r:.120}",
                level,
                reason=reason,
                count=n,
                rejected_total=self.reader.total_rejected,
                accepted_total=self.reader.total_accepted,
                fixes_published=self.published,
                example=repr(line)[:120],
            )
        elif n % LOG_EVERY == 0:
            self.log.warning("rejected NMEA line (%s, %d so far): %s: %.120r", reason, n, error, line)
