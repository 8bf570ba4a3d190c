"""The live gateway's state: the latest of what the pages show, per vehicle, from the bus.

The API process subscribes to GATEWAY_TOPICS of every vehicle on the router (bus.subscribe_fleet)
and hands each message to LiveHub.put, on the transport's thread: put only stores the message
(and queues an event), so the bus is never held up by a browser. The streams (blackbox/api/
routes/live.py) ask for frames at their own pace: `frame()` builds the view of one vehicle from
what is stored (the occupancy grid thinned for display, cached per grid message), `fleet_frame()`
the light view of every vehicle. Nothing here does I/O.

Lateness (the fleet page): each vehicle's legs between two points of interest are timed from
its mission status: a leg starts when the mission leaves a POI (or its goal starts) and ends at
the next POI. A leg's expected time is the median of the same leg's past times when there are
some, else the mission's own expected arrival from the speed profile when the leg began; a
vehicle is late once the time since its last POI exceeds the expected time by
`late_factor` and `late_margin_s` (a pause counts: the passengers wait all the same).
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ares.core.config import Params, param
from ares.core.geometry import vehicle_to_local
from ares.core.messages import (
    FIX_QUALITY_NAMES,
    AwarenessState,
    BlackboxStatus,
    BodyState,
    CarState,
    ControllerStatus,
    CorrectionsStatus,
    Event,
    GnssFix,
    MissionStatus,
    MovementStatus,
    ObstacleState,
    OccupancyGrid,
    OdometryScore,
    Pose,
    PredictedTrajectory,
    RoadDetection,
    SpeedLimits,
    SupervisorState,
)
from blackbox.console.passenger_view import passenger_frame

FORGET_AFTER_S = 3600.0  # a vehicle silent this long is dropped from memory

# topic -> what the pages make of it
GATEWAY_TOPICS: dict[str, type] = {
    "localization/pose": Pose,
    "dbw/car_state": CarState,
    "odometry/score": OdometryScore,
    "obstacle/state": ObstacleState,
    "perception/road": RoadDetection,
    "control/status": ControllerStatus,
    "control/mpc/trajectory": PredictedTrajectory,
    "movement/status": MovementStatus,
    "awareness/state": AwarenessState,
    "supervisor/state": SupervisorState,
    "mission/status": MissionStatus,
    "body/state": BodyState,
    "speed/limits": SpeedLimits,
    "perception/grid": OccupancyGrid,
    "gnss/corrections": CorrectionsStatus,
    "gnss/fix": GnssFix,
    "blackbox/status": BlackboxStatus,
    "events": Event,
}


class LiveSettings(Params):
    """The live gateway (GET /api/v1/live/...): what the pages see of the bus, and how often."""

    rate_hz: float = param(
        5.0, "frames per second a stream sends at most (a client may ask for fewer)", unit="Hz", gt=0, le=20
    )
    max_streams_per_user: int = param(4, "open streams per user name; one more is refused (429)", ge=1)
    max_streams: int = param(64, "open streams in all", ge=1)
    stale_s: float = param(
        2.0, "a value older than this (wall seconds since it arrived) is shown as missing", unit="s", gt=0
    )
    vehicle_gone_s: float = param(
        600.0,
        "a vehicle heard from no longer than this ago is left off the fleet (before: shown unreachable)",
        unit="s",
        gt=0,
    )
    unreachable_after_s: float = param(
        3.0, "a vehicle heard from no longer than this ago is shown unreachable (a cut link)", unit="s", gt=0
    )
    events_kept: int = param(200, "recent events kept for new streams", ge=1)
    grid_cell_m: float = param(0.5, "the occupancy grid is thinned to cells of this size for display", unit="m", gt=0)
    grid_max_cells: int = param(1500, "most occupied cells sent per frame", ge=1)
    late_factor: float = param(
        1.25, "late: the time since the last POI beyond this share of the leg's expected time ...", ge=1
    )
    late_margin_s: float = param(30.0, "... plus this margin", unit="s", ge=0)


@dataclass
class _Stored:
    msg: object
    wall: float  # time.time() when it arrived


@dataclass
class LegTimer:
    """One vehicle's legs between POIs: when the current one began and what it should take."""

    history: dict[tuple[str, str], deque] = field(default_factory=dict)  # (from, to) -> past durations (s)
    from_poi: str | None = None
    to_poi: str | None = None
    started_t: float | None = None  # stack time the leg began
    profile_s: float | None = None  # the mission's expected duration when it began
    was_at_poi: bool = False

    def update(self, status: MissionStatus) -> None:
        at_poi = status.state == "AT_POI"
        driving = status.state in ("DRIVING", "PAUSED") and status.kind == "tour"
        if at_poi and not self.was_at_poi and self.started_t is not None and self.to_poi == status.poi:
            key = (self.from_poi or "", status.poi or "")
            self.history.setdefault(key, deque(maxlen=20)).append(status.t - self.started_t)
        if at_poi:
            self.from_poi, self.started_t, self.to_poi = status.poi, None, None
        elif driving and (self.started_t is None or self.to_poi != status.poi):
            self.started_t, self.to_poi = status.t, status.poi
            self.profile_s = None if status.eta_s is None else max(status.eta_s - status.t, 0.0)
        elif not driving and not at_poi:
            self.started_t = self.to_poi = None
        self.was_at_poi = at_poi

    def snapshot(self) -> LegTimer:
        """A copy to read outside the hub's lock (the bus's thread updates the original)."""
        key = (self.from_poi or "", self.to_poi or "")
        history = {key: deque(self.history[key])} if key in self.history else {}
        return LegTimer(history, self.from_poi, self.to_poi, self.started_t, self.profile_s, self.was_at_poi)

    def expected_s(self) -> tuple[float | None, str]:
        past = self.history.get((self.from_poi or "", self.to_poi or ""))
        if past:
            return float(np.median(past)), f"median of {len(past)} past runs"
        return self.profile_s, "speed profile"


@dataclass
class _Vehicle:
    latest: dict[str, _Stored] = field(default_factory=dict)
    legs: LegTimer = field(default_factory=LegTimer)
    heard: float = 0.0
    grid_cache: tuple[object, dict] | None = None  # (the grid message, its thinned cells)
    full_stop_at: float | None = None  # the line of the mission's intersection stop under way (its events)


class LiveHub:
    """The latest messages of every vehicle, and the recent events, for the streams."""

    def __init__(
        self,
        settings: LiveSettings,
        now: Callable[[], float] = time.time,
        wall_of: Callable[[float], float] | None = None,
        not_vehicles: frozenset[str] = frozenset(),
    ):
        """`wall_of`: the wall time (epoch s) a stack time stands for, when the clock runs at real
        time: each frame then says when its vehicle state was published, and a page how far behind
        the bus it is."""
        self.s = settings
        self.now = now
        self.not_vehicles = not_vehicles  # ids on the bus that are no vehicle (the fleet server's): events only
        self.wall_of = wall_of
        self._vehicles: dict[str, _Vehicle] = {}
        self._events: deque[dict] = deque(maxlen=settings.events_kept)
        self._event_seq = 0
        self._lock = threading.Lock()
        self.streams: dict[str, int] = {}  # user -> open streams

    # ---- the bus's side: store and return ---------------------------------------------------
    def put(self, vehicle_id: str, topic: str, msg) -> None:
        wall = self.now()
        with self._lock:
            vehicle = self._vehicles.get(vehicle_id)
            if vehicle is None:
                vehicle = self._vehicles[vehicle_id] = _Vehicle()
            vehicle.heard = wall
            if topic == "events":
                if msg.kind in ("full_stop", "full_stop_cleared"):
                    line = (msg.data or {}).get("line_s")
                    vehicle.full_stop_at = float(line) if msg.kind == "full_stop" and line is not None else None
                self._event_seq += 1
                self._events.append(
                    {
                        "seq": self._event_seq,
                        "vehicle_id": vehicle_id,
                        "t": msg.t,
                        "wall_ms": wall * 1e3,
                        "source": msg.source,
                        "kind": msg.kind,
                        "level": msg.level.value if hasattr(msg.level, "value") else str(msg.level),
                        "message": msg.message,
                        # a snapshot's event answers the request that asked for it (the operator page)
                        "request_id": str((msg.data or {}).get("request_id", "")),
                    }
                )
                return
            vehicle.latest[topic] = _Stored(msg, wall)
            if topic == "mission/status":
                vehicle.legs.update(msg)

    # ---- the streams' side ------------------------------------------------------------------
    def vehicles(self) -> list[str]:
        now = self.now()
        cutoff = now - self.s.vehicle_gone_s
        with self._lock:
            for gone in [v for v, state in self._vehicles.items() if state.heard < now - FORGET_AFTER_S]:
                del self._vehicles[gone]  # (a vehicle back later starts its leg history anew)
            return sorted(
                v for v, state in self._vehicles.items() if state.heard >= cutoff and v not in self.not_vehicles
            )

    def knows(self, vehicle_id: str) -> bool:
        with self._lock:
            return vehicle_id in self._vehicles

    def events_since(self, seq: int, vehicle_id: str | None = None) -> list[dict]:
        with self._lock:
            return [e for e in self._events if e["seq"] > seq and (vehicle_id is None or e["vehicle_id"] == vehicle_id)]

    @property
    def event_seq(self) -> int:
        return self._event_seq

    def _fresh(self, vehicle: _Vehicle, topic: str, now: float):
        stored = vehicle.latest.get(topic)
        if stored is None or now - stored.wall > self.s.stale_s:
            return None
        return stored.msg

    def frame(self, vehicle_id: str) -> dict | None:
        """Everything the operator page shows of one vehicle; None if it was never heard."""
        now = self.now()
        with self._lock:
            vehicle = self._vehicles.get(vehicle_id)
            if vehicle is None:
                return None
            get = {topic: self._fresh(vehicle, topic, now) for topic in GATEWAY_TOPICS if topic != "events"}
            newest = max((s.wall for s in vehicle.latest.values()), default=None)
            stamp = vehicle.latest.get("dbw/car_state")
            legs = vehicle.legs.snapshot()
        frame = _summary(vehicle_id, get, legs, now, self.s)
        frame["gateway_wall_ms"] = None if newest is None else newest * 1e3
        frame["car_state_wall_ms"] = None if stamp is None else stamp.wall * 1e3  # reached the gateway
        frame["car_state_stamp_ms"] = (
            None if stamp is None or self.wall_of is None else self.wall_of(stamp.msg.t) * 1e3
        )  # published on the bus
        trajectory: PredictedTrajectory | None = get["control/mpc/trajectory"]
        frame["trajectory"] = None if trajectory is None else {"x": _round(trajectory.x), "y": _round(trajectory.y)}
        obstacle: ObstacleState | None = get["obstacle/state"]
        pose: Pose | None = get["localization/pose"]
        frame["obstacle"] = (
            None
            if obstacle is None
            else {
                "band": obstacle.band,
                "nearest_m": obstacle.nearest_m,
                "limit_mps": obstacle.limit_mps,
                "score": obstacle.score,
                "reason": obstacle.reason,
                "area": None if pose is None else _to_local(pose, obstacle.area_x, obstacle.area_y),
            }
        )
        frame["grid"] = self._grid(vehicle, get["perception/grid"], pose)
        supervisor: SupervisorState | None = get["supervisor/state"]
        frame["processes"] = (
            None
            if supervisor is None
            else [{"name": p.name, "state": p.state.value, "restarts": p.restarts} for p in supervisor.processes]
        )
        movement: MovementStatus | None = get["movement/status"]
        frame["movement"] = (
            None
            if movement is None
            else {
                "latched": movement.latched,
                "latch_cause": movement.latch_cause,
                "stopping": movement.stopping,
                "limit_mps": movement.limit_mps,
                "limited_by": movement.limited_by,
                "reason": movement.reason,
            }
        )
        mission: MissionStatus | None = get["mission/status"]
        frame["pois"] = [] if mission is None else [p.model_dump(mode="json") for p in mission.pois]
        return frame

    def passenger(self, vehicle_id: str, tour: str, stops: list[str]) -> dict | None:
        """What the passenger page shows of one vehicle (blackbox/console/passenger_view.py)."""
        now = self.now()
        with self._lock:
            vehicle = self._vehicles.get(vehicle_id)
            if vehicle is None:
                return None
            get = {
                t: self._fresh(vehicle, t, now)
                for t in ("dbw/car_state", "mission/status", "movement/status", "body/state")
            }
            full_stop_at = vehicle.full_stop_at
        car: CarState | None = get["dbw/car_state"]
        return passenger_frame(
            vehicle_id,
            tour,
            stops,
            None if car is None else car.speed_mps,
            get["mission/status"],
            get["movement/status"],
            get["body/state"],
            full_stop_at,
            now * 1e3,
        )

    def fleet_frame(self) -> list[dict]:
        """The light view of every vehicle heard lately: where, how fast, its mission, whether late,
        and whether it is reachable (heard within unreachable_after_s)."""
        now = self.now()
        out = []
        for vehicle_id in self.vehicles():
            with self._lock:
                vehicle = self._vehicles[vehicle_id]
                get = {topic: self._fresh(vehicle, topic, now) for topic in GATEWAY_TOPICS if topic != "events"}
                legs = vehicle.legs.snapshot()
                silent_s = max(now - vehicle.heard, 0.0)
            summary = _summary(vehicle_id, get, legs, now, self.s)
            summary["silent_s"] = round(silent_s, 2)
            summary["reachable"] = silent_s <= self.s.unreachable_after_s
            out.append(summary)
        return out

    def _grid(self, vehicle: _Vehicle, grid: OccupancyGrid | None, pose: Pose | None) -> dict | None:
        """Occupied cells, thinned to grid_cell_m, in the local frame (cached per grid message)."""
        if grid is None or pose is None:
            return None
        if vehicle.grid_cache is not None and vehicle.grid_cache[0] is grid:
            return vehicle.grid_cache[1]
        rows, cols = np.nonzero(grid.cells == 100)
        x = grid.origin_x + (cols + 0.5) * grid.resolution_m
        y = grid.origin_y + (rows + 0.5) * grid.resolution_m
        if grid.frame != "local":  # the vehicle frame: turn and move by the pose
            x, y = vehicle_to_local(pose.x, pose.y, pose.yaw, x, y)
        size = self.s.grid_cell_m
        cells = (
            np.unique(np.stack([np.floor(x / size), np.floor(y / size)], axis=1), axis=0)
            if len(x)
            else np.zeros((0, 2))
        )
        if len(cells) > self.s.grid_max_cells:
            cells = cells[np.linspace(0, len(cells) - 1, self.s.grid_max_cells).astype(int)]
        out = {
            "cell_m": size,
            "x": [round(float(v) * size, 2) for v in cells[:, 0]],
            "y": [round(float(v) * size, 2) for v in cells[:, 1]],
        }
        vehicle.grid_cache = (grid, out)
        return out

    # ---- streams per user -------------------------------------------------------------------
    def open_stream(self, user: str) -> str | None:
        """None if the user may open one more stream, else why not."""
        with self._lock:
            if sum(self.streams.values()) >= self.s.max_streams:
                return f"the gateway serves {self.s.max_streams} streams at most"
            if self.streams.get(user, 0) >= self.s.max_streams_per_user:
                return f"{user} has {self.s.max_streams_per_user} live streams open already"
            self.streams[user] = self.streams.get(user, 0) + 1
            return None

    def close_stream(self, user: str) -> None:
        with self._lock:
            left = self.streams.get(user, 0) - 1
            if left > 0:
                self.streams[user] = left
            else:
                self.streams.pop(user, None)


def _gnss(fix: GnssFix | None, corrections: CorrectionsStatus | None, odometry: OdometryScore | None) -> dict | None:
    """The receiver's fix and its corrections, as the operator reads them (DBW §3.10: satellites, DGNSS)."""
    if fix is None and corrections is None:
        return None
    return {
        "fix": None if fix is None else FIX_QUALITY_NAMES.get(fix.quality, f"quality {fix.quality}"),
        "satellites": None if fix is None else fix.satellites,
        "corrections_link": None if corrections is None else corrections.link,
        "corrections_age_s": None if corrections is None or corrections.age_s is None else round(corrections.age_s, 1),
        "corrections_source": None if corrections is None else corrections.source,
        "why_no_rtk": None if odometry is None else odometry.cause,
    }


def _blackbox(status: BlackboxStatus | None) -> dict | None:
    """What the operator sees of the black box's writer: a store down, and whether anything is lost."""
    if status is None:
        return None
    return {
        "store": "up" if status.store_up else "down",
        "written": status.written,
        "waiting": status.spooled + status.in_memory,
        "lost": status.dropped + status.events_dropped + status.lost,
        "store_faults": status.store_faults,
        "last_error": status.last_error or None,
    }


def _summary(vehicle_id: str, get: dict, legs: LegTimer, now_wall: float, s: LiveSettings) -> dict:
    pose: Pose | None = get["localization/pose"]
    car: CarState | None = get["dbw/car_state"]
    control: ControllerStatus | None = get["control/status"]
    awareness: AwarenessState | None = get["awareness/state"]
    mission: MissionStatus | None = get["mission/status"]
    body: BodyState | None = get["body/state"]
    odometry: OdometryScore | None = get["odometry/score"]
    obstacle: ObstacleState | None = get["obstacle/state"]
    road: RoadDetection | None = get["perception/road"]
    limits: SpeedLimits | None = get["speed/limits"]
    expected, basis = legs.expected_s()
    since = None if legs.started_t is None or mission is None else max(mission.t - legs.started_t, 0.0)
    late = bool(expected is not None and since is not None and since > expected * s.late_factor + s.late_margin_s)
    return {
        "vehicle_id": vehicle_id,
        "t": None if car is None else car.t,
        "pose": None
        if pose is None
        else {
            "x": round(pose.x, 3),
            "y": round(pose.y, 3),
            "yaw": round(pose.yaw, 4),
            "std_m": round(pose.position_std_m, 3),
            "rtk": pose.rtk,
        },
        "speed_mps": None if car is None else round(car.speed_mps, 3),
        "steering_wheel_deg": None if car is None else round(car.steering_wheel_deg, 2),
        "mode": None if car is None else car.mode.value,
        "emergency": None if car is None else car.emergency,
        "scores": {
            "odometry": None if odometry is None else round(odometry.score, 3),
            "obstacle": None if obstacle is None else round(obstacle.score, 3),
            "road": None if road is None else round(road.confidence, 3),
        },
        "controller": None if control is None else control.controller,
        "controller_reason": None if control is None else control.reason,
        "gnss": _gnss(get["gnss/fix"], get["gnss/corrections"], odometry),
        "speed_limit_mps": None if limits is None else limits.limit_mps,
        "awareness": None if awareness is None else {"level": awareness.level, "causes": list(awareness.causes)},
        "blackbox": _blackbox(get["blackbox/status"]),
        "mission": None
        if mission is None
        else {
            "state": mission.state,
            "kind": mission.kind,
            "poi": mission.poi,
            "action": mission.action,
            "distance_m": mission.distance_m,
            "eta_s": mission.eta_s,
            "goal_id": mission.goal_id,
            "result": mission.result,
        },
        "body": None
        if body is None
        else {
            "doors": body.doors,
            "ramp": body.ramp,
            "passengers": body.passengers,
            "entrance_clear": body.entrance_clear,
        },
        "leg": {
            "from": legs.from_poi,
            "to": legs.to_poi,
            "since_s": since,
            "expected_s": expected,
            "expected_from": basis,
            "late": late,
        },
        "wall_ms": now_wall * 1e3,
    }


def _round(values, digits: int = 2) -> list[float]:
    return [round(float(v), digits) for v in values]


def _to_local(pose: Pose, xs: list[float], ys: list[float]) -> dict:
    x, y = vehicle_to_local(pose.x, pose.y, pose.yaw, np.asarray(xs), np.asarray(ys))
    return {"x": _round(x), "y": _round(y)}
