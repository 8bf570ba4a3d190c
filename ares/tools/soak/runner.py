"""`ares soak`: the whole stack at --speed max on the tour, faults injected from a seeded plan.

The run: the plan (ares.tools.soak.plan) is drawn from the seed; its obstacles go into a scenario
file of the soak's own (they appear ahead of the shuttle at their stack time); the soak starts its
own Zenoh router process (a fault restarts it) and the stack under one supervisor (ares.app.stack.run,
headless, the soak's drive `SoakDrive`), with ARES_FAULT_INJECTION=1 so that its processes take the
busy-loop fault; it engages Automatic mode and, from `lead_s` of stack time on, injects each fault
at its time (ares.tools.soak.injectors), measuring what the stack does (ares.tools.soak.measure,
and the safety evaluation's collisions and invariants). As the operator and safety driver would,
it re-arms a latched emergency stop once its cause has cleared and engages Automatic again if the
shuttle fell back to Manual; both are counted.

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
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import yaml

from ares.app import processes, stack
from ares.app.engagement import STARTUP_TIMEOUT_S, RunFailed, engage_automatic, wait_for
from ares.app.evaluation.safety_eval import SafetyTracker
from ares.app.run_options import RunningStack, RunOptions
from ares.core import config
from ares.core.bus import ServiceError
from ares.core.launch import FAULT_INJECTION_ENV
from ares.core.messages import DriveMode, MissionGoal, ProcessState, RearmRequest
from ares.core.signed_command import load_command_key, sign
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

    def log(self, text: str) -> None:
        if not self.opts.quiet:
            print(text, file=sys.stderr, flush=True)

    # ---- set up -------------------------------------------------------------------------------------
    def configure(self) -> tuple[RunOptions, dict, list[PlannedFault]]:
        """The stack's run and its configuration, and the plan (drawn, its obstacles' scenario and
        plan.json written)."""
        from ares.core.localhost import free_port

        opts = self.opts
        settings: dict = {
            # a dozen processes importing at once on a shared machine miss the 15 s to their first
            # heartbeat, are restarted, import again: a storm in which no soak starts
            "supervisor": {"start_grace_s": START_GRACE_S},
        }
        if opts.start_s_m is not None:
            settings["sim"] = {"start_s_m": round(opts.start_s_m, 1)}
        options = RunOptions(
            config_files=opts.configs,
            settings=settings,
            headless=True,
            speed="max",
            route=opts.route,
            router=opts.listen or f"tcp/127.0.0.1:{free_port()}",  # the soak's own router process
            store=str((self.out / "blackbox.sqlite").resolve()),
            api_port=opts.api_port or free_port(),
            run_dir=self.out / "run",
        )
        cfg = stack.configure(options)
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
            options = options.model_copy(update={"scenario": str(path.resolve())})
            cfg = stack.configure(options)
        self.safety_relevant = {p.name: p.safety_relevant for p in running}
        self.write_plan(plan, kinds, lidars)
        return options, cfg, plan

    def write_plan(self, plan: list[PlannedFault], kinds: list[str], lidars: list[str]) -> None:
        """plan.json: the plan and what drew it."""
        opts = self.opts
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

    # ---- the run --------------------------------------------------------------------------------------
    def run(self) -> dict:
        """The stack driven through the plan (ares.app.stack.run, beside the soak's router), then
        the figures, written to soak.json with the picture."""
        options, cfg, plan = self.configure()
        run_dir = self.out / "run"
        logs = run_dir / "logs"
        logs.mkdir(parents=True, exist_ok=True)
        router_cfg = run_dir / "router.json"
        router_cfg.write_text(json.dumps({"vehicle_id": cfg["vehicle_id"], "bus": cfg["bus"]}))
        router = RouterProcess(router_cfg, cfg["bus"]["router"], logs / "router.log")
        os.environ[FAULT_INJECTION_ENV] = "1"  # the supervisor's children inherit it
        wall_start = time.monotonic()
        try:
            router.start()
            run = stack.run(options, drive=lambda running: SoakDrive(self, plan, running, router).drive())
        finally:
            router.stop()
            os.environ.pop(FAULT_INJECTION_ENV, None)
        # the stack has stopped and the recorder has flushed what it held: the black box's seconds
        result = {"ok": run.ok, **({"error": run.error} if run.error else {}), **run.figures}
        result["wall_time_s"] = round(time.monotonic() - wall_start, 1)
        summary = report.summarise_dir(self.out, final=result)
        (self.out / "soak.json").write_text(json.dumps(summary, indent=1))
        try:
            summary["picture"] = str(report.picture(self.out, summary))
        except Exception as exc:  # the figures stand without the picture
            summary["picture_error"] = f"{type(exc).__name__}: {exc}"
        (self.out / "soak.json").write_text(json.dumps(summary, indent=1))
        return summary


class SoakDrive:
    """The soak's drive of the running stack: engaged once, then a round every 50 ms of wall time
    (what the stack published, the faults due, the operator's and the safety driver's part, the
    progress) until the plan is done and its faults have recovered or the soak's hours are up."""

    def __init__(self, soak: Soak, plan: list[PlannedFault], running: RunningStack, router: RouterProcess):
        self.soak, self.plan, self.running, self.router = soak, plan, running, router
        cfg, bus = running.cfg, running.bus
        self.bus, self.clock, self.stop = bus, running.clock, running.stop
        self.vehicle = config.core(cfg).vehicle_profile
        self.command_key = load_command_key(config.core(cfg).commands)  # the operator's, as the CLI's
        self.truth = bus.subscribe("sim/truth", queue=QUEUE)
        self.car = bus.subscribe("dbw/car_state", queue=QUEUE)
        self.gate = bus.subscribe("movement/status", queue=QUEUE)
        self.awareness = bus.subscribe("awareness/state", queue=1024)
        self.sup_state = bus.subscribe("supervisor/state", queue=1024)
        self.mission = bus.subscribe("mission/status", queue=1024)
        self.body = bus.subscribe("body/state", queue=1024)
        self.world = bus.subscribe("sim/world", queue=1024) if cfg["lidars"] else None
        self.t0 = soak.opts.lead_s
        self.pending = list(plan)
        self.end_t = self.t0 + soak.opts.hours * 3600.0 + END_GRACE_S
        self.counters = {"rearms": 0, "rearm_refusals": 0, "engagements": 0, "mission_goals": 0}
        self.drive_only = (cfg.get("mission_manager") or {}).get("autostart") == "drive"
        self.no_goal_since: float | None = None
        self.last_rearm = -1e9
        self.out_of_auto_since: float | None = None
        self.closed: set[int] = set()
        self.written_timeline = 0

    def drive(self) -> dict:
        self.engage_first()
        self.start_measuring()
        try:
            while True:
                if self.stop.is_set():
                    raise RunFailed("interrupted")
                now = self.clock.now()
                self.take_messages(time.monotonic())
                self.inject_due(now)
                self.tracker.give_up(now, GIVE_UP_S)
                self.write_closed()
                self.check_clock(now)
                self.rearm(now)
                self.set_goal_again(now)
                self.engage_again(now)
                self.report_progress(now)
                if not self.pending and (now >= self.end_t or not self.tracker.open):
                    break
                time.sleep(0.05)
        finally:
            self.injectors.wait()
            self.write_closed(final=True)
            self.faults_file.close()
            self.timeline_file.close()
            final = self.progress(self.clock.now())
        return {**final, "level_history_changes": len(self.safety.level_history)}

    # ---- the start ----------------------------------------------------------------------------------
    def engage_first(self) -> None:
        """Automatic mode, with the patience a loaded machine needs: it starts a dozen processes slowly
        (some are restarted before their first heartbeat), which is not what a soak measures."""
        wait_for(
            lambda: self.truth.latest is not None, STARTUP_PATIENCE * STARTUP_TIMEOUT_S, "the simulator", self.stop
        )
        for attempt in range(STARTUP_PATIENCE):
            try:
                engage_automatic(self.bus, self.car, self.stop)
                break
            except RunFailed as exc:
                if attempt == STARTUP_PATIENCE - 1 or self.stop.is_set():
                    raise
                self.soak.log(f"soak: not engaged yet ({exc}); trying again")
        t_engaged = self.clock.now()
        lead_s = self.soak.opts.lead_s
        self.soak.log(f"soak: engaged at t={t_engaged:.1f} s; {len(self.plan)} faults from t={lead_s:g} s")
        if t_engaged > lead_s:
            self.soak.log(f"soak: engaged after the plan's start ({lead_s:g} s): the first faults come late")

    def start_measuring(self) -> None:
        """The injectors, the trackers and the soak's files; what came before the engagement dropped."""
        cfg = self.running.cfg
        store = cfg["blackbox_store"]["uri"]
        self.injectors = Injectors(
            self.bus,
            self.clock,
            self.running.supervisor.inject,
            self.router,
            store if not store.startswith("mongodb") else None,
            api_url(cfg),
            cfg["vehicle_id"],
        )
        self.tracker = SoakTracker(t_start=self.clock.now())
        self.safety = SafetyTracker(self.vehicle.length_m, self.vehicle.width_m, self.vehicle.front_bumper_m)
        for sub in self._subscriptions():
            sub.drain()
        self.faults_file = (self.soak.out / "faults.jsonl").open("w")
        self.timeline_file = (self.soak.out / "timeline.csv").open("w")
        self.timeline_file.write("t,v,level\n")
        self.last_progress = self.wall_start = time.monotonic()
        self.clock_moved = (self.clock.now(), time.monotonic())

    def _subscriptions(self) -> list:
        subs = [self.truth, self.car, self.gate, self.awareness, self.sup_state, self.mission, self.body]
        return subs + ([self.world] if self.world is not None else [])

    # ---- a round ------------------------------------------------------------------------------------
    def take_messages(self, wall: float) -> None:
        """What happened since the last look, in an order that judges motion against its causes; the
        timeline's new rows."""
        tracker, safety = self.tracker, self.safety
        for _, msg in self.sup_state.drain():
            tracker.add_processes([(p.name, p.state, p.restarts) for p in msg.processes])
        for _, msg in self.awareness.drain():
            tracker.add_awareness(msg.level)
            safety.add_awareness(msg)
        for _, msg in self.mission.drain():
            tracker.add_mission(msg.state)
        for _, msg in self.body.drain():
            safety.add_body(msg)
        if self.world is not None:
            for _, msg in self.world.drain():
                safety.add_world(msg)
        for _, msg in self.gate.drain():
            tracker.add_gate(msg.t, msg.latched, msg.stopping, msg.limit_mps, wall)
            safety.add_status(msg)
        for _, msg in self.car.drain():
            tracker.add_car(msg.t, msg.watchdog_tripped, msg.emergency, wall)
        for _, msg in self.truth.drain():
            safety.add_truth(msg.t, msg.x, msg.y, msg.yaw, msg.v, msg.board_failsafe)
            tracker.add_truth(msg.t, msg.v, msg.board_failsafe, wall)
        for t, v, level in tracker.timeline[self.written_timeline :]:
            self.timeline_file.write(f"{t},{v},{level}\n")
        self.written_timeline = len(tracker.timeline)

    def inject_due(self, now: float) -> None:
        """Each fault whose time has come, injected and tracked until it has recovered."""
        while self.pending and self.t0 + self.pending[0].at_s <= now:
            fault = self.pending.pop(0)
            ok, detail = self.injectors.inject(fault, now)
            relevant = KINDS[fault.kind].safety_relevant and (
                fault.target is None or self.soak.safety_relevant.get(fault.target, True)
            )
            process = LIDAR_PROCESS if fault.kind == "lidar_silent" else None
            process = fault.target if fault.kind in SIGNAL_OF else process
            if process is not None and "is not running" in detail:
                ok = False  # restarting after an earlier fault: nothing to inject into
            outcome = FaultOutcome(fault, now, relevant, ok, detail, process=process if ok else None)
            if fault.kind == "bad_api_burst":  # the API itself down (a fault of its own): none can answer
                outcome.extra["api_running"] = self.tracker.process_states.get("api") == ProcessState.RUNNING
            self.tracker.injected(outcome, time.monotonic())
            if fault.index % 10 == 0 or not ok:
                self.soak.log(
                    f"[t={now:8.1f} s] fault {fault.index + 1}/{len(self.plan)} {fault.kind}"
                    f"{' ' + fault.target if fault.target else ''}: {detail}"
                )

    def write_closed(self, final: bool = False) -> None:
        """faults.jsonl: each fault once it has recovered (every one, `final`ly); both files flushed."""
        for outcome in self.tracker.faults:
            i = outcome.fault.index
            if i in self.closed or (outcome in self.tracker.open and not final):
                continue
            if final or i in self.injectors.results or outcome.fault.kind not in LASTING:
                outcome.extra.update(self.injectors.results.get(i, {}))
                self.faults_file.write(json.dumps(outcome.as_dict()) + "\n")
                self.closed.add(i)
        self.faults_file.flush()
        self.timeline_file.flush()

    def check_clock(self, now: float) -> None:
        """RunFailed if the stack clock has stood still for CLOCK_STALL_S of wall time."""
        if now != self.clock_moved[0]:
            self.clock_moved = (now, time.monotonic())
        elif time.monotonic() - self.clock_moved[1] > CLOCK_STALL_S:
            raise RunFailed(f"the stack clock has not moved for {CLOCK_STALL_S:g} s of wall time")

    def rearm(self, now: float) -> None:
        """The operator: re-arm a latched stop once its cause has cleared."""
        status = self.gate.latest
        level = self.awareness.latest.level if self.awareness.latest is not None else None
        if status is None or not status.latched or level == 1 or now - self.last_rearm < REARM_EVERY_S:
            return
        self.last_rearm = now
        try:
            rearm = sign(self.command_key, "movement/rearm", RearmRequest(operator=OPERATOR), OPERATOR)
            reply = self.bus.call("movement/rearm", rearm)
            self.counters["rearms" if reply.accepted else "rearm_refusals"] += 1
        except ServiceError:
            self.counters["rearm_refusals"] += 1

    def set_goal_again(self, now: float) -> None:
        """The operator: the tour again if the mission has none (a mission manager restarted before its
        first heartbeat does not set its start-up goal: it resumes what it had, here nothing)."""
        goal = self.mission.latest
        if goal is None or goal.state not in ("IDLE", "SUCCEEDED", "CANCELED"):
            self.no_goal_since = None
            return
        self.no_goal_since = now if self.no_goal_since is None else self.no_goal_since
        if now - self.no_goal_since < GOAL_AFTER_S:
            return
        self.no_goal_since = None
        try:
            request = MissionGoal(operator=OPERATOR, drive=self.drive_only, repeat=not self.drive_only)
            if self.bus.call("mission/goal", sign(self.command_key, "mission/goal", request, OPERATOR)).accepted:
                self.counters["mission_goals"] += 1
                self.soak.log(f"[t={now:8.1f} s] soak: the mission had no goal; the tour set again")
        except ServiceError as exc:
            self.soak.log(f"soak: could not set the mission's goal: {exc}")

    def engage_again(self, now: float) -> None:
        """The safety driver: Automatic again if the shuttle fell back out of it."""
        state = self.car.latest
        if state is None or state.mode == DriveMode.AUTOMATIC:
            self.out_of_auto_since = None
            return
        self.out_of_auto_since = now if self.out_of_auto_since is None else self.out_of_auto_since
        if now - self.out_of_auto_since < ENGAGE_AFTER_S:
            return
        try:
            engage_automatic(self.bus, self.car, self.stop)
            self.counters["engagements"] += 1
        except RunFailed as exc:
            self.soak.log(f"soak: could not engage again: {exc}")
        self.out_of_auto_since = None

    def report_progress(self, now: float) -> None:
        """progress.json and a line on stderr every PROGRESS_WALL_S of wall time."""
        if time.monotonic() - self.last_progress < PROGRESS_WALL_S:
            return
        self.last_progress = time.monotonic()
        p = self.progress(now)
        self.soak.log(
            f"[t={now:8.1f} s] {p['faults_injected']}/{len(self.plan)} faults, collisions "
            f"{p['collisions']}, violations {p['invariant_violations']}, availability "
            f"{p['availability']}, x{p['speed_factor']} real time"
        )

    def progress(self, now: float) -> dict:
        """The running totals, written to progress.json."""
        tracker, safety, wall_s = self.tracker, self.safety, time.monotonic() - self.wall_start
        truth = self.truth.latest
        availability = tracker.availability()
        figures = {
            "t": round(now, 2),
            "t_start_s": round(tracker.t_start, 2),
            "plan_start_s": self.t0,
            "s": None if truth is None else round(truth.s, 1),  # where a resumed soak starts
            "faults_injected": len(tracker.faults),
            "faults_planned": len(self.plan),
            "collisions": len(safety.collided),
            "invariant_violations": safety.violations,
            "invariant_examples": safety.examples,
            "min_clearance_m": None if safety.min_clearance_m == float("inf") else round(safety.min_clearance_m, 3),
            "closest_approach": safety.closest,
            "availability": None if availability is None else round(availability, 5),
            "available_s": round(tracker.available_s, 1),
            "measured_s": round(tracker.total_s, 1),
            **self.counters,
            "router_restarts": self.router.restarts,
            "process_restarts": {n: c.restarts for n, c in self.running.supervisor.children.items() if c.restarts},
            "wall_s": round(wall_s, 1),
            "speed_factor": round(tracker.total_s / max(wall_s, 1e-9), 2),
        }
        (self.soak.out / "progress.json").write_text(json.dumps(figures, indent=1))
        return figures
