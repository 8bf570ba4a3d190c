"""Road Reactive Control as a process: road detection in, a candidate out (ARES §3.6.2).

The RRC trusts nothing but the LiDARs: the road's centre line and the vehicle's offset and
heading from perception/road, and the distance travelled (for its terms per metre) from the
drive-by-wire bridge's measured speed, never from the fused pose; each frame's road is
remembered and moved by that speed and the steering, so that the offset and heading at the
wheels are read from frames seen a few metres back (control/rrc.py). Without a fresh, confident
detection, or with one that disagrees with the road seen, it steers along the road last seen for
a few metres (moved by the measured speed and steering), a candidate marked `stop_only` with
v = 0; after that there is no candidate.
"""

from __future__ import annotations

from ares.core.config import param
from ares.core.messages import ControlCandidate, EventLevel, RoadDetection
from ares.core.node import Input, Node, Output
from control.rrc import RoadReactiveControl, RoadView, RrcParams

DOUBT_REPORT_S = 10.0  # road_doubted events come at most this often (each says how many spells since)


class RrcNodeParams(RrcParams):
    rate_hz: float = param(20.0, "loop and candidate rate", unit="Hz", gt=0)
    road_timeout_s: float = param(
        0.35, "an older road detection is not followed (LiDARs sweep at 10 Hz)", unit="s", gt=0
    )
    speed_timeout_s: float = param(0.5, "an older speed measurement counts as standstill", unit="s", gt=0)
    status_timeout_s: float = param(0.5, "an older control manager status: the RRC is not driving", unit="s", gt=0)


def road_view(road: RoadDetection | None) -> RoadView | None:
    if (
        road is None
        or not road.found
        or road.centre is None
        or road.lateral_offset_m is None
        or road.heading_rad is None
    ):
        return None
    return RoadView(
        road.lateral_offset_m, road.heading_rad, list(road.centre.coefficients), road.confidence, stamp=road.t
    )


class RrcNode(Node):
    """Road Reactive Control (ARES eqs. 14-15): a candidate that keeps to the middle of the road seen."""

    name = "rrc"
    Params = RrcNodeParams
    road = Input("perception/road", max_age="road_timeout_s", doc="centre line, offset and heading, confidence")
    car = Input("dbw/car_state", max_age="speed_timeout_s", doc="the measured speed: distance travelled")
    control = Input(
        "control/status", max_age="status_timeout_s", doc="whether the RRC drives: its integral runs only then"
    )
    # no declared rate: silent wherever the road is not seen (not news for the supervisor)
    candidate = Output(
        "control/candidate/rrc",
        doc="(v, kappa) at rate_hz while the road is seen (or remembered, stop_only); silent without it",
    )

    def setup(self) -> None:
        self.rrc = RoadReactiveControl(RrcParams(**{k: getattr(self.params, k) for k in RrcParams.model_fields}))
        self._last: float | None = None
        self._doubting = False
        self._reported: float | None = None  # the last road_doubted event
        self._spells = 0  # spells of doubt since it

    def step(self, now: float) -> None:
        car = self.car.fresh(now)
        dt = 0.0 if self._last is None else max(now - self._last, 0.0)
        self._last = now
        travelled = car.speed_mps * dt if car is not None else None  # unknown: frames cannot be moved
        driven_kappa = 0.0 if car is None else self.vehicle.curvature_of(car.steering_wheel_deg)
        road = self.road.fresh(now)
        since_frame = car.speed_mps * max(now - road.t, 0.0) if car is not None and road is not None else 0.0
        status = self.control.fresh(now)
        driving = status is not None and status.controller == "rrc"
        cmd = self.rrc.step(road_view(road), travelled, driven_kappa, since_frame, driving)
        self._say_doubts(road, now)
        if cmd is None:
            return
        if cmd.remembered:
            memory = self.rrc.memory
            self.candidate.put(
                ControlCandidate(
                    t=now,
                    controller="rrc",
                    v=0.0,
                    kappa=cmd.kappa,
                    cross_track_m=cmd.error_m,
                    stop_only=True,
                    note=("road detection disagrees with the road seen" if self.rrc.doubted else "road lost")
                    + f": steering along the road seen {memory.travelled_m:.1f} m back",
                )
            )
            return
        self.candidate.put(
            ControlCandidate(
                t=now,
                controller="rrc",
                v=cmd.v,
                kappa=cmd.kappa,
                cross_track_m=cmd.error_m,
                heading_error_rad=cmd.heading_rad,
                note=f"road confidence {road.confidence:.2f}",
            )
        )

    def _say_doubts(self, road: RoadDetection | None, now: float) -> None:
        """An event when road detection starts to disagree with the road seen (a spell; at most one
        every DOUBT_REPORT_S, counting the spells since), and one when frames that agree with one
        another replace it."""
        doubting = bool(self.rrc.doubted)
        if doubting and not self._doubting:
            self._spells += 1
            if self._reported is None or now - self._reported >= DOUBT_REPORT_S:
                more = f" ({self._spells - 1} more spells since the last report)" if self._spells > 1 else ""
                self.event(
                    "road_doubted",
                    f"road detection (confidence {road.confidence:.2f}) disagrees with the "
                    f"road seen: not followed{more}",
                    EventLevel.WARNING,
                    confidence=round(road.confidence, 3),
                    spells=self._spells,
                )
                self._reported, self._spells = now, 0
        if self.rrc.replaced:
            self.event(
                "road_replaced",
                f"{self.rrc.p.doubt_frames} frames in a row agreed with one another, not "
                "with the road seen: they replace it",
                EventLevel.WARNING,
                confidence=round(road.confidence, 3),
            )
        self._doubting = doubting
