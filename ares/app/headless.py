"""`ares run --headless`: drive the running stack unattended and measure what it did.

It engages Automatic mode itself (the Auto/Manual button on the simulated panel, then the
`set_automatic_mode` service, as a safety driver and the navigation system would), drives N laps
of the tour (or an open route to its end; or, with --seconds, for that much vehicle time), feeds
what the stack publishes to the evaluations (ares.app.evaluation: the lap, localization,
control, perception and safety figures), plays the scenario's process faults and operator
actions (ares.app.scenario_driver), and returns the figures of the run's result (`ares run` prints
them as its last line), with a picture of the lap (ares.app.lap_figure).

The stack itself is started, watched and stopped by ares.app.stack.run, which calls `drive` with
the running stack.
`Measurements` (what is measured, from which topics) and `Goal` (when the drive is done, or has
failed) serve the in-process stack too (tests.helpers.in_process_stack), so that a test on
the in-memory bus measures exactly what a headless run measures.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ares.app.engagement import STARTUP_TIMEOUT_S, RunFailed, engage_automatic, wait_for
from ares.app.evaluation.control_eval import ControlTracker
from ares.app.evaluation.corrections_eval import CorrectionsTracker
from ares.app.evaluation.lap_eval import LapTracker, LocalizationTracker
from ares.app.evaluation.perception_eval import PerceptionTracker
from ares.app.evaluation.safety_eval import SafetyTracker
from ares.app.lap_figure import write_lap_svg
from ares.app.run_options import RunningStack
from ares.app.scenario_driver import ScenarioDriver
from ares.core import config
from ares.core.bus import BaseBus
from ares.core.messages import DriveMode, MissionStatus
from ares.core.route import Route
from ares.core.signed_command import load_command_key
from managers.speed import SpeedProfileParams, cruise_speed
from simulator.scenario import load_scenario

CLOCK_STALL_S = 30.0  # wall seconds without the clock moving: the run has stalled
STANDSTILL_S = 60.0  # stack seconds without progress along the route: the shuttle is stuck
LEFT_AUTOMATIC_CHECKS = 20  # out of Automatic this many checks in a row: the run has failed
QUEUE = 4096  # messages a measured topic may hold between two takes


class Measurements:
    """What a headless run measures: the evaluations, fed from the topics they read."""

    def __init__(self, cfg: dict, route: Route, bus: BaseBus, inject: Callable[[str, str], str]):
        vehicle = config.core(cfg).vehicle_profile
        self.cfg, self.route = cfg, route
        self.perceiving = bool(vehicle.lidars) and cfg["lidars"]
        self.lap = LapTracker(route)
        self.localization = LocalizationTracker()
        self.control = ControlTracker()
        self.safety = SafetyTracker(vehicle.length_m, vehicle.width_m, vehicle.front_bumper_m)
        self.perception = PerceptionTracker(route, front_bumper_x_m=(vehicle.length_m + vehicle.wheelbase_m) / 2)
        self.corrections = CorrectionsTracker()
        scenario = load_scenario(cfg["scenario"]) if cfg["scenario"] else None
        self.scenario = ScenarioDriver(scenario, bus, inject, self.safety, load_command_key(config.core(cfg).commands))
        self.truth = bus.subscribe("sim/truth", queue=QUEUE)
        self.statuses = bus.subscribe("control/status", queue=QUEUE)
        self.movement = bus.subscribe("movement/status", queue=QUEUE)
        self.cars = bus.subscribe("dbw/car_state", queue=QUEUE)
        self.mission = bus.subscribe("mission/status")
        # what each evaluation learns from which topic, in this order at every take: the body and the
        # gate before the truth (its motion is judged against them), the truth before what is matched to it
        self._feeds: list[tuple[Any, Callable[[Any], None]]] = [
            (bus.subscribe("body/state", queue=1024), self.safety.add_body),
            (self.movement, self._on_movement),
            (self.cars, self.safety.add_car),
            (bus.subscribe("awareness/state", queue=1024), self.safety.add_awareness),
            (self.truth, self._on_truth),
        ]
        if self.perceiving:
            self._feeds += [
                (bus.subscribe("sim/world", queue=1024), self._on_world),
                (bus.subscribe("perception/road", queue=QUEUE), self.perception.add_road),
                (bus.subscribe("perception/grid", queue=256), self.perception.add_grid),
                (bus.subscribe("perception/lidar_status", queue=1024), self.perception.add_status),
            ]
        self._feeds += [
            (bus.subscribe("localization/pose", queue=QUEUE), self._on_pose),
            (bus.subscribe("odometry/score", queue=QUEUE), self._on_score),
            (self.statuses, lambda st: self.control.add_status(st.t, st.controller)),
            (bus.subscribe("control/candidate/mpc", queue=QUEUE), lambda c: self.control.add_mpc(c.solve_ms, c.fresh)),
            (bus.subscribe("events", queue=QUEUE), self._on_event),
            (bus.subscribe("drivers/status", queue=1024), self._on_driver),
            (bus.subscribe("gnss/corrections", queue=1024), self.corrections.add_status),
            (bus.subscribe("gnss/fix", queue=QUEUE), self.corrections.add_fix),
            (bus.subscribe("obstacle/state", queue=1024), self._on_obstacle),
        ]
        self.drivers: dict[str, Any] = {}  # device -> its driver's latest counts (--wire, a vehicle)
        self.obstacle: Any = None  # the obstacle manager's latest verdict
        self.hold: dict | None = None  # while the movement gate holds the shuttle: by what, why and where

    def begin(self) -> None:
        """The drive starts now: what came before it (starting up, standing, engaging) is not measured."""
        for subscription, _ in self._feeds:
            subscription.drain()

    def take(self, now: float) -> None:
        """The scenario's actions due by `now`, then everything published since the last take."""
        self.scenario.step(now)
        for subscription, handle in self._feeds:
            for _, msg in subscription.drain():
                handle(msg)
        if self.perceiving:
            self.perception.retry()

    def _on_truth(self, msg: Any) -> None:
        self.safety.add_truth(msg.t, msg.x, msg.y, msg.yaw, msg.v, msg.board_failsafe)
        self.lap.update(msg.x, msg.y, msg.odometer_m)
        self.localization.add_truth(msg.t, msg.x, msg.y, msg.yaw, msg.rtk_available, msg.v)
        self.perception.add_truth(msg.t, msg.x, msg.y, msg.yaw, msg.s)
        self.control.add_truth(msg.t, self.lap.xte[-1], msg.v, msg.yaw_rate, msg.accel)

    def _on_world(self, world: Any) -> None:
        self.perception.add_world(world)
        self.safety.add_world(world)

    def _on_pose(self, pose: Any) -> None:
        self.localization.add_pose(pose.t, pose.x, pose.y, pose.yaw)

    def _on_score(self, score: Any) -> None:
        self.localization.add_score(score.t, score.score)

    def _on_event(self, event: Any) -> None:
        self.safety.add_event(event)
        if event.kind == "controller_switch":
            self.control.add_switch(event.data)

    def _on_driver(self, status: Any) -> None:
        self.drivers[status.device] = status

    def _on_obstacle(self, state: Any) -> None:
        self.obstacle = state

    def _on_movement(self, status: Any) -> None:
        """Since when, by what, why and where the movement gate holds the shuttle (None while it
        lets it go): a drive that ends held says what held it. The gate names the manager whose limit
        is 0 (obstacle, mission, ...), or a stop or an emergency; for the obstacle manager its own reason
        (obstacle 1.5 m ahead, 3 cells). The place is where the shuttle stands (the simulator's truth)."""
        self.safety.add_status(status)
        held = status.latched or status.stopping or status.limit_mps == 0.0
        if not held:
            self.hold = None
            return
        # the gate's own words: "emergency" (latched: its reason says why), "stop", or a manager's name
        by = status.limited_by or ("emergency" if status.latched else "stop")
        if by == "obstacle":
            by = "obstacle_manager"
        obstacle = self.obstacle
        reason = status.reason
        if by == "obstacle_manager" and obstacle is not None and obstacle.band in ("stop", "unknown"):
            reason = obstacle.reason or f"obstacle manager: {obstacle.band}"
        if self.hold is None or self.hold["by"] != by:
            self.hold = {"by": by, "since_t_s": round(status.t, 2)}
        truth = self.truth.latest
        self.hold.update(
            at_s_m=None if truth is None else round(truth.s, 1),
            x=None if truth is None else round(truth.x, 2),
            y=None if truth is None else round(truth.y, 2),
            reason=reason,
        )

    def driver_figures(self) -> dict:
        """Per device: in, out, lost, malformed and skipped by cause, wire-to-bus latency (ms)."""
        return {
            device: {
                "driver": st.driver,
                "received": st.received,
                "published": st.published,
                "lost": st.lost,
                "malformed": st.malformed,
                "skipped": st.skipped,
                "latency_p50_ms": st.latency_p50_ms,
                "latency_p99_ms": st.latency_p99_ms,
                "connected": st.connected,
                **({"detail": st.detail} if st.detail else {}),
            }
            for device, st in sorted(self.drivers.items())
        }

    def partial(self) -> dict:
        """The figures of a drive that failed, up to the failure."""
        return {
            "route": self.route.name,
            "vehicle": self.cfg["vehicle"],
            **self.lap.summary(),
            **self.control.summary(),
            **self.safety.summary(),
            **self.scenario.summary(),
            **({"stopped": self.hold} if self.hold else {}),
        }

    def summary(self) -> dict:
        """Every figure of the drive."""
        return {
            **self.lap.summary(),
            **self.localization.summary(),
            **self.control.summary(),
            **(self.perception.summary() if self.perceiving else {}),
            **self.safety.summary(),
            **self.scenario.summary(),
            "mission": mission_summary(self.mission.latest),
            **self.corrections.summary(),
            **({"drivers": self.driver_figures()} if self.drivers else {}),
        }

    def save_trace(self, run_dir: Path) -> None:
        """For `ares compare`: the error along the route and who drove, at the simulator's rate."""
        np.savez_compressed(
            run_dir / "trace.npz",
            progress=np.array(self.lap.progress),
            xte=np.array(self.lap.xte),
            controller=np.array([c or "none" for c in self.control.in_charge()]),
        )

    def picture(self, path: Path, title: str) -> Path:
        lap = self.lap
        return write_lap_svg(
            path, self.route, np.array(lap.xs), np.array(lap.ys), np.array(lap.progress), np.array(lap.xte), title
        )


class Goal:
    """When a drive is done (N laps, an open route's end, or so many seconds) and when it has failed
    (out of Automatic unless the scenario's driver takes over, standing for STANDSTILL_S where no
    manager says so, over its time limit)."""

    def __init__(self, m: Measurements, t_start: float, laps: int = 1, seconds: float | None = None):
        self.m, self.t_start, self.laps, self.seconds = m, t_start, laps, seconds
        route = m.route
        self.target_m = laps * route.length if route.closed else route.length
        vehicle = config.core(m.cfg).vehicle_profile
        cruise = cruise_speed(config.section(m.cfg, "speed_profile", SpeedProfileParams), vehicle, route)
        self.time_limit_s = seconds + 60.0 if seconds is not None else 3.0 * self.target_m / (0.5 * cruise) + 60.0
        self._left_automatic = 0
        self._moved = (0.0, t_start)  # (travelled m, when): a shuttle that stops moving is stuck

    def reached(self, now: float) -> bool:
        """Whether the drive is done at `now`; RunFailed if it can no longer be."""
        m, travelled = self.m, self.m.lap.travelled_m
        car, status, truth = m.cars.latest, m.statuses.latest, m.truth.latest
        if car is not None and car.mode != DriveMode.AUTOMATIC and not m.scenario.driver_takes_over:
            self._left_automatic += 1
            if self._left_automatic > LEFT_AUTOMATIC_CHECKS:
                raise RunFailed(f"the vehicle left Automatic mode ({car.mode.value}: {car.reason})")
        else:
            self._left_automatic = 0
        if self.seconds is not None and now - self.t_start >= self.seconds:
            return True
        if m.route.closed and self.seconds is None and travelled >= self.target_m:
            return True
        if not m.route.closed and status is not None and status.finished and truth is not None and abs(truth.v) < 0.05:
            return True
        gate = m.movement.latest
        held = (gate is not None and (gate.latched or gate.stopping or gate.limit_mps == 0.0)) or (
            status is not None and status.controller == "stop" and self.seconds is not None
        )
        # standing where a manager says so is not stuck (a run of given seconds waits with it)
        if travelled > self._moved[0] + 0.5 or held:
            self._moved = (travelled, now)
        elif now - self._moved[1] > STANDSTILL_S:
            why = f": the control manager forwards {status.controller} ({status.reason})" if status else ""
            raise RunFailed(
                f"the shuttle has not moved for {STANDSTILL_S:g} s, at {travelled:.0f} of {self.target_m:.0f} m{why}"
            )
        if now - self.t_start > self.time_limit_s:
            raise RunFailed(
                f"did not finish within {self.time_limit_s:.0f} s of vehicle time "
                f"({travelled:.0f} of {self.target_m:.0f} m)"
            )
        return False

    def laps_driven(self) -> int:
        if self.seconds is not None and self.m.route.closed:
            return max(int(self.m.lap.travelled_m // self.m.route.length), 1)
        return self.laps if self.m.route.closed else 0


def drive(running: RunningStack) -> dict:
    """Engage, drive and measure (see the module's docstring); RunFailed carries the figures up to a failure."""
    cfg, route, bus, clock = running.cfg, running.route, running.bus, running.clock
    stop, run_dir = running.stop, running.run_dir
    car_state = bus.subscribe("dbw/car_state")
    m = Measurements(cfg, route, bus, running.supervisor.inject)
    wait_for(lambda: m.truth.latest is not None, STARTUP_TIMEOUT_S, "the simulator", stop)
    engage_automatic(bus, car_state, stop)
    t_start = clock.now()
    wall_start = time.monotonic()
    m.begin()
    goal = Goal(m, t_start, running.options.laps or 1, running.options.seconds)
    last_progress = 0.0
    clock_moved = (clock.now(), time.monotonic())  # a clock that stops moving is a stalled run
    try:
        while True:
            if stop.is_set():
                raise RunFailed("interrupted")
            m.take(clock.now())
            now = clock.now()
            if goal.reached(now):
                break
            if now != clock_moved[0]:
                clock_moved = (now, time.monotonic())
            elif time.monotonic() - clock_moved[1] > CLOCK_STALL_S:
                raise RunFailed(
                    f"the stack clock has not moved for {CLOCK_STALL_S:g} s (the simulator or a process it "
                    "waits for is stuck)"
                )
            if now - last_progress >= 30.0:
                last_progress = now
                print(f"[{now - t_start:6.0f} s] {m.lap.travelled_m:6.0f} / {goal.target_m:.0f} m", file=sys.stderr)
            time.sleep(0.05)
    except RunFailed as exc:  # what was driven until then, for `ares compare` and the reader
        exc.figures = m.partial()
        m.save_trace(run_dir)
        raise
    lap_time = clock.now() - t_start
    wall_s = time.monotonic() - wall_start
    laps = goal.laps_driven()
    result = {
        "laps": laps,
        "route": route.name,
        "route_length_m": round(route.length, 2),
        "lap_time_s": round(lap_time / max(laps, 1), 2),
        "total_time_s": round(lap_time, 2),
        **m.summary(),
        "speed_factor": round(lap_time / max(wall_s, 1e-9), 2),
        "clock": clock.mode,
        "wall_time_s": round(wall_s, 1),
        "vehicle": cfg["vehicle"],
        "t_start_s": round(t_start, 3),  # the drive, stack time
        "t_end_s": round(t_start + lap_time, 3),
    }
    for device, fig in result.get("drivers", {}).items():
        print(
            f"driver {fig['driver']:<12} {device:<18} in {fig['received']:>8}  out {fig['published']:>7}  "
            f"lost {fig['lost']:>4}  malformed {sum(fig['malformed'].values()):>4}  "
            f"wire->bus p50 {fig['latency_p50_ms']} ms  p99 {fig['latency_p99_ms']} ms",
            file=sys.stderr,
        )
    corrections = result.get("corrections")
    if corrections:
        print(
            f"corrections {corrections['source']}: RTK fixed {corrections['rtk_fixed_share']}, "
            f"age p50 {corrections['age_s_p50']} s max {corrections['age_s_max']} s, "
            f"{corrections['outages']} outages",
            file=sys.stderr,
        )
    title = f"{route.name}: {result['distance_m']:.0f} m in {lap_time:.0f} s, {cfg['vehicle']}"
    result["plot"] = str(m.picture(run_dir / "lap.svg", title))
    m.save_trace(run_dir)
    return result


def mission_summary(status: MissionStatus | None) -> dict | None:
    if status is None:
        return None
    return {
        "goal_id": status.goal_id,
        "kind": status.kind,
        "state": status.state,
        "poi": status.poi,
        "result": status.result,
    }
