"""The mission manager and the body on the in-memory bus, with a point that drives along the
route at the mission's limit (Tour)."""

from __future__ import annotations

from ares.core.clock import ManualClock
from ares.core.membus import MemoryNetwork
from ares.core.messages import (
    BodyState,
    CarState,
    DriveMode,
    PathMatch,
    SpeedLimits,
)
from managers.mission_node import MissionManager
from simulator.body import BodySim

DT = 0.1
CRUISE = 3.0


class Tour:
    """The mission manager, the body and a point that drives along the route at the mission's limit."""

    def __init__(self, cfg: dict, passengers=(), s0: float = 0.0):
        self.cfg = cfg
        self.clock = ManualClock()
        self.network = MemoryNetwork()
        self.bus = self.network.bus("test", self.clock)
        self.status = self.bus.subscribe("mission/status")
        self.commands = self.bus.subscribe("body/command", queue=1000)
        self.events = self.bus.subscribe("events", queue=10000)
        self.body = BodySim(
            door_travel_s=2.5, ramp_travel_s=6.0, per_person_s=2.0, passengers=2, stops={p.poi: p for p in passengers}
        )
        self.t, self.progress, self.v = 0.0, s0, 0.0
        self.node = self.start_node()
        self.violations: list[str] = []
        self.lap_offset = 0  # a restarted path manager counts its laps from 0 again

    def start_node(self) -> MissionManager:
        node = MissionManager(self.cfg, clock=self.clock, bus=self.network.bus("mission_manager", self.clock))
        node.setup()
        self.route = node.route
        return node

    def poi_here(self) -> str | None:
        if self.v > 0.05:
            return None
        for poi in self.route.pois:
            if abs(self.route.step_between(poi.s, self.progress % self.route.length)) <= 3.0:
                return poi.name
        return None

    def run(self, seconds: float) -> None:
        for _ in range(round(seconds / DT)):
            self.t = t = round(self.t + DT, 9)
            self.clock.set(t)
            lap, s = divmod(self.progress, self.route.length)
            self.bus.publish(
                "path/match",
                PathMatch(
                    t=t,
                    index=0,
                    s=s,
                    lap=int(lap) - self.lap_offset,
                    xte=0.0,
                    heading_error=0.0,
                    zones=[],
                    force_odometry=False,
                    distance_to_end_m=None,
                    ahead_x=[],
                    ahead_y=[],
                    ahead_yaw=[],
                    ahead_curvature=[],
                    ahead_speed=[],
                    ahead_s=[],
                ),
            )
            self.bus.publish(
                "dbw/car_state",
                CarState(
                    t=t,
                    mode=DriveMode.AUTOMATIC,
                    engaged=True,
                    watchdog_tripped=False,
                    setpoint_age_s=0.02,
                    v_command=self.v,
                    kappa_command=0.0,
                    speed_mps=self.v,
                    steering_wheel_deg=0.0,
                ),
            )
            self.bus.publish(
                "speed/limits",
                SpeedLimits(
                    t=t,
                    s=s,
                    section=0,
                    kind="cruise",
                    limit_mps=CRUISE,
                    next_section=1,
                    next_limit_mps=CRUISE,
                    distance_to_next_m=10.0,
                ),
            )
            b = self.body
            self.bus.publish(
                "body/state",
                BodyState(
                    t=t, doors=b.door_state, ramp=b.ramp_state, entrance_clear=b.entrance_clear, passengers=b.passengers
                ),
            )
            self.node.step_once(t)
            self.node.bus.poll_services()
            for _, cmd in self.commands.drain():
                self.body.command(cmd.doors, cmd.ramp, cmd.media)
            self.body.step(DT, self.poi_here())
            st = self.status.latest
            limit = CRUISE if st.limit_mps is None else min(st.limit_mps, CRUISE)
            self.v = max(0.0, min(limit, self.v + 1.0 * DT)) if limit >= self.v else max(limit, self.v - 2.5 * DT)
            if self.v > 0.05 and (b.door_state != "closed" or b.ramp_state != "stowed"):
                self.violations.append(
                    f"t={t:.1f}: moving at {self.v:.2f} m/s, doors {b.door_state}, ramp {b.ramp_state}"
                )
            self.progress += self.v * DT

    def until(self, condition, limit_s: float, what: str) -> None:
        for _ in range(round(limit_s / DT)):
            if self.status.latest is not None and condition():
                return
            self.run(DT)
        raise AssertionError(f"not within {limit_s} s: {what} (mission {self.status.latest})")

    def kinds(self, kind: str) -> list:
        return [e for _, e in self.events.drain() if e.kind == kind]
