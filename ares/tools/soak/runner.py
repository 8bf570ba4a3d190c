"""`ares soak`: the whole stack at --speed max on the tour, faults injected from a seeded plan.

The run: the plan (ares.tools.soak.plan) is drawn from the seed; its obstacles go into a scenario
file of the soak's own (they appear ahead of the shuttle at their stack time); the soak starts its
own Zenoh router process (a fault restarts it) and the stack under one supervisor, with
ARES_FAULT_INJECTION=1 so that its processes take the busy-loop fault; it engages Automatic mode
and, from `lead_s` of stack time on, injects each fault at its time (ares.tools.soak.injectors),
measuring what the stack does (ares.tools.soak.measure, and the safety evaluation's collisions and
invariants). As the operator and safety driver would, it re-arms a latched emergency stop once its
cause has cleared and engages Automatic again if the shuttle fell back to Manual; both are counted.

Everything goes to the soak's directory as it happens, so that a soak stopped early (or still
running) can be summarised (`ares soak --summarise DIR`):
  plan.json       the plan
  faults.jsonl    one line per fault once it has recovered (the rest at the end)
  timeline.csv    t, v, awareness level, once per stack second
  progress.json   the running totals, rewritten every 30 s of wall time
  soak.json       the figures, at the end (also the last line on stdout with --json)
  soak.png        the picture: the faults on a time line with the speed and the awareness level
  blackbox.sqlite the black box's store, from which the seconds lost are counted
"""

from __future__ import annotations

import json
import os
import signal
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import yaml

from ares.app import processes
from ares.app.evaluation.safety_eval import SafetyTracker
from ares.app.stack import (
    STARTUP_TIMEOUT_S,
    RunFailed,
    engage_automatic,
    overrides_from_args,
    prepare,
    stack_clock,
    wait_for,
)
from ares.app.supervisor import Supervisor
from ares.core import config
from ares.core.bus import ServiceError
from ares.core.launch import FAULT_INJECTION_ENV
from ares.core.messages import DriveMode, MissionGoal, ProcessState, RearmRequest
from ares.tools.soak import report
from ares.tools.soak.injectors import LASTING, LIDAR_PROCESS, SIGNAL_OF, Injectors, RouterProcess
from ares.tools.soak.measure import GIVE_UP_S, FaultOutcome, SoakTracker
from ares.tools.soak.plan import KINDS, OBSTACLE_KINDS, PlannedFault, fault_plan, kinds_for
from blackbox.api.api_node import api_url

QUEUE = 4096
START_GRACE_S = 60.0  # wall seconds a (re)started process has for its first heartbeat (the supervisor's: 15)
STARTUP_PATIENCE = 60  # times ares run's start-up timeouts: a soak on a busy machine waits up to an hour to start
OPERATOR = "soak"
PROGRESS_WALL_S = 30.0
REARM_EVERY_S = 1.0  # stack seconds between two re-arm attempts
GOAL_AFTER_S = 10.0  # stack seconds without a mission (none set, or it ended) before the soak sets the tour again
ENGAGE_AFTER_S = 3.0  # stack seconds out of Automatic (no fault holding) before the soak engages again
CLOCK_STALL_S = 120.0  # wall seconds without the stack clock moving: the soak has stalled
END_GRACE_S = 60.0  # stack seconds after the last fault's slot for it to recover
PEDESTRIAN_SPEED_MPS = 0.8
PEDESTRIAN_FROM_M = -2.0  # steps onto the road from its right edge ...
PEDESTRIAN_WAIT_S = 4.0  # ... stops in the middle of the path this long ...
PEDESTRIAN_TO_M = 4.0  # ... and walks on to the left verge


@dataclass
class SoakOptions:
    hours: float
    faults: int
    seed: int
    out_dir: Path
    configs: tuple[str, ...] = ()
    listen: str | None = None
    api_port: int | None = None
    lead_s: float = 60.0  # stack time of the plan's start: the shuttle is engaged and driving by then
    kinds: tuple[str, ...] | None = None  # default: every kind the run's vehicle can take
    route: str | None = None  # a built-in tour or a route file, as for ares run (default: the configuration's)
    quiet: bool = False
    plan: list[PlannedFault] | None = None  # this plan, not one drawn from the seed (a resumed soak's rest)
    start_s_m: float | None = None  # where along the route the shuttle starts (default: the configuration's)
    segment: dict | None = None  # a resumed soak's segment: {"of": its first directory, "index": k, "plan_offset_s": P}


def obstacle_scenario(plan: list[PlannedFault], lead_s: float, seed: int) -> dict:
    """The soak's scenario: the plan's pedestrians and parked objects, appearing ahead of the
    shuttle at their stack time and leaving after their duration."""
    obstacles = []
    for f in plan:
        if f.kind not in OBSTACLE_KINDS:
            continue
        common = {
            "name": f"{f.kind}_{f.index}",
            "start_t_s": round(lead_s + f.at_s, 2),
            "appear_ahead_m": f.ahead_m,
            "gone_after_s": f.duration_s,
        }
        if f.kind == "pedestrian_in_path":  # crosses the road, right to left, stopping on the way
            path = [
                {"s": 0.0, "offset_m": PEDESTRIAN_FROM_M},
                {"s": 0.0, "offset_m": 0.0, "wait_s": PEDESTRIAN_WAIT_S},
                {"s": 0.0, "offset_m": PEDESTRIAN_TO_M},
            ]
            obstacles.append({**common, "kind": "pedestrian", "path": path, "speed_mps": PEDESTRIAN_SPEED_MPS})
        else:  # a cart parked on the path, driven away after its duration
            obstacles.append({**common, "kind": "cart", "path": [{"s": 0.0, "offset_m": 0.0}]})
    return {"name": f"soak_seed_{seed}", "description": "a soak's obstacles in the path", "obstacles": obstacles}


class Soak:
    def __init__(self, opts: SoakOptions):
        self.opts = opts
        self.out = opts.out_dir
        self.out.mkdir(parents=True, exist_ok=True)
        self.stop = threading.Event()

    def log(self, text: str) -> None:
        if not self.opts.quiet:
            print(text, file=sys.stderr, flush=True)

    # ---- set up -------------------------------------------------------------------------------------
    def configure(self) -> tuple[dict, list[PlannedFault]]:
        from ares.core.localhost import free_port

        opts = self.opts
        listen = opts.listen or f"tcp/127.0.0.1:{free_port()}"
        overrides = {
            "bus": {"router": listen, "embedded_router": False},
            "blackbox_store": {"uri": str((self.out / "blackbox.sqlite").resolve())},
            "api": {"port": opts.api_port or free_port()},
            # a dozen processes importing at once on a shared machine miss the 15 s to their first
            # heartbeat, are restarted, import again: a storm in which no soak starts
            "supervisor": {"start_grace_s": START_GRACE_S},
        }
        if opts.route:
            overrides = config.deep_merge(overrides_from_args(SimpleNamespace(route=opts.route)), overrides)
        if opts.start_s_m is not None:
            overrides = config.deep_merge(overrides, {"sim": {"start_s_m": round(opts.start_s_m, 1)}})
        cfg = prepare(opts.configs, overrides, "max")
        core = config.core(cfg)
        lidars = sorted(core.vehicle_profile.lidars) if cfg["lidars"] else []
        running = [p for p in processes.for_config(cfg) if not p.sim_only]
        kinds = list(opts.kinds) if opts.kinds else kinds_for(bool(lidars))
        if not lidars and any(KINDS[k].needs_lidars for k in kinds):
            raise config.ConfigError("LiDAR and obstacle faults need a run with LiDARs")
        plan = (
            list(opts.plan)
            if opts.plan is not None
            else fault_plan(opts.seed, opts.hours, opts.faults, kinds, [p.name for p in running], lidars)
        )
        scenario = obstacle_scenario(plan, opts.lead_s, opts.seed)
        if scenario["obstacles"]:
            path = self.out / "scenario.yaml"
            path.write_text(yaml.safe_dump(scenario, sort_keys=False))
            cfg = prepare(opts.configs, {**overrides, "scenario": str(path.resolve())}, "max")
        self.safety_relevant = {p.name: p.safety_relevant for p in running}
        route_file = Path(opts.route or "").resolve()
        (self.out / "plan.json").write_text(
            json.dumps(
                {
                    "seed": opts.seed,
                    "hours": opts.hours,
                    "faults": opts.faults,
                    "lead_s": opts.lead_s,
                    "kinds": kinds,
                    "lidars": lidars,
                    # what a resumed soak starts its next segment with (ares soak --resume)
                    "configs": [str(Path(c).resolve()) for c in opts.configs],
                    "route": str(route_file) if route_file.is_file() else opts.route,
                    **({"segment": opts.segment} if opts.segment else {}),
                    "plan": [f.as_dict() for f in plan],
                },
                indent=1,
            )
        )
        return cfg, plan

    # ---- the run --------------------------------------------------------------------------------------
    def run(self) -> dict:
        cfg, plan = self.configure()
        clock = stack_clock(cfg, "max")
        run_dir = self.out / "run"
        (run_dir / "logs").mkdir(parents=True, exist_ok=True)
        router_cfg = run_dir / "router.json"
        router_cfg.write_text(json.dumps({"vehicle_id": cfg["vehicle_id"], "bus": cfg["bus"]}))
        router = RouterProcess(router_cfg, cfg["bus"]["router"], run_dir / "logs" / "router.log")
        os.environ[FAULT_INJECTION_ENV] = "1"  # the supervisor's children inherit it
        previous = {sig: signal.signal(sig, lambda *_: self.stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)}
        router.start()
        supervisor = Supervisor(cfg, processes.for_config(cfg), run_dir, clock)
        supervisor.start()
        loop = threading.Thread(target=supervisor.run, args=(self.stop,), name="supervisor", daemon=True)
        loop.start()
        wall_start = time.monotonic()
        result: dict
        try:
            result = self.drive(cfg, plan, supervisor, clock, router)
        except RunFailed as exc:
            result = {"ok": False, "error": str(exc)}
        finally:
            self.stop.set()
            loop.join(timeout=5)
            supervisor.stop()
            router.stop()
            os.environ.pop(FAULT_INJECTION_ENV, None)
            for sig, handler in previous.items():
                signal.signal(sig, handler)
        # the stack has stopped and the recorder has flushed what it held: the black box's seconds
        result["wall_time_s"] = round(time.monotonic() - wall_start, 1)
        summary = report.summarise_dir(self.out, final=result)
        (self.out / "soak.json").write_text(json.dumps(summary, indent=1))
        try:
            summary["picture"] = str(report.picture(self.out, summary))
        except Exception as exc:  # the figures stand without the picture
            summary["picture_error"] = f"{type(exc).__name__}: {exc}"
        (self.out / "soak.json").write_text(json.dumps(summary, indent=1))
        return summary

    def drive(self, cfg: dict, plan: list[PlannedFault], supervisor: Supervisor, clock, router) -> dict:
        bus = supervisor.bus
        vehicle = config.core(cfg).vehicle_profile
        truth = bus.subscribe("sim/truth", queue=QUEUE)
        car = bus.subscribe("dbw/car_state", queue=QUEUE)
        gate = bus.subscribe("movement/status", queue=QUEUE)
        awareness = bus.subscribe("awareness/state", queue=1024)
        sup_state = bus.subscribe("supervisor/state", queue=1024)
        mission = bus.subscribe("mission/status", queue=1024)
        body = bus.subscribe("body/state", queue=1024)
        world = bus.subscribe("sim/world", queue=1024) if cfg["lidars"] else None
        # a loaded machine starts a dozen processes slowly (some are restarted before their first
        # heartbeat): a soak is patient with its start, which is not what it measures
        wait_for(lambda: truth.latest is not None, STARTUP_PATIENCE * STARTUP_TIMEOUT_S, "the simulator", self.stop)
        for attempt in range(STARTUP_PATIENCE):
            try:
                engage_automatic(bus, car, self.stop)
                break
            except RunFailed as exc:
                if attempt == STARTUP_PATIENCE - 1 or self.stop.is_set():
                    raise
                self.log(f"soak: not engaged yet ({exc}); trying again")
        t_engaged = clock.now()
        self.log(f"soak: engaged at t={t_engaged:.1f} s; {len(plan)} faults from t={self.opts.lead_s:g} s")
        if t_engaged > self.opts.lead_s:
            self.log(f"soak: engaged after the plan's start ({self.opts.lead_s:g} s): the first faults come late")
        t0 = self.opts.lead_s
        store = cfg["blackbox_store"]["uri"]
        injectors = Injectors(
            bus,
            clock,
            supervisor.inject,
            router,
            store if not store.startswith("mongodb") else None,
            api_url(cfg),
            cfg["vehicle_id"],
        )
        tracker = SoakTracker(t_start=clock.now())
        safety = SafetyTracker(vehicle.length_m, vehicle.width_m, vehicle.front_bumper_m)
        for sub in (truth, car, gate, awareness, sup_state, mission, body, *([world] if world else [])):
            sub.drain()
        faults_file = (self.out / "faults.jsonl").open("w")
        timeline_file = (self.out / "timeline.csv").open("w")
        timeline_file.write("t,v,level\n")
        written_timeline = 0
        pending = list(plan)
        end_t = t0 + self.opts.hours * 3600.0 + END_GRACE_S
        counters = {"rearms": 0, "rearm_refusals": 0, "engagements": 0, "mission_goals": 0}
        drive_only = (cfg.get("mission_manager") or {}).get("autostart") == "drive"
        no_goal_since: float | None = None
        last_rearm = -1e9
        out_of_auto_since: float | None = None
        last_progress = time.monotonic()
        wall_start = time.monotonic()
        closed: set[int] = set()
        clock_moved = (clock.now(), time.monotonic())

        def write_closed(final: bool = False) -> None:
            for outcome in tracker.faults:
                i = outcome.fault.index
                if i in closed or (outcome in tracker.open and not final):
                    continue
                if final or i in injectors.results or outcome.fault.kind not in LASTING:
                    outcome.extra.update(injectors.results.get(i, {}))
                    faults_file.write(json.dumps(outcome.as_dict()) + "\n")
                    closed.add(i)
            faults_file.flush()
            timeline_file.flush()

        def progress(now: float) -> dict:
            injected = len(tracker.faults)
            figures = {
                "t": round(now, 2),
                "t_start_s": round(tracker.t_start, 2),
                "plan_start_s": t0,
                "s": None if truth.latest is None else round(truth.latest.s, 1),  # where a resumed soak starts
                "faults_injected": injected,
                "faults_planned": len(plan),
                "collisions": len(safety.collided),
                "invariant_violations": safety.violations,
                "invariant_examples": safety.examples,
                "min_clearance_m": None if safety.min_clearance_m == float("inf") else round(safety.min_clearance_m, 3),
                "closest_approach": safety.closest,
                "availability": None if tracker.availability() is None else round(tracker.availability(), 5),
                "available_s": round(tracker.available_s, 1),
                "measured_s": round(tracker.total_s, 1),
                **counters,
                "router_restarts": router.restarts,
                "process_restarts": {n: c.restarts for n, c in supervisor.children.items() if c.restarts},
                "wall_s": round(time.monotonic() - wall_start, 1),
                "speed_factor": round(tracker.total_s / max(time.monotonic() - wall_start, 1e-9), 2),
            }
            (self.out / "progress.json").write_text(json.dumps(figures, indent=1))
            return figures

        try:
            while True:
                if self.stop.is_set():
                    raise RunFailed("interrupted")
                now, wall = clock.now(), time.monotonic()
                # what happened since the last look, in an order that judges motion against its causes
                for _, msg in sup_state.drain():
                    tracker.add_processes([(p.name, p.state, p.restarts) for p in msg.processes])
                for _, msg in awareness.drain():
                    tracker.add_awareness(msg.level)
                    safety.add_awareness(msg)
                for _, msg in mission.drain():
                    tracker.add_mission(msg.state)
                for _, msg in body.drain():
                    safety.add_body(msg)
                if world is not None:
                    for _, msg in world.drain():
                        safety.add_world(msg)
                for _, msg in gate.drain():
                    tracker.add_gate(msg.t, msg.latched, msg.stopping, msg.limit_mps, wall)
                    safety.add_status(msg)
                for _, msg in car.drain():
                    tracker.add_car(msg.t, msg.watchdog_tripped, msg.emergency, wall)
                for _, msg in truth.drain():
                    safety.add_truth(msg.t, msg.x, msg.y, msg.yaw, msg.v, msg.board_failsafe)
                    tracker.add_truth(msg.t, msg.v, msg.board_failsafe, wall)
                for t, v, level in tracker.timeline[written_timeline:]:
                    timeline_file.write(f"{t},{v},{level}\n")
                written_timeline = len(tracker.timeline)
                # the faults due
                while pending and t0 + pending[0].at_s <= now:
                    fault = pending.pop(0)
                    ok, detail = injectors.inject(fault, now)
                    relevant = KINDS[fault.kind].safety_relevant and (
                        fault.target is None or self.safety_relevant.get(fault.target, True)
                    )
                    process = LIDAR_PROCESS if fault.kind == "lidar_silent" else None
                    process = fault.target if fault.kind in SIGNAL_OF else process
                    if process is not None and "is not running" in detail:
                        ok = False  # restarting after an earlier fault: nothing to inject into
                    outcome = FaultOutcome(fault, now, relevant, ok, detail, process=process if ok else None)
                    if fault.kind == "bad_api_burst":  # the API itself down (a fault of its own): none can answer
                        outcome.extra["api_running"] = tracker.process_states.get("api") == ProcessState.RUNNING
                    tracker.injected(outcome, time.monotonic())
                    if fault.index % 10 == 0 or not ok:
                        self.log(
                            f"[t={now:8.1f} s] fault {fault.index + 1}/{len(plan)} {fault.kind}"
                            f"{' ' + fault.target if fault.target else ''}: {detail}"
                        )
                tracker.give_up(now, GIVE_UP_S)
                write_closed()
                if now != clock_moved[0]:
                    clock_moved = (now, time.monotonic())
                elif time.monotonic() - clock_moved[1] > CLOCK_STALL_S:
                    raise RunFailed(f"the stack clock has not moved for {CLOCK_STALL_S:g} s of wall time")
                # the operator: re-arm a latched stop once its cause has cleared
                status = gate.latest
                level = awareness.latest.level if awareness.latest is not None else None
                if status is not None and status.latched and level != 1 and now - last_rearm >= REARM_EVERY_S:
                    last_rearm = now
                    try:
                        reply = bus.call("movement/rearm", RearmRequest(operator=OPERATOR))
                        counters["rearms" if reply.accepted else "rearm_refusals"] += 1
                    except ServiceError:
                        counters["rearm_refusals"] += 1
                # the operator: the tour again if the mission has none (a mission manager restarted before its
                # first heartbeat does not set its start-up goal: it resumes what it had, here nothing)
                goal = mission.latest
                if goal is not None and goal.state in ("IDLE", "SUCCEEDED", "CANCELED"):
                    no_goal_since = now if no_goal_since is None else no_goal_since
                    if now - no_goal_since >= GOAL_AFTER_S:
                        no_goal_since = None
                        try:
                            request = MissionGoal(operator=OPERATOR, drive=drive_only, repeat=not drive_only)
                            if bus.call("mission/goal", request).accepted:
                                counters["mission_goals"] += 1
                                self.log(f"[t={now:8.1f} s] soak: the mission had no goal; the tour set again")
                        except ServiceError as exc:
                            self.log(f"soak: could not set the mission's goal: {exc}")
                else:
                    no_goal_since = None
                # the safety driver: Automatic again if the shuttle fell back out of it
                state = car.latest
                if state is not None and state.mode != DriveMode.AUTOMATIC:
                    out_of_auto_since = now if out_of_auto_since is None else out_of_auto_since
                    if now - out_of_auto_since >= ENGAGE_AFTER_S:
                        try:
                            engage_automatic(bus, car, self.stop)
                            counters["engagements"] += 1
                        except RunFailed as exc:
                            self.log(f"soak: could not engage again: {exc}")
                        out_of_auto_since = None
                else:
                    out_of_auto_since = None
                if time.monotonic() - last_progress >= PROGRESS_WALL_S:
                    last_progress = time.monotonic()
                    p = progress(now)
                    self.log(
                        f"[t={now:8.1f} s] {p['faults_injected']}/{len(plan)} faults, collisions "
                        f"{p['collisions']}, violations {p['invariant_violations']}, availability "
                        f"{p['availability']}, x{p['speed_factor']} real time"
                    )
                if not pending and (now >= end_t or not tracker.open):
                    break
                time.sleep(0.05)
        finally:
            injectors.wait()
            write_closed(final=True)
            faults_file.close()
            timeline_file.close()
            final = progress(clock.now())
        return {"ok": True, **final, "level_history_changes": len(safety.level_history)}
