"""`ares run`: the whole stack under one supervisor, interactive or headless.

Interactive, it engages Automatic mode (the Auto/Manual button on the simulated panel, then the
`set_automatic_mode` service, as a safety driver and the navigation system would) and prints the
vehicle's state every second until Ctrl-C. Headless, the drive and its figures are
ares.app.headless's (the CLI passes its `drive` in); this module prints them as one JSON object,
the last line, once the stack has stopped: its `blackbox_records` is read back from the black-box
store after the recorder's final flush.

The whole configuration (defaults, `--config` files, the command line's choices) is validated
here before any process is spawned: an error names the file and the key, and `ares run` exits 2.
The black box's store (`blackbox_store.uri`, `--store URI`) is resolved here once: a relative
file path becomes absolute against the working directory, so every process of the run (recorder,
API) finds the same file.

The clock: the wall clock on the vehicle (no simulation), the simulation's clock scaled by
`--speed X`, or with `--speed max` the simulator's own (ares.core.lockstep), which waits for every
process the simulator feeds; those participants are found here from the topic graph.
"""

from __future__ import annotations

import json
import logging
import os
import signal
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path

from ares.app import contracts, processes, run_config, vehicle_io
from ares.app.bus_record import in_run as bus_record
from ares.app.fleet import fleet_configs, start_fleet
from ares.app.supervisor import Supervisor, check_cpus
from ares.core import affinity, config
from ares.core.bus import Bus, ServiceError
from ares.core.clock import MODE_ENV, Clock, DrivenClock, ScaledClock, WallClock
from ares.core.messages import DriveMode, DriverCommand
from ares.core.route import Route, RouteError, load_route, read_origin
from blackbox.api import ApiSettings
from blackbox.api.api_node import api_url, pages_url
from blackbox.api.first_logins import ensure_first_logins
from blackbox.api.settings import state_dir
from blackbox.register.recorder import open_configured_store, store_uri
from blackbox.register.store.record_store import StoreSettings
from simulator.scenario import PROCESS_FAULTS, load_scenario, scenario_file

log = logging.getLogger("ares.run")

STARTUP_TIMEOUT_S = 60.0  # wall seconds for every process to come up and publish
ENGAGE_TIMEOUT_S = 10.0
READY_MAX_AGE_S = 0.5  # stack seconds: the controller's status is this fresh when it is ready


# a headless drive: (args, cfg, route, bus, clock, stop, run_dir, inject) -> its figures
HeadlessDrive = Callable[..., dict]


class RunFailed(RuntimeError):
    figures: dict | None = None  # a headless run's figures up to the failure


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
    if getattr(args, "wire", False):
        over["wire"] = True
    if getattr(args, "vehicle_io", None):
        over["vehicle_io"] = vehicle_io.load(args.vehicle_io)
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
    if getattr(args, "vehicle_cpus", None):
        rest = sorted(affinity.available() - set(args.vehicle_cpus)) or None  # one CPU: all share it
        over["cpus"] = {"vehicle": args.vehicle_cpus, "simulator": rest, "host": rest}
    if getattr(args, "api_port", None):
        over["api"] = {"port": args.api_port}
    return over


def default_run_dir() -> Path:
    return Path(os.environ.get("ARES_RUNS_DIR", "runs")) / time.strftime("%Y%m%d-%H%M%S")


def run(args, headless_drive: HeadlessDrive | None = None) -> int:
    """`ares run`: the whole stack under one supervisor until Ctrl-C, or, given `headless_drive`
    (ares.app.headless.drive, for `--headless`), until that drive is done; its figures are
    printed as one JSON line."""
    headless = headless_drive is not None
    logging.basicConfig(
        level=os.environ.get("ARES_LOG_LEVEL", "WARNING" if headless else "INFO"),
        format="%(asctime)s %(name)s %(levelname)s: %(message)s",
        stream=sys.stderr,
    )
    speed = getattr(args, "speed", None) or 1.0
    run_dir = Path(args.run_dir) if getattr(args, "run_dir", None) else default_run_dir()
    try:
        overrides = overrides_from_args(args)
        cfg = prepare(tuple(getattr(args, "config", None) or ()), overrides, speed, wire_dir=run_dir / "wire")
        route = load_route(config.core(cfg))
    except (config.ConfigError, RouteError) as exc:
        print(f"ares run: {exc}", file=sys.stderr)
        return 2
    clock = stack_clock(cfg, speed)
    if (getattr(args, "fleet", None) or 1) > 1:
        return _fleet(args, cfg, route, clock, run_dir)
    if cfg["replay"]["record"] and not cfg["replay"]["dir"]:
        cfg["replay"]["dir"] = str((run_dir / "replay").resolve())
    supervisor = Supervisor(cfg, processes.for_config(cfg), run_dir, clock)
    # --record, --foxglove: on the supervisor's session, before any process speaks
    try:
        taps = bus_record.start(args, cfg, supervisor.bus, clock, run_dir, route)
    except (RuntimeError, OSError) as exc:
        supervisor.stop()
        print(f"ares run: {exc}", file=sys.stderr)
        return 2
    stop = threading.Event()
    previous = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)}
    supervisor.start()
    loop = threading.Thread(target=supervisor.run, args=(stop,), name="supervisor", daemon=True)
    loop.start()
    try:
        if not headless:
            return _interactive(args, cfg, route, supervisor.bus, clock, stop, run_dir)
        result = headless_drive(args, cfg, route, supervisor.bus, clock, stop, run_dir, supervisor.inject)
    except RunFailed as exc:
        print(f"ares run: {exc} (logs in {run_dir / 'logs'})", file=sys.stderr)
        if headless:
            print(json.dumps({"ok": False, "error": str(exc), "run_dir": str(run_dir), **(exc.figures or {})}))
        return 1
    finally:
        stop.set()
        loop.join(timeout=5)
        supervisor.stop()
        recording = taps.close()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    # the stack has stopped and the recorder flushed what it held: count what the store has
    result["blackbox_records"] = count_blackbox_records(cfg, clock)
    if recording:
        result["recording"] = recording
    print(json.dumps(result))
    return 0


def prepare(files: tuple[str, ...], overrides: dict, speed: float | str, wire_dir: Path | None = None) -> dict:
    """The run configuration, validated; the route file's origin, if it has one; the store made
    absolute; the simulator's wires (--wire) or the vehicle's devices checked (simulate: false);
    the lockstep's participants."""
    cfg = run_config.build(files, overrides)
    if speed != 1 and not cfg["simulate"]:
        # on the vehicle the wall clock runs as it is: only a simulated shuttle can be hurried
        raise config.ConfigError(f"--speed {speed} needs the simulator (simulate: true)")
    if cfg["wire"]:
        if not cfg["simulate"]:
            raise config.ConfigError("--wire puts the simulator behind the devices' wires: it needs simulate: true")
        cfg["vehicle_io"] = vehicle_io.simulator_wires(cfg, wire_dir or Path(tempfile.mkdtemp(prefix="ares-wire-")))
    elif not cfg["simulate"]:
        missing = vehicle_io.missing_inputs(cfg)
        if missing:
            raise config.ConfigError(
                "simulate: false, but no driver reads a device for these inputs: "
                + "; ".join(missing)
                + ". Describe the vehicle's devices with --vehicle-io FILE (see docs/vehicle_io.md)"
            )
    if not config.core(cfg).vehicle_profile.lidars:
        cfg["lidars"] = False  # a vehicle without LiDARs runs no LiDAR process (and no RRC)
    if cfg["route_file"]:
        origin = read_origin(cfg["route_file"])
        if origin is not None:  # a recorded route brings its frame: the configured origin is for the others
            cfg["origin_utm"] = {**origin.model_dump(), "reach_km": cfg["origin_utm"]["reach_km"]}
    if cfg["scenario"]:
        scenario = scenario_file(cfg["scenario"])
        loaded = load_scenario(str(scenario))  # a bad scenario stops the run here, with its error
        cfg["scenario"] = str(scenario.resolve()) if scenario.suffix else cfg["scenario"]
        # the simulator and its LiDARs stand for the vehicle and its sensors: not theirs to kill
        running = {p.name for p in processes.for_config(cfg) if not p.sim_only}
        unknown = sorted({f.process for f in loaded.faults if f.kind in PROCESS_FAULTS} - running)
        if unknown:
            raise config.ConfigError(
                f"{scenario}: process faults name {', '.join(unknown)}, which this run does not "
                f"start (it runs {', '.join(sorted(running))})"
            )
        if loaded.mission is not None and "autostart" not in overrides.get("mission_manager", {}):
            cfg.setdefault("mission_manager", {})["autostart"] = loaded.mission  # --mission still wins
    store = config.section(cfg, "blackbox_store", StoreSettings)
    cfg["blackbox_store"]["uri"] = store_uri(store)
    check_cpus(config.core(cfg).cpus)
    if speed in ("max", "paced"):
        running = processes.for_config(cfg)
        cfg["lockstep"]["participants"] = contracts.fed_by(contracts.all_contracts(cfg, running), "sim")
        cfg["lockstep"]["pace"] = 1.0 if speed == "paced" else None
    return cfg


def stack_clock(cfg: dict, speed: float | str) -> Clock:
    if not cfg["simulate"]:
        # the vehicle's wall clock; given in the environment (ARES_CLOCK_MODE=wall and its epoch), one
        # shared with another process of this machine: `ares sim serve`'s clock.env
        return Clock.from_env() if os.environ.get(MODE_ENV) == "wall" else WallClock()
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
    except Exception as exc:  # a report, not a reason to fail the run
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
    path manager and a controller are up and trusted. Process start-up takes wall seconds, which
    at --speed X are X times as many vehicle seconds: a run engaged before this would count them
    in its lap time."""
    status = bus.subscribe("control/status")
    try:
        wait_for(
            lambda: status.alive(READY_MAX_AGE_S) and status.latest.controller != "stop",
            STARTUP_TIMEOUT_S,
            "a controller in charge (localization, path manager, a controller and the control manager up)",
            stop,
        )
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


def _fleet(args, cfg: dict, route: Route, clock: Clock, run_dir: Path) -> int:
    """`--fleet N`: N shuttles on one router (ares/app/fleet.py), each engaged, until Ctrl-C."""
    if headless_or_max(args):
        print(
            "ares run: --fleet runs interactively at real or scaled time (not --headless, not --speed max|paced)",
            file=sys.stderr,
        )
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
        print(
            f"ARES fleet: {len(cfgs)} shuttles on '{route.name}' ({route.length:.0f} m), router "
            f"{cfg['bus']['router']}.\n"
            + "".join(
                f"  {c['vehicle_id']:<10} {pages_url(c)}/operator   logs {run_dir / c['vehicle_id'] / 'logs'}\n"
                for c in cfgs
            )
            + f"  fleet     {pages_url(cfgs[0])}/fleet  (any of the APIs serves the whole fleet)\n{first_logins(cfg)}"
            "Ctrl-C stops everything.",
            flush=True,
        )
        views = [
            (c["vehicle_id"], sup.bus.subscribe("sim/truth"), sup.bus.subscribe("dbw/car_state"))
            for c, sup in zip(cfgs, supervisors)
        ]
        if not getattr(args, "manual", False):
            for (vehicle_id, truth, car), sup in zip(views, supervisors):
                wait_for(
                    lambda t=truth: t.latest is not None, STARTUP_TIMEOUT_S, f"the simulator of {vehicle_id}", stop
                )
                engage_automatic(sup.bus, car, stop)
            print("Automatic mode engaged on every shuttle.", flush=True)
        while not stop.wait(2.0):
            print(
                "  ".join(
                    f"{vid} s={t.latest.s:6.0f} m v={t.latest.v:4.2f}" for vid, t, _ in views if t.latest is not None
                ),
                flush=True,
            )
        return 0
    except RunFailed as exc:
        print(f"ares run: {exc} (logs in {run_dir})", file=sys.stderr)
        return 1
    finally:
        stop.set()
        for sup in reversed(supervisors):  # the router's host last
            sup.stop()
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def headless_or_max(args) -> bool:
    return bool(getattr(args, "headless", False)) or getattr(args, "speed", 1.0) in ("max", "paced")


def first_logins(cfg: dict) -> str:
    """The pages' logins, for the banner: made on a black box without users (blackbox/api/first_logins.py)."""
    settings = config.section(cfg, "api", ApiSettings)
    try:
        store = open_configured_store(config.section(cfg, "blackbox_store", StoreSettings))
    except Exception as exc:  # the store's own process will say more
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
    pace = (
        (f"in lockstep, at most {paced:g}x real time" if paced else "as fast as every process keeps up")
        if clock.mode == "driven"
        else f"speed x{clock.speed:g}"
    )
    print(
        f"ARES is running: vehicle {cfg['vehicle_id']} ({cfg['vehicle']}) on '{route.name}' "
        f"({route.length:.0f} m), {pace}.\n"
        f"  router    {cfg['bus']['router']}\n"
        f"  api       {api_url(cfg)}  (black box REST API; store {cfg['blackbox_store']['uri']})\n"
        f"  pages     {pages_url(cfg)}/operator  /blackbox  /fleet  (self-signed certificate: accept it once)\n"
        f"{first_logins(cfg)}"
        f"  logs      {run_dir / 'logs'}\n"
        f"  look      ares topics | ares echo dbw/car_state | ares mission status\n"
        f"Ctrl-C stops everything.",
        flush=True,
    )
    if not getattr(args, "manual", False):
        wait_for(lambda: truth.latest is not None, STARTUP_TIMEOUT_S, "the simulator", stop)
        engage_automatic(bus, car_state, stop)
        print("Automatic mode engaged: the shuttle is driving the tour.", flush=True)
    while not stop.wait(1.0):
        t, c = truth.latest, car_state.latest
        if t is not None and c is not None:
            m = mission.latest
            doing = (
                ""
                if m is None
                else f"  mission {m.state}" + (f" {m.poi}" if m.poi else "") + (f" {m.action}" if m.action else "")
            )
            print(
                f"t={clock.now():7.1f}s  lap {t.lap}  s={t.s:7.1f} m  v={t.v:4.2f} m/s  "
                f"mode={c.mode.value}{' (watchdog)' if c.watchdog_tripped else ''}{doing}",
                flush=True,
            )
    return 0
