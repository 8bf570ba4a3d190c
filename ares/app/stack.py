"""`ares run`: the whole stack under one supervisor, interactive or headless, as a function:
`run(RunOptions) -> RunResult` (ares.app.run_options). The command line, the benches, the soak
and `ares compare` call it.

Interactive, it engages Automatic mode (the Auto/Manual button on the simulated panel, then the
`set_automatic_mode` service, as a safety driver and the navigation system would) and prints the
vehicle's state every second until Ctrl-C. Headless, a drive is given the running stack and
returns its figures (ares.app.headless.drive by default); the result carries them, and once the
stack has stopped, the count of the black box's records, read back from its store after the
recorder's final flush.

The whole configuration (defaults, the options' files and choices) is validated here before any
process is spawned: an error names the file and the key, and the run is refused (`ares run`
exits 2). The black box's store (`blackbox_store.uri`, `--store URI`) is resolved here once: a
relative file path becomes absolute against the working directory, so every process of the run
(recorder, API) finds the same file.

The clock: the wall clock on the vehicle (no simulation); in simulation, unless the options say
otherwise, the simulator's own paced at real time (`paced`, ares.core.lockstep: it waits for every
process the simulator feeds, whose participants are found here from the topic graph), or with
`max` as fast as they all keep up, or the simulation's clock scaled by a factor.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path

from ares.app import contracts, headless, processes, run_config, vehicle_io
from ares.app.bus_record import in_run as bus_record
from ares.app.engagement import STARTUP_TIMEOUT_S, RunFailed, engage_automatic, wait_for
from ares.app.fleet import fleet_configs, start_fleet
from ares.app.run_options import LOCKSTEP_SPEEDS, HeadlessDrive, RunningStack, RunOptions, RunResult, Speed
from ares.app.supervisor import Supervisor, check_cpus
from ares.core import config
from ares.core.clock import MODE_ENV, Clock, DrivenClock, ScaledClock, WallClock
from ares.core.manifest import ReleaseRefused, ReleaseSettings, check_release
from ares.core.route import Route, RouteError, load_route, read_origin
from blackbox.api import ApiSettings
from blackbox.api.api_node import api_url, pages_url
from blackbox.api.first_logins import FIRST_USERS, ensure_first_logins
from blackbox.api.settings import state_dir
from blackbox.register.recorder import open_configured_store, store_uri
from blackbox.register.store.record_store import StoreSettings
from simulator.scenario import PROCESS_FAULTS, load_scenario, scenario_file

log = logging.getLogger("ares.run")


def default_run_dir() -> Path:
    return Path(os.environ.get("ARES_RUNS_DIR", "runs")) / time.strftime("%Y%m%d-%H%M%S")


def resolved_speed(speed: Speed | None, simulate: bool, fleet: int = 1) -> Speed:
    """The clock of a run that does not choose one. In simulation the lockstep paced at real time:
    a machine too small for the stack then runs it slower, where on timers of their own
    (`--speed 1`, 2 cores) the simulated LiDARs fell below the rate the awareness manager expects
    and it latched an emergency stop before the shuttle left the depot. A fleet's shuttles share
    one clock, which no one simulator can drive: the wall's. On the vehicle, the wall clock."""
    if speed is not None:
        return speed
    return "paced" if simulate and fleet == 1 else 1.0


def configure(options: RunOptions, wire_dir: Path | None = None) -> dict:
    """The run configuration `options` make, validated (config.ConfigError)."""
    return prepare(options.config_files, options.overrides(), options.speed, wire_dir, fleet=options.fleet)


def run(options: RunOptions, drive: HeadlessDrive | None = None) -> RunResult:
    """The whole stack under one supervisor as `options` say: interactive until Ctrl-C, or headless
    until its drive is done (`drive`, for a headless run only; default ares.app.headless.drive)."""
    if drive is not None and not options.headless:
        raise ValueError("a drive is for a headless run (RunOptions(headless=True))")
    logging.basicConfig(
        level=os.environ.get("ARES_LOG_LEVEL", "WARNING" if options.headless else "INFO"),
        format="%(asctime)s %(name)s %(levelname)s: %(message)s",
        stream=sys.stderr,
    )
    run_dir = options.run_dir or default_run_dir()
    try:
        cfg = configure(options, wire_dir=run_dir / "wire")
        route = load_route(config.core(cfg))
        # ARES §3.8.3: a stack that is not the signed release does not start
        check_release(config.section(cfg, "release", ReleaseSettings))
    except (config.ConfigError, RouteError, ReleaseRefused) as exc:
        return RunResult(ok=False, run_dir=run_dir, error=str(exc), refused=True)
    speed = resolved_speed(options.speed, cfg["simulate"], options.fleet)
    clock = stack_clock(cfg, speed)
    if options.fleet > 1:
        return _fleet(options, speed, cfg, route, clock, run_dir)
    if options.headless and drive is None:
        drive = headless.drive
    if cfg["replay"]["record"] and not cfg["replay"]["dir"]:
        cfg["replay"]["dir"] = str((run_dir / "replay").resolve())
    try:
        supervisor = Supervisor(cfg, processes.for_config(cfg), run_dir, clock)
    except RuntimeError as exc:  # its router's port taken: no process started
        return RunResult(ok=False, run_dir=run_dir, error=str(exc), refused=True)
    # --record, --foxglove: on the supervisor's session, before any process speaks
    try:
        taps = bus_record.start(options.record, options.foxglove, cfg, supervisor.bus, clock, run_dir, route)
    except (RuntimeError, OSError) as exc:
        supervisor.stop()
        return RunResult(ok=False, run_dir=run_dir, error=str(exc), refused=True)
    return _supervised(RunningStack(options, cfg, route, supervisor, clock, threading.Event(), run_dir), taps, drive)


def _supervised(running: RunningStack, taps: bus_record.RunTaps, drive: HeadlessDrive | None) -> RunResult:
    """The processes started, the drive (or the interactive loop) until it is done or stopped, every
    process stopped; how the run ended."""
    supervisor, stop, run_dir = running.supervisor, running.stop, running.run_dir
    failure: RunFailed | None = None
    figures: dict = {}
    # the recorder's last word comes at its teardown, before the supervisor closes its bus
    blackbox_status = supervisor.bus.subscribe("blackbox/status")
    with stop_on_signals(stop):
        supervisor.start()
        loop = threading.Thread(target=supervisor.run, args=(stop,), name="supervisor", daemon=True)
        loop.start()
        try:
            if drive is None:
                _interactive(running)
            else:
                figures = drive(running)
        except RunFailed as exc:
            failure = exc
        finally:
            interrupted = stop.is_set()  # by a signal: nothing else sets it before this
            stop.set()
            loop.join(timeout=5)
            supervisor.stop()
            recording = taps.close()
    logs = run_dir / "logs"
    if failure is not None:
        return RunResult(
            ok=False,
            run_dir=run_dir,
            error=str(failure),
            interrupted=interrupted,
            logs=logs,
            figures=failure.figures or {},
        )
    # the stack has stopped and the recorder flushed what it held: count what the store has
    in_store = count_blackbox_records(running.cfg, running.clock) if drive is not None else None
    last = blackbox_status.latest
    return RunResult(
        ok=True,
        run_dir=run_dir,
        interrupted=interrupted,
        logs=logs,
        figures=figures,
        blackbox_records=in_store,
        blackbox=None if drive is None else {**(last.model_dump(exclude={"t"}) if last else {}), "in_store": in_store},
        recording=recording or None,
    )


@contextlib.contextmanager
def stop_on_signals(stop: threading.Event) -> Iterator[None]:
    """SIGINT and SIGTERM set `stop` while the run lasts. Only the main thread may take signals: a
    run started on another one is stopped by its drive (or its process's end)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def prepare(
    files: tuple[str, ...],
    overrides: dict,
    speed: Speed | None = None,
    wire_dir: Path | None = None,
    fleet: int = 1,
) -> dict:
    """The run configuration, validated; the route file's origin, if it has one; the store made
    absolute; the simulator's wires (--wire) or the vehicle's devices checked (simulate: false);
    the lockstep's participants (`speed` None: resolved_speed's)."""
    cfg = run_config.build(files, overrides)
    speed = resolved_speed(speed, cfg["simulate"], fleet)
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
    if speed in LOCKSTEP_SPEEDS:
        running = processes.for_config(cfg)
        cfg["lockstep"]["participants"] = contracts.fed_by(contracts.all_contracts(cfg, running), "sim")
        cfg["lockstep"]["pace"] = 1.0 if speed == "paced" else None
    return cfg


def stack_clock(cfg: dict, speed: Speed) -> Clock:
    if not cfg["simulate"]:
        # the vehicle's wall clock; given in the environment (ARES_CLOCK_MODE=wall and its epoch), one
        # shared with another process of this machine: `ares sim serve`'s clock.env
        return Clock.from_env() if os.environ.get(MODE_ENV) == "wall" else WallClock()
    if speed in LOCKSTEP_SPEEDS:
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


def _fleet(options: RunOptions, speed: Speed, cfg: dict, route: Route, clock: Clock, run_dir: Path) -> RunResult:
    """`--fleet N`: N shuttles on one router (ares/app/fleet.py), each engaged, until Ctrl-C."""
    if options.headless or speed in LOCKSTEP_SPEEDS:
        return RunResult(
            ok=False,
            run_dir=run_dir,
            error="--fleet runs interactively at real or scaled time (not --headless, not --speed max|paced)",
            refused=True,
        )
    try:
        cfgs = fleet_configs(cfg, options.fleet, route.length)
    except config.ConfigError as exc:
        return RunResult(ok=False, run_dir=run_dir, error=str(exc), refused=True)
    stop = threading.Event()
    supervisors: list = []
    with stop_on_signals(stop):
        try:
            start_fleet(cfgs, clock, run_dir, stop, started=supervisors)
            _drive_fleet(options, cfg, cfgs, supervisors, route, run_dir, stop)
        except RunFailed as exc:
            return RunResult(ok=False, run_dir=run_dir, error=str(exc), logs=run_dir)
        finally:
            stop.set()
            for sup in reversed(supervisors):  # the router's host last
                sup.stop()
    return RunResult(ok=True, run_dir=run_dir, logs=run_dir)


def _drive_fleet(
    options: RunOptions, cfg: dict, cfgs: list[dict], supervisors: list, route: Route, run_dir: Path, stop
) -> None:
    """The fleet's banner, each shuttle engaged (unless --manual), where each is every 2 s until `stop`."""
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
    if not options.manual:
        for (vehicle_id, truth, car), sup in zip(views, supervisors):
            wait_for(lambda t=truth: t.latest is not None, STARTUP_TIMEOUT_S, f"the simulator of {vehicle_id}", stop)
            engage_automatic(sup.bus, car, stop)
        print("Automatic mode engaged on every shuttle.", flush=True)
    while not stop.wait(2.0):
        print(
            "  ".join(
                f"{vid} s={t.latest.s:6.0f} m v={t.latest.v:4.2f}" for vid, t, _ in views if t.latest is not None
            ),
            flush=True,
        )


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
    # where the passwords are, never the passwords: a banner ends up in logs
    return f"  logins    first users made ({', '.join(FIRST_USERS)}): their passwords are in {made} (owner only)\n"


def _interactive(running: RunningStack) -> None:
    """The banner, Automatic engaged (unless --manual), the vehicle's state every second until `stop`."""
    cfg, route, bus, clock, stop = running.cfg, running.route, running.bus, running.clock, running.stop
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
        f"  logs      {running.run_dir / 'logs'}\n"
        f"  look      ares topics | ares echo dbw/car_state | ares mission status\n"
        f"Ctrl-C stops everything.",
        flush=True,
    )
    if not running.options.manual:
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
