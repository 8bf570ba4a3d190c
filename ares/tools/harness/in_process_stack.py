"""The whole stack in one process: every node of the process table on the in-memory bus, stepped
in lockstep on a manual clock. Deterministic and quick, for tests and experiments.

    stack = InProcessStack(cfg)              # cfg: a run configuration (ares.app.run_config)
    result = stack.drive(seconds=120)        # engage Automatic, drive, measure as `ares run --headless`
    stack.close()

Each node is the class the process table names, built with the run's configuration, on its own
bus of one MemoryNetwork (messages encoded and decoded as on Zenoh, contracts enforced), and
stepped with `Node.step_once` on the period grid of its own rate, as `--speed max` steps it
(ares.core.lockstep): the clock moves to the next time some node is due, and the nodes due then
step in the order of the process table, the simulator first, so each sees every message
published up to that time. What this lacks next to the process stack is the bus's latency and
the processes' concurrency: a node due at t sees what the nodes before it in the table
published at t, where a process might not have yet.

The harness hosts the processes, so it also plays the supervisor's part: it publishes
`supervisor/state` every STATE_PERIOD_S of stack time with each hosted node running, and
`inject` stops a node the way a scenario's process fault stops a process (SIGKILL or SIGTERM:
it exits; SIGSTOP: it stands still until its heartbeat is stale), reports it restarting, and
starts a new instance after `restart_after_s` of stack time. The real supervisor, its restarts
and its wall-clock health checks are tested with real processes (tests/test_supervisor.py and
the whole-stack runs).

Nodes that do not step (the REST API: an asyncio server) are left out.
"""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

from ares.app.processes import Process, for_run
from ares.app.stack import RunFailed
from ares.core import config
from ares.core.clock import ManualClock
from ares.core.membus import MemoryNetwork
from ares.core.messages import DriveMode, DriverCommand, ProcessState, ProcessStatus, SupervisorState
from ares.core.node import Node, grid_after
from ares.core.recording import INCARNATION_ENV
from ares.core.route import Route, load_route
from ares.tools.headless import Goal, Measurements

STATE_PERIOD_S = 0.5  # supervisor/state, as often as the supervisor publishes it
READY_WITHIN_S = 60.0  # stack seconds for the stack to be ready to drive (a controller in charge)
TAKE_EVERY_S = 0.1  # the measurements take what was published this often


@dataclass
class Hosted:
    """One process of the table in this process: its node, when its next step is due, its health."""

    spec: Process
    node: Node | None = None
    due: float = 0.0
    period: float = 0.1
    restarts: int = 0
    last_failure: str = ""
    restart_at: float | None = None  # stopped: when its new instance starts
    hung_at: float | None = None  # stands still, alive, since then (until found out)
    incarnation: int = 0


class InProcessStack:
    def __init__(
        self, cfg: dict, *, run_dir: Path | None = None, restart_after_s: float = 0.5, exclude: tuple[str, ...] = ()
    ):
        self.cfg = cfg
        # as in a supervised run: the run's configuration in a file that ARES_RUN_CONFIG names, beside
        # which a node keeps what its restart must find (Node.kept_state_path)
        self.run_dir = Path(run_dir) if run_dir is not None else Path(tempfile.mkdtemp(prefix="ares-in-process-"))
        self._environ = {key: os.environ.get(key) for key in (config.RUN_CONFIG_ENV, INCARNATION_ENV)}
        os.environ[config.RUN_CONFIG_ENV] = str(config.write_run_config(cfg, self.run_dir / "config.json"))
        self.route: Route = load_route(config.core(cfg))
        self.clock = ManualClock(0.0)
        self.network = MemoryNetwork(cfg["vehicle_id"])
        self.bus = self.network.bus("supervisor", self.clock)  # the harness's own view of the bus
        self.restart_after_s = restart_after_s
        self.stale_after_s = config.core(cfg).heartbeat.stale_after_s
        self._state = self.bus.publisher("supervisor/state")
        self._next_state = 0.0
        self.hosted: dict[str, Hosted] = {}
        for spec in for_run(cfg["simulate"], cfg["lidars"]):
            if spec.name in exclude or not spec.node_class().steps:
                continue
            self.hosted[spec.name] = hosted = Hosted(spec)
            self._start(hosted)

    # ---- the processes -------------------------------------------------------------------------
    def _start(self, hosted: Hosted) -> None:
        name = hosted.spec.name
        # a restarted node knows it is one (the mission manager resumes, the bridge finds its mode)
        os.environ[INCARNATION_ENV] = str(hosted.incarnation)
        node = hosted.spec.node_class()(self.cfg, clock=self.clock, bus=self.network.bus(name, self.clock), name=name)
        node.setup()
        node.bus.declare_alive()
        hosted.node, hosted.hung_at, hosted.restart_at = node, None, None
        hosted.period = 1.0 / node.rate_hz
        hosted.due = self.clock.now()

    def _stop(self, hosted: Hosted, why: str, graceful: bool) -> None:
        node = hosted.node
        if node is None:
            return
        if graceful:
            node.teardown()
        node.bus.close()
        hosted.node, hosted.hung_at = None, None
        hosted.last_failure = why
        hosted.restarts += 1
        hosted.incarnation += 1
        hosted.restart_at = self.clock.now() + self.restart_after_s

    def inject(self, process: str, fault: str) -> str:
        """A scenario's process fault (ares.tools.scenario_driver): kill_process, stop_process or
        hang_process, as the supervisor's `inject` does it to a real process."""
        hosted = self.hosted.get(process)
        if hosted is None or hosted.node is None:
            return f"{process} is not running"
        if fault == "hang_process":
            hosted.hung_at = self.clock.now()
            return f"{process} stands still"
        self._stop(hosted, "killed by SIGKILL" if fault == "kill_process" else "exited 0", fault == "stop_process")
        return f"{process} stopped ({fault})"

    def _health(self, now: float) -> None:
        for hosted in self.hosted.values():
            if hosted.hung_at is not None and now - hosted.hung_at > self.stale_after_s:
                self._stop(hosted, "heartbeat stale", graceful=False)  # killed, as the supervisor does
            if hosted.node is None and hosted.restart_at is not None and now >= hosted.restart_at:
                self._start(hosted)
        if now >= self._next_state:
            self._next_state = grid_after(now, STATE_PERIOD_S)
            self._state.put(SupervisorState(t=now, processes=[self._status(h) for h in self.hosted.values()]))

    def _status(self, hosted: Hosted) -> ProcessStatus:
        running = hosted.node is not None and hosted.hung_at is None
        return ProcessStatus(
            name=hosted.spec.name,
            state=ProcessState.RUNNING if running else ProcessState.RESTARTING,
            pid=os.getpid(),
            restarts=hosted.restarts,
            last_failure=hosted.last_failure,
            safety_relevant=hosted.spec.safety_relevant,
        )

    # ---- time ------------------------------------------------------------------------------------
    def advance(self, until: float) -> None:
        """Step every node due up to stack time `until`, in time order, and leave the clock there."""
        while True:
            due = [h.due for h in self.hosted.values() if h.node is not None and h.hung_at is None]
            restarts = [h.restart_at for h in self.hosted.values() if h.restart_at is not None]
            t = min(due + restarts + [self._next_state])
            if t > until:
                break
            self.clock.set(t)
            self._health(t)
            for hosted in self.hosted.values():
                if hosted.node is not None and hosted.hung_at is None and hosted.due <= t:
                    hosted.node.step_once(t)
                    hosted.due = grid_after(t, hosted.period)
        self.clock.set(until)

    # ---- driving ---------------------------------------------------------------------------------
    def engage(self) -> None:
        """As a safety driver and the navigation system would, once a controller is in charge:
        the Auto/Manual button (Manual -> Ready), then `set_automatic_mode` (Ready -> Automatic)."""
        car, status = self.bus.subscribe("dbw/car_state"), self.bus.subscribe("control/status")
        ready = self._until(
            lambda: car.latest is not None and status.latest is not None and status.latest.controller != "stop",
            READY_WITHIN_S,
        )
        if not ready:
            why = status.latest.reason if status.latest is not None else "no control/status"
            raise RunFailed(f"no controller in charge within {READY_WITHIN_S:g} s ({why})")
        if car.latest.mode == DriveMode.MANUAL:
            self.bus.call("sim/driver", DriverCommand(t=self.clock.now(), action="BUTTON"))
            if not self._until(lambda: car.latest.mode == DriveMode.READY, 5.0):
                raise RunFailed("the panel button did not make the bridge Ready")
        reply = self.bus.call("set_automatic_mode")
        if not reply.accepted:
            raise RunFailed(f"Automatic mode refused: {reply.reason}")
        self._until(lambda: car.latest.mode == DriveMode.AUTOMATIC, 1.0)

    def _until(self, condition, within_s: float) -> bool:
        end = self.clock.now() + within_s
        while not condition():
            if self.clock.now() >= end:
                return False
            self.advance(self.clock.now() + TAKE_EVERY_S)
        return True

    def drive(self, *, laps: int = 1, seconds: float | None = None) -> dict:
        """`ares run --headless` in this process: engage, drive N laps, the open route to its end or
        `seconds` of vehicle time, and return the same figures (ares.tools.headless)."""
        m = Measurements(self.cfg, self.route, self.bus, self.inject)
        self.engage()
        t_start = self.clock.now()
        m.begin()
        goal = Goal(m, t_start, laps, seconds)
        try:
            while True:
                self.advance(self.clock.now() + TAKE_EVERY_S)
                m.take(self.clock.now())
                if goal.reached(self.clock.now()):
                    break
        except RunFailed as exc:
            exc.figures = m.partial()
            raise
        total = self.clock.now() - t_start
        driven = goal.laps_driven()
        return {
            "ok": True,
            "laps": driven,
            "route": self.route.name,
            "route_length_m": round(self.route.length, 2),
            "lap_time_s": round(total / max(driven, 1), 2),
            "total_time_s": round(total, 2),
            **m.summary(),
            "clock": "in_process",
            "vehicle": self.cfg["vehicle"],
            "t_start_s": round(t_start, 3),
            "t_end_s": round(self.clock.now(), 3),
        }

    def close(self) -> None:
        """Tear every node down (the recorder writes what it holds) and leave the bus."""
        for hosted in self.hosted.values():
            if hosted.node is not None:
                hosted.node.teardown()
                hosted.node.bus.close()
                hosted.node = None
        self.bus.close()
        for key, value in self._environ.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value

    def __enter__(self) -> InProcessStack:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
