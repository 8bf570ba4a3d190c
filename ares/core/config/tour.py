"""Tours (tours/*.yaml): a closed polygon with rounded corners and what lies along it (widths,
verges, POIs and their actions, RTK-loss zones, intersections, elevation)."""

from __future__ import annotations

from typing import Literal, Self, get_args

from pydantic import model_validator

from ares.core.config.base import Params, load_yaml, named_file, param, validated


class TourCorner(Params):
    xy: tuple[float, float]
    radius_m: float = param(doc="radius of the arc that rounds the corner", unit="m", gt=0)


class TourElevation(Params):
    s: float = param(doc="distance along the tour", unit="m", ge=0)
    z: float = param(doc="height", unit="m")


class TourStretch(Params):
    s_start: float = param(unit="m", ge=0)
    s_end: float = param(unit="m", ge=0)
    width_m: float = param(unit="m", gt=0)


# A POI's actions, in the order the mission runs them (the paper's action state machine, Fig. 7):
# stop, hold, open, ramp out, ramp in, close, media, set off. NEXT_POI comes last: it ends the POI.
PoiAction = Literal[
    "STOP",
    "FULL_STOP",
    "OPENING_DOORS",
    "TAKEOFF_RAMP",
    "PICKUP_RAMP",
    "CLOSING_DOORS",
    "START_MEDIA",
    "NEXT_POI",
]
POI_ACTIONS: tuple[str, ...] = get_args(PoiAction)


class TourPoi(Params):
    name: str
    s: float = param(unit="m", ge=0)
    actions: list[PoiAction] = param(factory=list)


class TourZone(Params):
    kind: Literal["rtk_loss", "no_4g", "intersection", "road_opening", "narrow"] = param(
        doc="rtk_loss: the sky blocked, no RTK whatever the corrections; no_4g: no corrections arrive "
        "(the fix degrades as they age); intersection, road_opening: no road to follow; narrow"
    )
    s_start: float = param(unit="m", ge=0)
    s_end: float = param(unit="m", ge=0)
    full_stop: bool = param(
        False,
        "intersection: a stop line at s_start (a stop sign): the mission stands there mission_manager.full_stop_s "
        "before it crosses (ARES §3.3's FULL_STOP, handed to the movement gate)",
    )

    @model_validator(mode="after")
    def _full_stop_at_an_intersection(self) -> Self:
        if self.full_stop and self.kind != "intersection":
            raise ValueError(f"full_stop marks an intersection's stop line, not a {self.kind} zone")
        return self


VergeKind = Literal["grass", "rock_wall", "ravine", "kerb", "open"]
VERGE_KINDS: tuple[str, ...] = ("grass", "rock_wall", "ravine", "kerb", "open")


class TourVerge(Params):
    """What lies beside the road over a stretch, on each side (the simulator's 3-D world)."""

    s_start: float = param(unit="m", ge=0)
    s_end: float = param(unit="m", ge=0)
    left: VergeKind = param(
        doc="grass shoulder (no step, a gentle change of slope), rock_wall, ravine (a drop, "
        "no barrier), kerb, or open (no boundary)"
    )
    right: VergeKind = param(doc="as left")


class TourDescription(Params):
    """A closed tour: a polygon whose corners are rounded with arcs, profiles along it."""

    name: str
    default_width_m: float = param(6.0, unit="m", gt=0)
    speed_limit_mps: float | None = param(
        None,
        "the road's speed limit: the speed profile's top speed on straights (null: the vehicle's maximum)",
        unit="m/s",
        gt=0,
    )
    default_verge: VergeKind = param("kerb", "the verge where `verges` says nothing")
    verges: list[TourVerge] = param(
        factory=list, doc="verges stretch by stretch; intersections and road openings are open whatever they say"
    )
    corners: list[TourCorner] = param(min_length=3)
    elevation: list[TourElevation] = param(min_length=1)
    narrow: list[TourStretch] = param(factory=list)
    pois: list[TourPoi] = param(factory=list)
    zones: list[TourZone] = param(factory=list)


def load_tour(name: str) -> TourDescription:
    path = named_file("tours", name)
    return validated(TourDescription, load_yaml(path), str(path))
