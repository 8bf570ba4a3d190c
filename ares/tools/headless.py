"""`ares run --headless`: drive the running stack unattended and measure what it did.

It engages Automatic mode itself (the Auto/Manual button on the simulated panel, then the
`set_automatic_mode` service, as a safety driver and the navigation system would), drives N laps
of the tour (or an open route to its end; or, with --seconds, for that much vehicle time), feeds
what the stack publishes to the evaluations (ares.tools.evaluation: the lap, localization,
control, perception and safety figures), plays the scenario's process faults and operator
actions (ares.tools.scenario_driver), and returns the figures that `ares run` prints as its last
line, with a picture of the lap (ares.tools.figures.lap).

The stack itself is started, watched and stopped by ares.app.stack.run, which calls `drive`.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from ares.app.stack import STARTUP_TIMEOUT_S, RunFailed, engage_automatic, wait_for
from ares.core import config
from ares.core.bus import Bus
from ares.core.clock import Clock
from ares.core.messages import DriveMode
from ares.core.route import Route
from ares.tools.evaluation.control_eval import ControlTracker
from ares.tools.evaluation.lap_eval import LapTracker, LocalizationTracker
from ares.tools.evaluation.perception_eval import PerceptionTracker
from ares.tools.evaluation.safety_eval import SafetyTracker
from ares.tools.figures.lap import write_lap_svg
from ares.tools.scenario_driver import ScenarioDriver
from managers.speed import SpeedProfileParams, cruise_speed

CLOCK_STALL_S = 30.0  # wall seconds without the clock moving: the run has stalled
STANDSTILL_S = 60.0  # stack seconds without progress along the route: the shuttle is stuck


def drive(args, cfg, route: Route, bus: Bus, clock: Clock, stop, run_dir: Path, inject) -> dict:
    """Engage, drive and measure (see the module's docstring); RunFailed carries the figures up to a failure."""
    laps = int(getattr(args, "laps", None) or 1)
    seconds = getattr(args, "seconds", None)  # drive this long (vehicle time) instead of laps
    truth = bus.subscribe("sim/truth", queue=4096)
    car_state = bus.subscribe("dbw/car_state")
    wait_for(lambda: truth.latest is not None, STARTUP_TIMEOUT_S, "the simulator", stop)
    engage_automatic(bus, car_state, stop)
    t_start = clock.now()
    wall_start = time.monotonic()
    truth.drain()
    tracker = LapTracker(route)
    localization = LocalizationTracker()
    vehicle = config.core(cfg).vehicle_profile
    perceiving = bool(vehicle.lidars) and cfg["lidars"]
    perception = PerceptionTracker(route, front_bumper_x_m=(vehicle.length_m + vehicle.wheelbase_m) / 2)
    roads = bus.subscribe("perception/road", queue=4096) if perceiving else None
    grids = bus.subscribe("perception/grid", queue=256) if perceiving else None
    worlds = bus.subscribe("sim/world", queue=1024) if perceiving else None
    lidar_status = bus.subscribe("perception/lidar_status", queue=1024) if perceiving else None
    poses = bus.subscribe("localization/pose", queue=4096)
    scores = bus.subscribe("odometry/score", queue=4096)
    statuses = bus.subscribe("control/status", queue=4096)
    mpc_candidates = bus.subscribe("control/candidate/mpc", queue=4096)
    events = bus.subscribe("events", queue=4096)
    control = ControlTracker()
    safety = SafetyTracker(vehicle.length_m, vehicle.width_m, vehicle.front_bumper_m)
    movement = bus.subscribe("movement/status", queue=4096)
    bodies = bus.subscribe("body/state", queue=1024)
    awareness = bus.subscribe("awareness/state", queue=1024)
    mission = bus.subscribe("mission/status")
    cars = bus.subscribe("dbw/car_state", queue=4096)
    scenario = ScenarioDriver(config.load_scenario(cfg["scenario"]) if cfg["scenario"] else None, bus, inject, safety)
    target_m = laps * route.length if route.closed else route.length
    cruise = cruise_speed(config.section(cfg, "speed_profile", SpeedProfileParams), vehicle, route)
    time_limit_s = 3.0 * target_m / (0.5 * cruise) + 60.0  # stack seconds
    if seconds is not None:
        time_limit_s = seconds + 60.0

    def on_truth(msg) -> None:
        safety.add_truth(msg.t, msg.x, msg.y, msg.yaw, msg.v, msg.board_failsafe)
        tracker.update(msg.x, msg.y, msg.odometer_m)
        localization.add_truth(msg.t, msg.x, msg.y, msg.yaw, msg.rtk_available, msg.v)
        perception.add_truth(msg.t, msg.x, msg.y, msg.yaw, msg.s)
        control.add_truth(msg.t, tracker.xte[-1], msg.v, msg.yaw_rate, msg.accel)

    def on_world(world) -> None:
        perception.add_world(world)
        safety.add_world(world)

    def on_event(event) -> None:
        safety.add_event(event)
        if event.kind == "controller_switch":
            control.add_switch(event.data)

    # what each tracker learns from which topic, in this order every loop: the body and the gate
    # before the truth (its motion is judged against them), the truth before what is matched to it
    feeds = [
        (bodies, safety.add_body),
        (movement, safety.add_status),
        (cars, safety.add_car),
        (awareness, safety.add_awareness),
        (truth, on_truth),
    ]
    if perceiving:
        feeds += [
            (worlds, on_world),
            (roads, perception.add_road),
            (grids, perception.add_grid),
            (lidar_status, perception.add_status),
        ]
    feeds += [
        (poses, lambda pose: localization.add_pose(pose.t, pose.x, pose.y, pose.yaw)),
        (scores, lambda score: localization.add_score(score.t, score.score)),
        (statuses, lambda st: control.add_status(st.t, st.controller)),
        (mpc_candidates, lambda cand: control.add_mpc(cand.solve_ms, cand.fresh)),
        (events, on_event),
    ]
    left_automatic = 0
    last_progress = 0.0
    clock_moved = (clock.now(), time.monotonic())  # a clock that stops moving is a stalled run
    moved = (0.0, clock.now())  # (travelled m, when): a shuttle that stops moving is stuck
    try:
        while True:
            if stop.is_set():
                raise RunFailed("interrupted")
            scenario.step(clock.now())
            for subscription, handle in feeds:
                for _, msg in subscription.drain():
                    handle(msg)
            if perceiving:
                perception.retry()
            now = clock.now()
            if car_state.latest is not None and car_state.latest.mode != DriveMode.AUTOMATIC:
                left_automatic += 1
                if left_automatic > 20:
                    raise RunFailed(
                        f"the vehicle left Automatic mode ({car_state.latest.mode.value}: {car_state.latest.reason})"
                    )
            else:
                left_automatic = 0
            if seconds is not None and now - t_start >= seconds:
                break
            if route.closed and seconds is None and tracker.travelled_m >= target_m:
                break
            if (
                not route.closed
                and statuses.latest is not None
                and statuses.latest.finished
                and truth.latest is not None
                and abs(truth.latest.v) < 0.05
            ):
                break
            if now != clock_moved[0]:
                clock_moved = (now, time.monotonic())
            elif time.monotonic() - clock_moved[1] > CLOCK_STALL_S:
                raise RunFailed(
                    f"the stack clock has not moved for {CLOCK_STALL_S:g} s (the simulator or a process it "
                    "waits for is stuck)"
                )
            held = (
                movement.latest is not None
                and (movement.latest.latched or movement.latest.stopping or movement.latest.limit_mps == 0.0)
            ) or (statuses.latest is not None and statuses.latest.controller == "stop" and seconds is not None)
            # standing where a manager says so is not stuck (a run of given seconds waits with it)
            if tracker.travelled_m > moved[0] + 0.5 or held:
                moved = (tracker.travelled_m, now)
            elif now - moved[1] > STANDSTILL_S:
                why = statuses.latest
                raise RunFailed(
                    f"the shuttle has not moved for {STANDSTILL_S:g} s, at {tracker.travelled_m:.0f} of "
                    f"{target_m:.0f} m"
                    + (f": the control manager forwards {why.controller} ({why.reason})" if why is not None else "")
                )
            if now - t_start > time_limit_s:
                raise RunFailed(
                    f"did not finish within {time_limit_s:.0f} s of vehicle time "
                    f"({tracker.travelled_m:.0f} of {target_m:.0f} m)"
                )
            if now - last_progress >= 30.0:
                last_progress = now
                print(f"[{now - t_start:6.0f} s] {tracker.travelled_m:6.0f} / {target_m:.0f} m", file=sys.stderr)
            time.sleep(0.05)
    except RunFailed as exc:  # what was driven until then, for `ares compare` and the reader
        exc.figures = {
            "route": route.name,
            "vehicle": cfg["vehicle"],
            **tracker.summary(),
            **control.summary(),
            **safety.summary(),
            **scenario.summary(),
        }
        _save_trace(run_dir, tracker, control)
        raise
    lap_time = clock.now() - t_start
    wall_s = time.monotonic() - wall_start
    if seconds is not None and route.closed:
        laps = max(int(tracker.travelled_m // route.length), 1)
    result = {
        "ok": True,
        "laps": laps if route.closed else 0,
        "route": route.name,
        "route_length_m": round(route.length, 2),
        "lap_time_s": round(lap_time / max(laps, 1), 2),
        "total_time_s": round(lap_time, 2),
        **tracker.summary(),
        **localization.summary(),
        **control.summary(),
        **(perception.summary() if perceiving else {}),
        **safety.summary(),
        **scenario.summary(),
        "mission": _mission_summary(mission.latest),
        "speed_factor": round(lap_time / max(wall_s, 1e-9), 2),
        "clock": clock.mode,
        "wall_time_s": round(wall_s, 1),
        "vehicle": cfg["vehicle"],
        "run_dir": str(run_dir),
        "t_start_s": round(t_start, 3),
        "t_end_s": round(t_start + lap_time, 3),
    }  # the drive, stack time
    picture = write_lap_svg(
        run_dir / "lap.svg",
        route,
        np.array(tracker.xs),
        np.array(tracker.ys),
        np.array(tracker.progress),
        np.array(tracker.xte),
        f"{route.name}: {result['distance_m']:.0f} m in {lap_time:.0f} s, {cfg['vehicle']}",
    )
    result["plot"] = str(picture)
    _save_trace(run_dir, tracker, control)
    return result


def _mission_summary(status) -> dict | None:
    if status is None:
        return None
    return {
        "goal_id": status.goal_id,
        "kind": status.kind,
        "state": status.state,
        "poi": status.poi,
        "result": status.result,
    }


def _save_trace(run_dir: Path, tracker: LapTracker, control: ControlTracker) -> None:
    """For `ares compare`: the error along the route and who drove, at the simulator's rate."""
    np.savez_compressed(
        run_dir / "trace.npz",
        progress=np.array(tracker.progress),
        xte=np.array(tracker.xte),
        controller=np.array([c or "none" for c in control.in_charge()]),
    )
