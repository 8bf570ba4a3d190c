"""`ares run`: the whole stack under one supervisor, interactive or headless.

Headless, it engages Automatic mode itself (the Auto/Manual button on the simulated panel,
then the `set_automatic_mode` service, as a safety driver and the navigation system would),
drives N laps of the tour (or an open route to its end; or, with --seconds, for that much
vehicle time), measures the cross-track error of the simulator's ground truth against the
route, and prints one JSON object as its last line, once the stack has stopped: its
`blackbox_records` is read back from the black-box store after the recorder's final flush.

The whole configuration (defaults, `--config` files, the command line's choices) is validated
here before any process is spawned: an error names the file and the key, and `ares run` exits 2.
The black box's store (`blackbox_store.uri`, `--store URI`) is resolved here once: a relative
file path becomes absolute against the working directory, so every process of the run (recorder,
API) finds the same file.

The clock: the wall clock on the vehicle (no simulation), the simulation's clock scaled by
`--speed X`, or with `--speed max` the simulator's own (ares.lockstep), which waits for every
process the simulator feeds; those participants are found here from the topic graph.
"""
from __future__ import annotations

import json
import logging
import os
import signal
import sys
import threading
import time
from pathlib import Path

import numpy as np

from ares import config, contracts, processes, run_config
from ares.bus import Bus, ServiceError
from ares.clock import Clock, DrivenClock, ScaledClock, WallClock
from ares.control_eval import ControlTracker
from ares.fleet import fleet_configs, start_fleet
from ares.messages import DriveMode, DriverCommand
from ares.metrics import LapTracker, LocalizationTracker
from ares.perception_eval import PerceptionTracker
from ares.report import write_lap_svg
from ares.route import Route, RouteError, load_route, read_origin
from ares.safety_eval import SafetyTracker
from ares.scenario_run import ScenarioDriver
from ares.supervisor import Supervisor
from blackbox.api import ApiSettings
from blackbox.api.settings import state_dir
from blackbox.api_server import api_url, pages_url
from blackbox.first_logins import ensure_first_logins
from blackbox.recorder import open_configured_store, store_uri
from blackbox.store import StoreSettings
from managers.speed_profile import SpeedProfileParams, cruise_speed

log = logging.getLogger("ares.run")

STARTUP_TIMEOUT_S = 60.0        # wall seconds for every process to come up and publish
ENGAGE_TIMEOUT_S = 10.0
READY_MAX_AGE_S = 0.5        # stack seconds: the controller's status is this fresh when it is ready
CLOCK_STALL_S = 30.0         # wall seconds without the clock moving: the run has stalled
STANDSTILL_S = 60.0          # stack seconds without progress along the route: the shuttle is stuck


class RunFailed(RuntimeError):
    figures: dict | None = None         # a headless run's figures up to the failure


def overrides_from_args(args) -> dict:
    over: dict = {"sim": {}, "bus": {}, "blackbox_store": {}}
    if getattr(args, "vehicle", None):
        over["vehicle"] = args.vehicle
    if getattr(args, "vehicle_id", None):
        over["vehicle_id"] = args.vehicle_id
    if getattr(args, "passengers", None) is not None:
        over["sim"]["passengers"] = args.passengers
    if getattr(args, "route", None):
        # a built-in tour by name (`--route campus`) or a tour's YAML; anything else is a route CSV
        builtin = config.packaged_file("tours", args.route).exists() and not Path(args.route).exists()
        if builtin or Path(args.route).suffix in (".yaml", ".yml"):
            over["tour"] = args.route if builtin else str(Path(args.route).resolve())
        else:
            over["route_file"] = str(Path(args.route).resolve())
    if getattr(args, "scenario", None):
        over["scenario"] = args.scenario
    if getattr(args, "mission", None):
        over["mission_manager"] = {"autostart": args.mission}
    if getattr(args, "controller", None):
        over["control_manager"] = {"pinned": None if args.controller == "auto" else args.controller}
    if getattr(args, "listen", None):
        over["bus"]["router"] = args.listen
    if getattr(args, "router", None):
        over["bus"]["router"] = args.router
        over["bus"]["embedded_router"] = False
    if getattr(args, "store", None):
        over["blackbox_store"]["uri"] = args.store
    if getattr(args, "api_port", None):
        over["api"] = {"port": args.api_port}
    return over


def default_run_dir() -> Path:
    return Path(os.environ.get("ARES_RUNS_DIR", "runs")) / time.strftime("%Y%m%d-%H%M%S")


def run(args) -> int:
    headless = bool(getattr(args, "headless", False))
    logging.basicConfig(level=os.environ.get("ARES_LOG_LEVEL", "WARNING" if headless else "INFO"),
                        format="%(asctime)s %(name)s %(levelname)s: %(message)s", stream=sys.stderr)
    speed = getattr(args, "speed", None) or 1.0
    try:
        cfg = prepare(tuple(getattr(args, "config", None) or ()), overrides_from_args(args), speed)
        route = load_route(config.core(cfg))
    except (config.ConfigError, RouteError) as exc:
        print(f"ares run: {exc}", file=sys.stderr)
        return 2
    clock = stack_clock(cfg, speed)
    run_dir = Path(args.run_dir) if getattr(args, "run_dir", None) else default_run_dir()
    if (getattr(args, "fleet", None) or 1) > 1:
        return _fleet(args, cfg, route, clock, run_dir)
    if cfg["replay"]["record"] and not cfg["replay"]["dir"]:
        cfg["replay"]["dir"] = str((run_dir / "replay").resolve())
    supervisor = Supervisor(cfg, processes.for_run(cfg["simulate"], cfg["lidars"]), run_dir, clock)
    stop = threading.Event()
    previous = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)}
    supervisor.start()
    loop = threading.Thread(target=supervisor.run, args=(stop,), name="supervisor", daemon=True)
    loop.start()
    try:
        if not headless:
            return _interactive(args, cfg, route, supervisor.bus, clock, stop, run_dir)
        result = _headless(args, cfg, route, supervisor.bus, clock, stop, run_dir, supervisor.inject)
    except RunFailed as exc:
        print(f"ares run: {exc} (logs in {run_dir / 'logs'})", file=sys.stderr)
        if headless:
            print(json.dumps({"ok": False, "error": str(exc), "run_dir": str(run_dir), **(exc.figures or {})}))
        return 1
    finally:
        stop.set()
        loop.join(timeout=5)
        supervisor.stop()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    # the stack has stopped and the recorder flushed what it held: count what the store has
    result["blackbox_records"] = count_blackbox_records(cfg, clock)
    print(json.dumps(result))
    return 0


def prepare(files: tuple[str, ...], overrides: dict, speed: float | str) -> dict:
    """The run configuration, validated; the route file's origin, if it has one; the store made
    absolute; the lockstep's participants."""
    cfg = run_config.build(files, overrides)
    if not config.core(cfg).vehicle_profile.lidars:
        cfg["lidars"] = False           # a vehicle without LiDARs runs no LiDAR process (and no RRC)
    if cfg["route_file"]:
        origin = read_origin(cfg["route_file"])
        if origin is not None:      # a recorded route brings its frame: the configured origin is for the others
            cfg["origin_utm"] = {**origin.model_dump(), "reach_km": cfg["origin_utm"]["reach_km"]}
    if cfg["scenario"]:
        scenario = config.named_file("scenarios", cfg["scenario"])
        loaded = config.load_scenario(str(scenario))  # a bad scenario stops the run here, with its error
        cfg["scenario"] = str(scenario.resolve()) if scenario.suffix else cfg["scenario"]
        # the simulator and its LiDARs stand for the vehicle and its sensors: not theirs to kill
        running = {p.name for p in processes.for_run(cfg["simulate"], cfg["lidars"]) if not p.sim_only}
        unknown = sorted({f.process for f in loaded.faults if f.kind in config.PROCESS_FAULTS} - running)
        if unknown:
            raise config.ConfigError(f"{scenario}: process faults name {', '.join(unknown)}, which this run does not "
                                     f"start (it runs {', '.join(sorted(running))})")
        if loaded.mission is not None and "autostart" not in overrides.get("mission_manager", {}):
            cfg.setdefault("mission_manager", {})["autostart"] = loaded.mission     # --mission still wins
    store = config.section(cfg, "blackbox_store", StoreSettings)
    cfg["blackbox_store"]["uri"] = store_uri(store)
    if speed != 1 and not cfg["simulate"]:
        # on the vehicle the wall clock runs as it is: only a simulated shuttle can be hurried
        raise config.ConfigError(f"--speed {speed} needs the simulator (simulate: true)")
    if speed in ("max", "paced"):
        running = processes.for_run(True, cfg["lidars"])
        cfg["lockstep"]["participants"] = contracts.fed_by(contracts.all_contracts(cfg, running), "sim")
        cfg["lockstep"]["pace"] = 1.0 if speed == "paced" else None
    return cfg


def stack_clock(cfg: dict, speed: float | str) -> Clock:
    if not cfg["simulate"]:
        return WallClock()
    if speed in ("max", "paced"):
        return DrivenClock()
    return ScaledClock(float(speed))


def count_blackbox_records(cfg: dict, clock: Clock) -> int | None:
    """Records stored for the run's vehicle since the run began (None if the store can't say)."""
    try:
        store = open_configured_store(config.section(cfg, "blackbox_store", StoreSettings))
        try:
            # record times are vehicle time (utc of stack t), ahead of the wall clock at --speed > 1
            return store.count_records(cfg["vehicle_id"], clock.utc(0.0), clock.utc(clock.now() + 2.0))
        finally:
            store.close()
    except Exception as exc:        # a report, not a reason to fail the run
        print(f"ares run: could not count the black box's records: {exc}", file=sys.stderr)
        return None


def wait_for(condition, timeout_s: float, what: str, stop: threading.Event) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        if stop.is_set():
            raise RunFailed("interrupted")
        if time.monotonic() > deadline:
            raise RunFailed(f"timed out waiting for {what}")
        time.sleep(0.05)


def wait_until_ready_to_drive(bus: Bus, stop: threading.Event) -> None:
    """Until the control manager forwards a controller's candidate (not a stop): localization, the
    path manager and a controller are up and trusted. Process start-up takes wall seconds, which at --speed X are X times as many
    vehicle seconds: a run engaged before this would count them in its lap time."""
    status = bus.subscribe("control/status")
    try:
        wait_for(lambda: status.alive(READY_MAX_AGE_S) and status.latest.controller != "stop", STARTUP_TIMEOUT_S,
                  "a controller in charge (localization, path manager, a controller and the control manager up)", stop)
    finally:
        bus.unsubscribe(status)


def engage_automatic(bus: Bus, car_state, stop: threading.Event) -> None:
    """When the stack is ready to drive: Manual -> Ready with the panel button, then Ready ->
    Automatic with the service."""
    wait_for(lambda: car_state.latest is not None, STARTUP_TIMEOUT_S, "the drive-by-wire bridge", stop)
    wait_until_ready_to_drive(bus, stop)
    if car_state.latest.mode == DriveMode.MANUAL:
        bus.call("sim/driver", DriverCommand(t=bus.clock.now(), action="BUTTON"))
        wait_for(lambda: car_state.latest.mode == DriveMode.READY, ENGAGE_TIMEOUT_S, "Ready mode", stop)
    deadline = time.monotonic() + ENGAGE_TIMEOUT_S
    while True:
        try:
            reply = bus.call("set_automatic_mode")
            if reply.accepted:
                return
            reason = reply.reason
        except ServiceError as exc:
            reason = str(exc)
        if time.monotonic() > deadline:
            raise RunFailed(f"Automatic mode refused: {reason}")
        time.sleep(0.2)


def _headless(args, cfg, route: Route, bus: Bus, clock: Clock, stop, run_dir: Path, inject) -> dict:
    laps = int(getattr(args, "laps", None) or 1)
    seconds = getattr(args, "seconds", None)   # drive this long (vehicle time) instead of laps
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
    scenario = ScenarioDriver(config.load_scenario(cfg["scenario"]) if cfg["scenario"] else None, bus, inject,
                              safety)
    target_m = laps * route.length if route.closed else route.length
    cruise = cruise_speed(config.section(cfg, "speed_profile", SpeedProfileParams), vehicle, route)
    time_limit_s = 3.0 * target_m / (0.5 * cruise) + 60.0     # stack seconds
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
    feeds = [(bodies, safety.add_body), (movement, safety.add_status), (cars, safety.add_car),
             (awareness, safety.add_awareness), (truth, on_truth)]
    if perceiving:
        feeds += [(worlds, on_world), (roads, perception.add_road), (grids, perception.add_grid),
                  (lidar_status, perception.add_status)]
    feeds += [(poses, lambda pose: localization.add_pose(pose.t, pose.x, pose.y, pose.yaw)),
              (scores, lambda score: localization.add_score(score.t, score.score)),
              (statuses, lambda st: control.add_status(st.t, st.controller)),
              (mpc_candidates, lambda cand: control.add_mpc(cand.solve_ms, cand.fresh)),
              (events, on_event)]
    left_automatic = 0
    last_progress = 0.0
    clock_moved = (clock.now(), time.monotonic())      # a clock that stops moving is a stalled run
    moved = (0.0, clock.now())                         # (travelled m, when): a shuttle that stops moving is stuck
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
                    raise RunFailed(f"the vehicle left Automatic mode ({car_state.latest.mode.value}: "
                                    f"{car_state.latest.reason})")
            else:
                left_automatic = 0
            if seconds is not None and now - t_start >= seconds:
                break
            if route.closed and seconds is None and tracker.travelled_m >= target_m:
                break
            if not route.closed and statuses.latest is not None and statuses.latest.finished \
                    and truth.latest is not None and abs(truth.latest.v) < 0.05:
                break
            if now != clock_moved[0]:
                clock_moved = (now, time.monotonic())
            elif time.monotonic() - clock_moved[1] > CLOCK_STALL_S:
                raise RunFailed(f"the stack clock has not moved for {CLOCK_STALL_S:g} s (the simulator or a process it "
                                "waits for is stuck)")
            held = (movement.latest is not None and (movement.latest.latched or movement.latest.stopping
                                                     or movement.latest.limit_mps == 0.0)) or \
                (statuses.latest is not None and statuses.latest.controller == "stop" and seconds is not None)
            # standing where a manager says so is not stuck (a run of given seconds waits with it)
            if tracker.travelled_m > moved[0] + 0.5 or held:
                moved = (tracker.travelled_m, now)
            elif now - moved[1] > STANDSTILL_S:
                why = statuses.latest
                raise RunFailed(f"the shuttle has not moved for {STANDSTILL_S:g} s, at {tracker.travelled_m:.0f} of "
                                f"{target_m:.0f} m" + (f": the control manager forwards {why.controller} ({why.reason})"
                                                       if why is not None else ""))
            if now - t_start > time_limit_s:
                raise RunFailed(f"did not finish within {time_limit_s:.0f} s of vehicle time "
                                f"({tracker.travelled_m:.0f} of {target_m:.0f} m)")
            if now - last_progress >= 30.0:
                last_progress = now
                print(f"[{now - t_start:6.0f} s] {tracker.travelled_m:6.0f} / {target_m:.0f} m", file=sys.stderr)
            time.sleep(0.05)
    except RunFailed as exc:     # what was driven until then, for `ares compare` and the reader
        exc.figures = {"route": route.name, "vehicle": cfg["vehicle"], **tracker.summary(), **control.summary(),
                       **safety.summary(), **scenario.summary()}
        _save_trace(run_dir, tracker, control)
        raise
    lap_time = clock.now() - t_start
    wall_s = time.monotonic() - wall_start
    if seconds is not None and route.closed:
        laps = max(int(tracker.travelled_m // route.length), 1)
    result = {"ok": True, "laps": laps if route.closed else 0, "route": route.name,
              "route_length_m": round(route.length, 2), "lap_time_s": round(lap_time / max(laps, 1), 2),
              "total_time_s": round(lap_time, 2), **tracker.summary(), **localization.summary(),
              **control.summary(), **(perception.summary() if perceiving else {}),
              **safety.summary(), **scenario.summary(),
              "mission": _mission_summary(mission.latest),
              "speed_factor": round(lap_time / max(wall_s, 1e-9), 2), "clock": clock.mode,
              "wall_time_s": round(wall_s, 1),
              "vehicle": cfg["vehicle"], "run_dir": str(run_dir),
              "t_start_s": round(t_start, 3), "t_end_s": round(t_start + lap_time, 3)}   # the drive, stack time
    picture = write_lap_svg(run_dir / "lap.svg", route, np.array(tracker.xs), np.array(tracker.ys),
                            np.array(tracker.progress), np.array(tracker.xte),
                            f"{route.name}: {result['distance_m']:.0f} m in {lap_time:.0f} s, {cfg['vehicle']}")
    result["plot"] = str(picture)
    _save_trace(run_dir, tracker, control)
    return result


def _mission_summary(status) -> dict | None:
    if status is None:
        return None
    return {"goal_id": status.goal_id, "kind": status.kind, "state": status.state, "poi": status.poi,
            "result": status.result}


def _save_trace(run_dir: Path, tracker: LapTracker, control: ControlTracker) -> None:
    """For `ares compare`: the error along the route and who drove, at the simulator's rate."""
    np.savez_compressed(run_dir / "trace.npz", progress=np.array(tracker.progress), xte=np.array(tracker.xte),
                        controller=np.array([c or "none" for c in control.in_charge()]))


def _fleet(args, cfg: dict, route: Route, clock: Clock, run_dir: Path) -> int:
    """`--fleet N`: N shuttles on one router (ares/fleet.py), each engaged, until Ctrl-C."""
    if headless_or_max(args):
        print("ares run: --fleet runs interactively at real or scaled time (not --headless, not --speed max|paced)",
              file=sys.stderr)
        return 2
    try:
        cfgs = fleet_configs(cfg, args.fleet, route.length)
    except config.ConfigError as exc:
        print(f"ares run: {exc}", file=sys.stderr)
        return 2
    stop = threading.Event()
    previous = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)}
    supervisors: list = []
    try:
        start_fleet(cfgs, clock, run_dir, stop, started=supervisors)
        print(f"ARES fleet: {len(cfgs)} shuttles on '{route.name}' ({route.length:.0f} m), router "
              f"{cfg['bus']['router']}.\n" + "".join(
                  f"  {c['vehicle_id']:<10} {pages_url(c)}/operator   logs {run_dir / c['vehicle_id'] / 'logs'}\n"
                  for c in cfgs) +
              f"  fleet     {pages_url(cfgs[0])}/fleet  (any of the APIs serves the whole fleet)\n{first_logins(cfg)}"
              "Ctrl-C stops everything.", flush=True)
        views = [(c["vehicle_id"], sup.bus.subscribe("sim/truth"), sup.bus.subscribe("dbw/car_state"))
                 for c, sup in zip(cfgs, supervisors)]
        if not getattr(args, "manual", False):
            for (vehicle_id, truth, car), sup in zip(views, supervisors):
                wait_for(lambda: truth.latest is not None, STARTUP_TIMEOUT_S, f"the simulator of {vehicle_id}", stop)
                engage_automatic(sup.bus, car, stop)
            print("Automatic mode engaged on every shuttle.", flush=True)
        while not stop.wait(2.0):
            print("  ".join(f"{vid} s={t.latest.s:6.0f} m v={t.latest.v:4.2f}" for vid, t, _ in views
                            if t.latest is not None), flush=True)
        return 0
    except RunFailed as exc:
        print(f"ares run: {exc} (logs in {run_dir})", file=sys.stderr)
        return 1
    finally:
        stop.set()
        for sup in reversed(supervisors):       # the router's host last
            sup.stop()
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def headless_or_max(args) -> bool:
    return bool(getattr(args, "headless", False)) or getattr(args, "speed", 1.0) in ("max", "paced")


def first_logins(cfg: dict) -> str:
    """The pages' logins, for the banner: made on a black box without users (blackbox/first_logins.py)."""
    settings = config.section(cfg, "api", ApiSettings)
    try:
        store = open_configured_store(config.section(cfg, "blackbox_store", StoreSettings))
    except Exception as exc:        # the store's own process will say more
        return f"  logins    (the black box store cannot be opened: {exc})\n"
    try:
        made = ensure_first_logins(store, settings.auth, state_dir(settings, store))
    finally:
        store.close()
    if made is None:
        return "  logins    the black box's users (`ares users list`; `ares users add NAME --role operator`)\n"
    users = "".join(f"            {line}\n" for line in made.read_text().splitlines() if not line.startswith("#"))
    return f"  logins    first users made (also in {made}):\n{users}"


def _interactive(args, cfg, route: Route, bus: Bus, clock: Clock, stop, run_dir: Path) -> int:
    truth = bus.subscribe("sim/truth")
    car_state = bus.subscribe("dbw/car_state")
    mission = bus.subscribe("mission/status")
    paced = cfg["lockstep"].get("pace")
    pace = (f"in lockstep, at most {paced:g}x real time" if paced else "as fast as every process keeps up") \
        if clock.mode == "driven" else f"speed x{clock.speed:g}"
    print(f"ARES is running: vehicle {cfg['vehicle_id']} ({cfg['vehicle']}) on '{route.name}' "
          f"({route.length:.0f} m), {pace}.\n"
          f"  router    {cfg['bus']['router']}\n"
          f"  api       {api_url(cfg)}  (black box REST API; store {cfg['blackbox_store']['uri']})\n"
          f"  pages     {pages_url(cfg)}/operator  /blackbox  /fleet  (self-signed certificate: accept it once)\n"
          f"{first_logins(cfg)}"
          f"  logs      {run_dir / 'logs'}\n"
          f"  look      ares topics | ares echo dbw/car_state | ares mission status\n"
          f"Ctrl-C stops everything.", flush=True)
    if not getattr(args, "manual", False):
        wait_for(lambda: truth.latest is not None, STARTUP_TIMEOUT_S, "the simulator", stop)
        engage_automatic(bus, car_state, stop)
        print("Automatic mode engaged: the shuttle is driving the tour.", flush=True)
    while not stop.wait(1.0):
        t, c = truth.latest, car_state.latest
        if t is not None and c is not None:
            m = mission.latest
            doing = "" if m is None else f"  mission {m.state}" + (f" {m.poi}" if m.poi else "") + \
                (f" {m.action}" if m.action else "")
            print(f"t={clock.now():7.1f}s  lap {t.lap}  s={t.s:7.1f} m  v={t.v:4.2f} m/s  "
                  f"mode={c.mode.value}{' (watchdog)' if c.watchdog_tripped else ''}{doing}", flush=True)
    return 0
