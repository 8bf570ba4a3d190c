"""The safety figures of a headless run (issue 11), from the simulator's truth and the managers' messages:

| figure                 | how                                                                      |
|------------------------|--------------------------------------------------------------------------|
| collisions             | the body's footprint overlapping an obstacle's (truth), counted once per obstacle |
| min_clearance_m        | the smallest gap between them while the shuttle moves or stands         |
| closest_approach       | ... when, to which obstacle, at what speed (the soak's: where to look)   |
| invariant_violations   | moving (> 0.05 m/s) with a door not closed or the ramp not stowed; a     |
|                        | command above the gate's active limit; moving under a latched emergency  |
| faults                 | per fault: when it began; the stop begun (the gate stopping or latched,  |
|                        | the bridge's watchdog or emergency, the board's fail-safe); standstill   |
|                        | while it lasted (none if the cause cleared first); the stop's end; moving |
|                        | again at 0.5 m/s after it                                                |
| level_history          | every change of the awareness level, with its causes                     |
| poi_actions            | the mission's POI actions, in the order done                             |
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from ares.core.geometry import convex_gap, rectangle_corners
from ares.core.messages import AwarenessState, BodyState, CarState, Event, MovementStatus, WorldTruth

MOVING_MPS = 0.05
RESUMED_MPS = 0.5


@dataclass
class FaultRecord:
    kind: str
    target: str
    at_s: float
    stop_begun_s: float | None = None
    standstill_s: float | None = None
    stop_ended_s: float | None = None
    resumed_s: float | None = None

    def summary(self) -> dict:
        def after(t):
            return None if t is None else round(t - self.at_s, 3)

        return {
            "kind": self.kind,
            "target": self.target,
            "at_s": round(self.at_s, 2),
            "time_to_safe_state_s": after(self.stop_begun_s),
            "time_to_standstill_s": after(self.standstill_s),
            "stop_ended_after_s": after(self.stop_ended_s),
            "resumed_after_s": after(self.resumed_s),
        }


@dataclass
class SafetyTracker:
    length_m: float
    width_m: float
    front_bumper_m: float  # ahead of the truth's reference point (the rear axle)
    obstacles: list = field(default_factory=list)
    collided: set[str] = field(default_factory=set)
    min_clearance_m: float = math.inf
    closest: dict | None = None  # where min_clearance_m was: t, obstacle, kind, speed
    violations: int = 0
    examples: list[str] = field(default_factory=list)
    level_history: list[list] = field(default_factory=list)
    poi_actions: list[list[str]] = field(default_factory=list)
    faults: list[FaultRecord] = field(default_factory=list)
    body: BodyState | None = None
    latched: bool = False
    stops: dict[str, bool] = field(default_factory=dict)  # each source of a stop: active now?
    v: float = 0.0

    # ---- inputs ---------------------------------------------------------------------------------
    def add_world(self, world: WorldTruth) -> None:
        self.obstacles = world.obstacles

    def add_body(self, body: BodyState) -> None:
        self.body = body

    def add_truth(self, t: float, x: float, y: float, yaw: float, v: float, failsafe: bool = False) -> None:
        self.v = v
        moving = abs(v) > MOVING_MPS
        if moving and self.body is not None and (self.body.doors != "closed" or self.body.ramp != "stowed"):
            self._violate(t, f"moving at {v:.2f} m/s with the doors {self.body.doors} and the ramp {self.body.ramp}")
        if self.obstacles:
            me = rectangle_corners(
                x, y, yaw, self.front_bumper_m, self.length_m - self.front_bumper_m, self.width_m / 2
            )
            centre = me.mean(axis=0)
            reach = math.hypot(self.length_m, self.width_m) / 2  # the footprint's corners from its centre
            for ob in self.obstacles:
                # no nearer than the two circles around the footprints allow: a gap that cannot be the
                # smallest yet, nor a collision, needs no exact figure (most obstacles are far away)
                bound = math.hypot(ob.x - centre[0], ob.y - centre[1]) - reach - math.hypot(ob.length_m, ob.width_m) / 2
                if bound > 0.0 and bound >= self.min_clearance_m:
                    continue
                other = rectangle_corners(ob.x, ob.y, ob.yaw, ob.length_m / 2, ob.length_m / 2, ob.width_m / 2)
                gap = convex_gap(me, other)
                if gap < self.min_clearance_m:
                    self.min_clearance_m = gap
                    self.closest = {"t": round(t, 2), "obstacle": ob.name, "kind": ob.kind, "v_mps": round(v, 2)}
                if gap <= 0.0 and ob.name not in self.collided:
                    self.collided.add(ob.name)
                    self._violate(t, f"collision with {ob.name} ({ob.kind}) at {v:.2f} m/s")
        self._update_faults(t, v, failsafe)

    def add_status(self, status: MovementStatus) -> None:
        if status.latched and status.v > 0.0:
            self._violate(status.t, f"command {status.v:.3f} m/s under a latched emergency stop")
        elif status.limit_mps is not None and status.v > status.limit_mps + 1e-6:
            self._violate(
                status.t,
                f"command {status.v:.3f} m/s above the active limit {status.limit_mps:.3f} ({status.limited_by})",
            )
        self.latched = status.latched
        self._stop_signal(status.t, "gate", status.latched or status.stopping)

    def add_car(self, car: CarState) -> None:
        self._stop_signal(car.t, "bridge", car.watchdog_tripped or car.emergency)

    def add_awareness(self, state: AwarenessState) -> None:
        if not self.level_history or self.level_history[-1][1] != state.level:
            self.level_history.append([round(state.t, 2), state.level, "; ".join(state.causes)])

    def add_event(self, event: Event) -> None:
        if event.kind == "poi_action":
            self.poi_actions.append([event.data.get("poi", "?"), event.data.get("action", "?")])

    def add_fault(self, t: float, kind: str, target: str) -> None:
        self.faults.append(FaultRecord(kind, target, t))

    # ---- bookkeeping ----------------------------------------------------------------------------
    def _violate(self, t: float, what: str) -> None:
        self.violations += 1
        if len(self.examples) < 5:
            self.examples.append(f"t={t:.2f}: {what}")

    def _stop_signal(self, t: float, source: str, active: bool) -> None:
        was = any(self.stops.values())
        self.stops[source] = active
        now = any(self.stops.values())
        for fault in self.faults:
            if t < fault.at_s:
                continue
            if now and fault.stop_begun_s is None:
                fault.stop_begun_s = t
            elif was and not now and fault.stop_begun_s is not None and fault.stop_ended_s is None:
                fault.stop_ended_s = t

    def _update_faults(self, t: float, v: float, failsafe: bool) -> None:
        self._stop_signal(t, "board", failsafe)
        for fault in self.faults:
            if fault.stop_begun_s is None or t < fault.stop_begun_s:
                continue
            if fault.stop_ended_s is None:
                if fault.standstill_s is None and abs(v) <= MOVING_MPS:
                    fault.standstill_s = t
            elif fault.resumed_s is None and abs(v) >= RESUMED_MPS:
                fault.resumed_s = t

    def summary(self) -> dict:
        return {
            "collisions": len(self.collided),
            "min_clearance_m": round(self.min_clearance_m, 3) if math.isfinite(self.min_clearance_m) else None,
            "closest_approach": self.closest,
            "invariant_violations": self.violations,
            "invariant_examples": self.examples,
            "level_history": self.level_history,
            "faults": [f.summary() for f in self.faults],
            "poi_actions": self.poi_actions,
        }
