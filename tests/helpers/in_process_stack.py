"""The whole stack in one process: every node of the process table on the in-memory bus, stepped
in lockstep on a manual clock. Deterministic and quick, for tests and experiments.

    stack = InProcessStack(cfg)              # cfg: a run configuration (ares.app.stack.prepare)
    result = stack.drive(seconds=120)        # engage Automatic, drive, measure as `ares run --headless`
    stack.close()

    python -m tests.helpers.in_process_stack --seconds 120 [--config FILE ...]   # the same, as JSON

Each node is the class the process table names, built with the run's configuration, on its own
bus of one MemoryNetwork (messages encoded and decoded as on Zenoh, contracts enforced), and
stepped with `Node.step_once` on the period grid of its own rate, as `--speed max` steps it
(ares.core.lockstep): the clock moves to the next time some node is due, and the nodes due then
step in the order of the process table, the simulator first, so each sees every message
published up to that time. What this lacks next to the process stack is the bus's latency and
the processes' concurrency: a node due at t sees what the nodes before it in the table
published at t, where a process might not have yet.

The harness hosts the processes, so it plays the supervisor's part, in stack time where the
supervisor judges in wall time:
- it publishes `supervisor/state` every STATE_PERIOD_S and at once on a change, each hosted node
  running, or restarting after a fault;
- `inject` plays a scenario's process fault (ares.app.scenario_driver) as `Supervisor.inject`
  does to a process: kill (SIGKILL) and stop (SIGTERM) end the node at once; hang (SIGSTOP)
  stops its steps, and it is reported running until its heartbeat would be stale
  (heartbeat.stale_after_s), then ended;
- an ended node starts again after the supervisor's backoff (supervisor.restart_backoff_s, the
  n-th delay for the n-th failure in a row) as a new instance that knows it is a restart and
  finds what its predecessor kept (ARES_INCARNATION, ARES_RUN_CONFIG's folder).
A node's threads cannot be killed without its process, so an ended node's teardown always runs
(a killed recorder writes what a killed process would have left in its queue). The real
supervisor, its wall-clock health checks and its restarts are tested with real processes
(tests/test_supervisor.py and the whole-stack runs).

Nodes that do not step (the REST API: an asyncio server) are left out.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from ares.app.engagement import RunFailed
from ares.app.headless import Goal, Measurements
from ares.app.processes import Process, for_config
from ares.app.stack import prepare
from ares.app.supervisor import STATE_PERIOD_S, SupervisorSettings
from ares.core import config
from ares.core.clock import ManualClock
from ares.core.membus import MemoryNetwork
from ares.core.messages import DriveMode, DriverCommand, ProcessState, ProcessStatus, SupervisorState
from ares.core.node import Node, grid_after
from ares.core.recording import INCARNATION_ENV
from ares.core.route import Route, load_route

READY_WITHIN_S = 60.0  # stack seconds for the stack to be ready to drive (a controller in charge)
TAKE_EVERY_S = 0.1  # the measurements take what was published this often
FAULTS = ("kill", "stop", "hang")  # as Supervisor.inject takes them


@dataclass
class Hosted:
    """One process of the table in this process: its node, when its next step is due, its health."""

    spec: Process
    node: Node | None = None
    due: float = 0.0
    period: float = 0.1
    restarts: int = 0
    failures_in_a_row: int = 0
    last_failure: str = ""
    restart_at: float | None = None  # ended: when its new instance starts
    hung_at: float | None = None  # stands still, alive, since then (until found out)


class InProcessStack:
    def __init__(self, cfg: dict, *, run_dir: Path | None = None, exclude: tuple[str, ...] = ()):
        self.cfg = cfg
        self.route: Route = load_route(config.core(cfg))
        self.clock = ManualClock(0.0)
        self.network = MemoryNetwork(cfg["vehicle_id"])
        self.bus = self.network.bus("supervisor", self.clock)  # the harness's own view of the bus
        self.stale_after_s = config.core(cfg).heartbeat.stale_after_s
        self.backoff_s = config.section(cfg, "supervisor", SupervisorSettings).restart_backoff_s
        self._state = self.bus.publisher("supervisor/state")
        self._next_state = 0.0
        self._changed = True
        self.hosted: dict[str, Hosted] = {}
        # as in a supervised run: the run's configuration in a file that ARES_RUN_CONFIG names, beside
        # which a node keeps what its restart must find (Node.kept_state_path)
        self._own_dir = run_dir is None
        self.run_dir = Path(tempfile.mkdtemp(prefix="ares-in-process-")) if run_dir is None else Path(run_dir)
        self._environ = {key: os.environ.get(key) for key in (config.RUN_CONFIG_ENV, INCARNATION_ENV)}
        os.environ[config.RUN_CONFIG_ENV] = str(config.write_run_config(cfg, self.run_dir / "config.json"))
        try:
            for spec in for_config(cfg):
                if spec.name in exclude or not spec.node_class().steps:
                    continue
                self.hosted[spec.name] = hosted = Hosted(spec)
                self._start(hosted)
        except BaseException:
            self.close()
            raise

    # ---- the processes -------------------------------------------------------------------------
    def _start(self, hosted: Hosted) -> None:
        name = hosted.spec.name
        # a restart knows it is one (the mission manager resumes, the bridge finds its mode): the
        # incarnation is read while the node is built and set up
        os.environ[INCARNATION_ENV] = str(hosted.restarts)
        try:
            node = hosted.spec.node_class()(
                self.cfg, clock=self.clock, bus=self.network.bus(name, self.clock), name=name
            )
            try:
                node.setup()
            except BaseException:
                node.bus.close()
                raise
        finally:
            self._restore(INCARNATION_ENV)
        node.bus.declare_alive()
        now = self.clock.now()
        hosted.node, hosted.hung_at, hosted.restart_at = node, None, None
        hosted.period = 1.0 / node.rate_hz
        hosted.due = grid_after(now, hosted.period)  # as a process joins the lockstep: its first due time
        self._changed = True

    def _end(self, hosted: Hosted, why: str) -> None:
        node = hosted.node
        if node is None:
            return
        hosted.node, hosted.hung_at = None, None
        try:
            self._close_node(node)
        finally:
            delay = self.backoff_s[min(hosted.failures_in_a_row, len(self.backoff_s) - 1)]
            hosted.failures_in_a_row += 1
            hosted.restarts += 1
            hosted.last_failure = why
            hosted.restart_at = self.clock.now() + delay
            self._changed = True

    @staticmethod
    def _close_node(node: Node) -> None:
        try:
            node.teardown()
        finally:
            if node._recorder is not None:  # process replay's recording, as Node.run closes it
                node._recorder.close()
            node.bus.close()

    def inject(self, process: str, fault: str) -> str:
        """A scenario's process fault, as Supervisor.inject takes it: kill, stop or hang."""
        if fault not in FAULTS:
            raise ValueError(f"unknown process fault {fault!r}; known: {', '.join(FAULTS)}")
        hosted = self.hosted.get(process)
        if hosted is None:
            raise KeyError(f"no process {process!r} in this run ({', '.join(self.hosted)})")
        if hosted.node is None or hosted.hung_at is not None:
            return f"{process} is not running: nothing to {fault}"
        if fault == "hang":
            hosted.hung_at = self.clock.now()
            return f"hang {process}: its steps stand still"
        self._end(hosted, "killed by SIGKILL" if fault == "kill" else "exited 0 (SIGTERM)")
        return f"{fault} {process}"

    def _health(self, now: float) -> None:
        for hosted in self.hosted.values():
            if hosted.hung_at is not None and now - hosted.hung_at >= self.stale_after_s:
                self._end(hosted, f"heartbeat stale for {self.stale_after_s:g} s")  # killed, then restarted
            if hosted.node is None and hosted.restart_at is not None and now >= hosted.restart_at:
                self._start(hosted)
        if self._changed or now >= self._next_state:
            self._changed = False
            self._next_state = grid_after(now, STATE_PERIOD_S)
            self._state.put(SupervisorState(t=now, processes=[self._status(h) for h in self.hosted.values()]))

    def _status(self, hosted: Hosted) -> ProcessStatus:
        return ProcessStatus(
            name=hosted.spec.name,
            state=ProcessState.RUNNING if hosted.node is not None else ProcessState.RESTARTING,
            pid=os.getpid(),
            restarts=hosted.restarts,
            last_failure=hosted.last_failure,
            safety_relevant=hosted.spec.safety_relevant,
        )

    # ---- time ------------------------------------------------------------------------------------
    def advance(self, until: float) -> None:
        """Step every node due up to stack time `until`, in time order, and leave the clock there."""
        while True:
            stepping = [h for h in self.hosted.values() if h.node is not None and h.hung_at is None]
            pending = [h.restart_at for h in self.hosted.values() if h.restart_at is not None]
            hanging = [h.hung_at + self.stale_after_s for h in self.hosted.values() if h.hung_at is not None]
            t = min([h.due for h in stepping] + pending + hanging + [self._next_state])
            if t > until:
                break
            self.clock.set(t)
            self._health(t)
            for hosted in self.hosted.values():
                node = hosted.node
                if node is not None and hosted.hung_at is None and hosted.due <= t:
                    node.step_once(t)
                    hosted.due = grid_after(t, hosted.period)
        self.clock.set(until)

    def _take_step(self) -> None:
        self.advance(grid_after(self.clock.now(), TAKE_EVERY_S))

    # ---- driving ---------------------------------------------------------------------------------
    def engage(self) -> None:
        """As a safety driver and the navigation system would, once a controller is in charge:
        the Auto/Manual button (Manual -> Ready), then `set_automatic_mode` (Ready -> Automatic)."""
        car, status = self.bus.subscribe("dbw/car_state"), self.bus.subscribe("control/status")
        try:
            if not self._until(
                lambda: car.latest is not None and status.latest is not None and status.latest.controller != "stop",
                READY_WITHIN_S,
            ):
                why = status.latest.reason if status.latest is not None else "no control/status"
                raise RunFailed(f"no controller in charge within {READY_WITHIN_S:g} s ({why})")
            if car.latest.mode == DriveMode.MANUAL:
                self.bus.call("sim/driver", DriverCommand(t=self.clock.now(), action="BUTTON"))
                if not self._until(lambda: car.latest.mode == DriveMode.READY, 5.0):
                    raise RunFailed("the panel button did not make the bridge Ready")
            reply = self.bus.call("set_automatic_mode")
            if not reply.accepted:
                raise RunFailed(f"Automatic mode refused: {reply.reason}")
            if not self._until(lambda: car.latest.mode == DriveMode.AUTOMATIC, 1.0):
                raise RunFailed(f"the bridge did not go to Automatic ({car.latest.reason})")
        finally:
            self.bus.unsubscribe(car)
            self.bus.unsubscribe(status)

    def _until(self, condition: Callable[[], bool], within_s: float) -> bool:
        end = self.clock.now() + within_s
        while not condition():
            if self.clock.now() >= end:
                return False
            self._take_step()
        return True

    def drive(self, *, laps: int = 1, seconds: float | None = None) -> dict:
        """`ares run --headless` in this process: engage, drive N laps, the open route to its end or
        `seconds` of vehicle time, and return the same figures (ares.app.headless)."""
        m = Measurements(self.cfg, self.route, self.bus, self.inject)
        self.engage()
        t_start = self.clock.now()
        m.begin()
        goal = Goal(m, t_start, laps, seconds)
        try:
            while True:
                self._take_step()
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

    # ---- the end ---------------------------------------------------------------------------------
    def close(self) -> None:
        """Tear every node down (the recorder writes what it holds), leave the bus, and put the
        environment back as it was; every step is tried, the first error is raised at the end."""
        errors: list[BaseException] = []
        for hosted in self.hosted.values():
            node, hosted.node = hosted.node, None
            if node is not None:
                try:
                    self._close_node(node)
                except Exception as exc:
                    errors.append(exc)
        self.bus.close()
        for key in self._environ:
            self._restore(key)
        if self._own_dir:
            shutil.rmtree(self.run_dir, ignore_errors=True)
        if errors:
            raise errors[0]

    def _restore(self, key: str) -> None:
        value = self._environ[key]
        if value is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = value

    def __enter__(self) -> InProcessStack:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="the whole stack in one process: drive, print the figures as JSON")
    parser.add_argument("--seconds", type=float, help="vehicle seconds to drive (default: one lap)")
    parser.add_argument("--laps", type=int, default=1)
    parser.add_argument("--config", action="append", default=[], metavar="FILE", help="as ares run --config")
    parser.add_argument("--store", metavar="URI", help="as ares run --store")
    args = parser.parse_args(argv)
    overrides = {"blackbox_store": {"uri": args.store}} if args.store else {}
    try:
        cfg = prepare(tuple(args.config), overrides, 1.0)
    except config.ConfigError as exc:
        print(f"in_process_stack: {exc}", file=sys.stderr)
        return 2
    with InProcessStack(cfg) as stack:
        print(json.dumps(stack.drive(laps=args.laps, seconds=args.seconds)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
