"""A scenario's obstacles, where they are at any moment.

A static obstacle stands at one place beside the route (arc length, lateral offset); a moving one
follows its path at its speed once started, by the clock or when the vehicle reaches a point of
the route, and stays at the path's end. One with `appear_ahead_m` is absent until its start time,
then appears that far ahead of the vehicle (its path counted from there) and leaves again after
`gone_after_s` (a soak's pedestrian or parked object in the path, ares.tools.soak). `along_tour`
places obstacles of several kinds in turn along the tour, alternately left and right of the path
the shuttle drives, skipping intersections, road openings and narrow stretches.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ares.core.geometry import convex_gap, rectangle_corners
from ares.core.messages import ObstacleBox
from ares.core.route import OPEN_ZONES, Route
from simulator.scenario import OBSTACLE_SIZES, Scenario, ScenarioAlongTour, ScenarioObstacle, ScenarioPlace
from simulator.world import CROSSFALL, Mesh, box_mesh


@dataclass
class PlacedObstacle:
    spec: ScenarioObstacle
    xy: np.ndarray  # (k, 2) the path in the local frame
    yaw_along: np.ndarray  # heading of each leg (a standing obstacle faces along the road)
    base_z: np.ndarray  # ground height at each path point
    started_at: float | None = None
    gone_at: float | None = None  # it leaves the world then (an obstacle that appeared, for a while)

    @property
    def moving(self) -> bool:
        return len(self.xy) > 1 and self.spec.speed_mps > 0

    def where(self, t: float) -> tuple[float, float, float, float]:
        """(x, y, z of the base, yaw) at stack time t: along its path at its speed, standing each
        place's wait_s."""
        if not self.moving or self.started_at is None:
            return float(self.xy[0, 0]), float(self.xy[0, 1]), float(self.base_z[0]), float(self.yaw_along[0])
        tau = max(t - self.started_at, 0.0)
        legs = np.hypot(*np.diff(self.xy, axis=0).T)
        leave = 0.0
        for i, place in enumerate(self.spec.path):
            arrive = leave if i == 0 else leave + legs[i - 1] / self.spec.speed_mps
            if i > 0 and tau < arrive:  # on the leg from place i-1 to place i
                f = (tau - leave) / (arrive - leave) if arrive > leave else 1.0
                x, y = self.xy[i - 1] + f * (self.xy[i] - self.xy[i - 1])
                z = self.base_z[i - 1] + f * (self.base_z[i] - self.base_z[i - 1])
                return float(x), float(y), float(z), float(self.yaw_along[i])
            leave = arrive + place.wait_s
            if tau < leave or i == len(self.spec.path) - 1:  # standing at place i
                return (
                    float(self.xy[i, 0]),
                    float(self.xy[i, 1]),
                    float(self.base_z[i]),
                    float(self.yaw_along[max(i, 1) if len(self.xy) > 1 else 0]),
                )
        raise AssertionError("unreachable: the last place ends the walk")


class ObstacleField:
    def __init__(self, scenario: Scenario | None, route: Route, ground: Callable[[float], float]):
        """`ground(s)` is the road crown's height at arc length s (World.centre_height)."""
        self.route = route
        self.ground = ground
        specs = list(scenario.obstacles) if scenario else []
        if scenario is not None and scenario.along_tour is not None:
            specs += along_tour(route, scenario.along_tour)
        self.obstacles = [self._place(spec) for spec in specs if spec.appear_ahead_m is None]
        # those that appear ahead of the vehicle at a time (and may leave again): placed when they appear
        self.to_appear = sorted((s for s in specs if s.appear_ahead_m is not None), key=lambda s: s.start_t_s or 0.0)

    def _place(self, spec: ScenarioObstacle, from_s: float = 0.0) -> PlacedObstacle:
        xy, yaws, zs = [], [], []
        for place in spec.path:
            x, y, _, yaw = self.route.point_at(from_s + place.s)
            xy.append((x - math.sin(yaw) * place.offset_m, y + math.cos(yaw) * place.offset_m))
            yaws.append(yaw)
            at = self.route.wrap_s(from_s + place.s)
            half = float(self.route.width[self.route.index_at(at)]) / 2
            zs.append(float(self.ground(at)) - CROSSFALL * min(abs(place.offset_m), half))
        xy = np.array(xy)
        heading = [yaws[0]] + [
            math.atan2(b[1] - a[1], b[0] - a[0]) if np.any(b != a) else yaws[0] for a, b in zip(xy[:-1], xy[1:])
        ]
        return PlacedObstacle(spec, xy, np.array(heading), np.array(zs))

    def update(self, t: float, vehicle_progress_m: float) -> list[str]:
        """Start whatever is due (and place those that appear now, take away those that leave); the
        names of those that started or appeared."""
        started = []
        self.obstacles = [ob for ob in self.obstacles if ob.gone_at is None or ob.gone_at > t]
        while self.to_appear and (self.to_appear[0].start_t_s or 0.0) <= t:
            spec = self.to_appear.pop(0)
            begins = spec.start_t_s or 0.0
            if spec.gone_after_s is not None and begins + spec.gone_after_s <= t:
                continue  # came and went before this process started (a restart)
            ob = self._place(spec, vehicle_progress_m + (spec.appear_ahead_m or 0.0))
            ob.started_at = t
            if spec.gone_after_s is not None:
                ob.gone_at = t + spec.gone_after_s
            self.obstacles.append(ob)
            started.append(spec.name)
        for ob in self.obstacles:
            if ob.started_at is not None or not ob.moving:
                continue
            spec = ob.spec
            if (
                (spec.start_t_s is not None and t >= spec.start_t_s)
                or (spec.start_when_vehicle_at_s is not None and vehicle_progress_m >= spec.start_when_vehicle_at_s)
                or (spec.start_t_s is None and spec.start_when_vehicle_at_s is None)
            ):
                ob.started_at = t
                started.append(spec.name)
        return started

    def boxes(self, t: float) -> list[ObstacleBox]:
        out = []
        for ob in self.obstacles:
            x, y, _, yaw = ob.where(t)
            length, width, height = ob.spec.size()
            out.append(
                ObstacleBox(
                    name=ob.spec.name,
                    kind=ob.spec.kind,
                    x=x,
                    y=y,
                    yaw=yaw,
                    length_m=length,
                    width_m=width,
                    height_m=height,
                    moving=ob.moving,
                )
            )
        return out

    def mesh_near(self, t: float, x: float, y: float, reach_m: float) -> Mesh | None:
        """The obstacles within reach of (x, y), as one mesh; None if there are none."""
        parts = []
        for ob in self.obstacles:
            ox, oy, oz, yaw = ob.where(t)
            if math.hypot(ox - x, oy - y) <= reach_m:
                parts.append(box_mesh((ox, oy, oz - 0.05), ob.spec.size(), yaw, "metal"))
        return Mesh.join(parts) if parts else None


def along_tour(route: Route, spec: ScenarioAlongTour) -> list[ScenarioObstacle]:
    out: list[ScenarioObstacle] = []
    k = 0
    for s in np.arange(spec.every_m / 2, route.length, spec.every_m):
        s = float(s)
        width = float(route.width[route.index_at(s)])
        near_open = any(route.in_zone(s + d, kind) for kind in OPEN_ZONES for d in (-15.0, 0.0, 15.0))
        if width < spec.skip_narrower_than_m or near_open:
            continue
        kind = spec.kinds[k % len(spec.kinds)]
        side = 1.0 if k % 2 == 0 else -1.0
        offset = side * (spec.clearance_m + OBSTACLE_SIZES[kind][1] / 2)
        out.append(ScenarioObstacle(name=f"{kind}_{round(s)}", kind=kind, path=[ScenarioPlace(s=s, offset_m=offset)]))
        k += 1
    return out


def touching(boxes: list[ObstacleBox], body: np.ndarray) -> set[str]:
    """The names of the obstacles whose footprint overlaps the body's (its corners, in order)."""
    centre, reach = body.mean(axis=0), float(np.max(np.hypot(*(body - body.mean(axis=0)).T)))
    out = set()
    for box in boxes:
        if math.hypot(box.x - centre[0], box.y - centre[1]) > reach + math.hypot(box.length_m, box.width_m) / 2:
            continue  # the circles around the two footprints do not meet
        corners = rectangle_corners(box.x, box.y, box.yaw, box.length_m / 2, box.length_m / 2, box.width_m / 2)
        if convex_gap(body, corners) <= 0.0:
            out.add(box.name)
    return out
