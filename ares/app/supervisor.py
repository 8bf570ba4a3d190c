"""The supervisor: starts every process of the stack, notices when one dies or hangs, and
restarts it.

It hosts the embedded Zenoh router in its own session (bus.embedded_router), so the stack
needs no zenohd on a laptop; otherwise it joins the external router like any process.

A process is judged three ways, because each catches what the others miss:
- its exit (Popen.poll): a crash or a kill, with the exact exit code or signal;
- its liveliness token: disappears at once when the process's session dies, or after the
  lease when the process is frozen (SIGSTOP, a stuck machine);
- its heartbeat, sent from the node's loop: the only one that reveals a loop stuck while
  holding the GIL, which keeps the token alive.
A hung process is SIGKILLed (its whole process group) before it is restarted, with a backoff
that grows on repeated failures and starts afresh once a process has stayed up long enough.

A process can also be alive and silent: its heartbeat says when it last published each output
it declares with a rate (ares.core.node). One that has published on such an output and then said
nothing for `silent_after_periods` of its periods (and at least `silent_min_s`, in stack time)
is reported silent in the state and by a `process_silent` event; it is not restarted, because
its silence may be its inputs' (a controller without a fresh pose stays quiet on purpose).

Threading: Zenoh callbacks only record what they saw (a dict entry, a queue item); every
decision, restart, publication and service answer happens on the supervisor's own loop.
Health deadlines are in wall seconds (time.monotonic), never stack time: they judge the
computer, not the simulated vehicle.
"""

from __future__ import annotations

import logging
import math
import os
import queue
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, NamedTuple

from pydantic import Field

import ares
from ares.app.processes import Process, for_config
from ares.core import affinity, config
from ares.core.bus import Bus
from ares.core.clock import Clock, DrivenClock
from ares.core.config import Params, param
from ares.core.messages import Event, EventLevel, Heartbeat, ProcessState, ProcessStatus, SupervisorState
from ares.core.node import NICE_ENV, PROCESS_ENV, setup_logging
from ares.core.recording import INCARNATION_ENV

log = logging.getLogger("supervisor")

NAME = "supervisor"
STATE_PERIOD_S = 0.5  # supervisor/state is published every 0.5 s of wall or stack time
# (--speed max runs the stack clock several times faster: the
# awareness manager judges the state's age in stack time), and on every change
RUN_DIR_ENV = "ARES_RUN_DIR"
# what the supervisor itself reads and writes on the bus (it is not a Node: it hosts the router)
INPUTS = ("heartbeat/*", "sim/clock")  # sim/clock: at --speed max only
OUTPUTS = ("supervisor/state", "events", "heartbeat/supervisor")
SERVICES = ("supervisor/status",)


class SupervisorSettings(Params):
    check_period_s: float = param(0.1, "period of the supervisor's checks", unit="s", gt=0)
    restart_backoff_s: list[Annotated[float, Field(ge=0)]] = param(
        doc="delay before each successive restart of a failing process",
        unit="s",
        factory=lambda: [0.2, 0.5, 1.0, 2.0, 5.0],
        min_length=1,
    )
    backoff_reset_after_s: float = param(
        30.0, "a process that stayed up this long starts its backoff afresh", unit="s", gt=0
    )
    start_grace_s: float = param(15.0, "time a new process has to show its first heartbeat", unit="s", gt=0)
    stop_timeout_s: float = param(3.0, "SIGTERM to SIGKILL when stopping", unit="s", gt=0)
    token_exit_grace_s: float = param(
        0.5,
        "a lost liveliness token waits this long for the process's exit "
        "to be seen (its exit code is the better reason)",
        unit="s",
        gt=0,
    )
    silent_after_periods: float = param(10.0, "an output silent for this many of its periods is reported", gt=0)
    silent_min_s: float = param(2.0, "... and for at least this long (stack time)", unit="s", gt=0)


class Failure(NamedTuple):
    reason: str  # for people: "exited with code 3", "heartbeat stale for 1.2 s"
    exit_code: int | None = None


@dataclass
class Child:
    """What the supervisor knows about one process of the table (its current incarnation)."""

    spec: Process
    state: ProcessState = ProcessState.STOPPED
    proc: subprocess.Popen | None = None
    started_at: float = 0.0  # monotonic time of the current spawn
    running_since: float | None = None  # monotonic time of the first heartbeat of this incarnation
    last_heartbeat: float | None = None  # monotonic receipt time of its latest heartbeat
    token_seen: bool = False  # its liveliness token appeared since this spawn
    token_lost_at: float | None = None  # ... and then disappeared (monotonic time)
    spawns: int = 0
    restarts: int = 0
    failures_in_a_row: int = 0  # picks the backoff; reset after a long healthy run
    backoff_s: float = 0.0  # the delay chosen at the last failure
    restart_at: float = 0.0
    last_exit_code: int | None = None
    last_failure: str = ""
    outputs: dict[str, tuple[float, float | None]] = field(default_factory=dict)  # from its heartbeat
    outputs_at: float = 0.0  # that heartbeat's stamp (the child's stack time)
    silent: list[str] = field(default_factory=list)

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def pid(self) -> int | None:
        return self.proc.pid if self.proc is not None and self.proc.returncode is None else None

    def heartbeat_age(self, now: float) -> float | None:
        return None if self.last_heartbeat is None else now - self.last_heartbeat

    def status(self, now: float) -> ProcessStatus:
        age = self.heartbeat_age(now) if self.state in (ProcessState.STARTING, ProcessState.RUNNING) else None
        return ProcessStatus(
            name=self.name,
            state=self.state,
            pid=self.pid,
            restarts=self.restarts,
            last_exit_code=self.last_exit_code,
            last_failure=self.last_failure,
            safety_relevant=self.spec.safety_relevant,
            heartbeat_age_s=None if age is None else round(age, 3),
            silent=list(self.silent),
        )


def describe_exit(code: int) -> str:
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exited with code {code}"


def _signal_group(pgid: int, sig: int) -> None:
    """Signal a child's whole process group (it leads its own), so that anything it started
    goes too. A group that is already gone is not an error."""
    try:
        os.killpg(pgid, sig)
    except (ProcessLookupError, PermissionError):
        pass


def check_cpus(cpus: config.CpuSettings) -> None:
    """Refuse a `cpus:` section that names CPUs this machine does not let us use."""
    for part in ("vehicle", "simulator", "host"):
        missing = affinity.unavailable(getattr(cpus, part) or [])
        if missing:
            allowed = ", ".join(str(c) for c in sorted(affinity.available()))
            cpus_named = ", ".join(map(str, missing))
            raise config.ConfigError(
                f"cpus.{part}: CPU {cpus_named} is not available here (this process may use {allowed})"
            )


class Supervisor:
    def __init__(self, cfg: dict, processes: list[Process], run_dir: Path, clock: Clock, publishes_state: bool = True):
        """`publishes_state` False: a supervisor beside the vehicle's own on its bus (the simulator
        serving its wires, `ares sim serve`), which must not speak for the vehicle's processes."""
        self.publishes_state = publishes_state
        names = [p.name for p in processes]
        if len(set(names)) != len(names):
            raise ValueError(f"duplicate process names in the table: {names}")
        self.cfg = cfg
        self.clock = clock
        self.run_dir = Path(run_dir).resolve()
        self.log_dir = self.run_dir / "logs"
        self.config_path = self.run_dir / "config.json"
        core = config.core(cfg)
        self.cpus = core.cpus
        check_cpus(self.cpus)
        if self.cpus.host is not None:  # this process: the supervisor, the embedded router, measurements
            affinity.pin_process(self.cpus.host)
        self.settings = sup = config.section(cfg, "supervisor", SupervisorSettings)
        self.check_period_s = sup.check_period_s
        self.backoff_s = list(sup.restart_backoff_s)
        self.backoff_reset_after_s = sup.backoff_reset_after_s
        self.start_grace_s = sup.start_grace_s
        self.stop_timeout_s = sup.stop_timeout_s
        self.stale_after_s = core.heartbeat.stale_after_s
        self.heartbeat_period_s = core.heartbeat.period_s

        self.children: dict[str, Child] = {p.name: Child(p) for p in processes}

        # What Zenoh's threads saw, handed to the loop without blocking them.
        self._heartbeats: dict[str, tuple[float, Heartbeat]] = {}  # process -> (monotonic, latest)
        self._liveliness: queue.SimpleQueue[tuple[str, bool]] = queue.SimpleQueue()

        self._started = False
        self._changed = True
        self._last_state_pub = 0.0
        self._last_state_stack = -math.inf
        self._hb_seq = 0
        self._hb_last = 0.0
        self._liveliness_sub = None
        self._closed = False

        # stop(): a flag any thread or signal handler may set; the work is done once, by the
        # loop if one is running, else by the caller.
        self._stop_requested = threading.Event()
        self._stopped = threading.Event()
        self._shutdown_guard = threading.Lock()
        self._shutdown_ident: int | None = None
        self._loop_ident: int | None = None

        embedded = core.bus.embedded_router
        try:
            self.bus = Bus(cfg, NAME, clock, mode="router" if embedded else None)
        except Exception as exc:
            where = cfg["bus"]["router"]
            what = (
                f"host the embedded router on {where} (is a stack already running?)"
                if embedded
                else f"join the router at {where}"
            )
            raise RuntimeError(f"supervisor cannot {what}: {exc}") from exc

    # ---- lifecycle -------------------------------------------------------------------------
    def start(self) -> None:
        """Write the run config, start listening, and spawn every process of the table."""
        if self._started:
            return
        self._started = True
        config.write_run_config(self.cfg, self.config_path)
        self.log_dir.mkdir(parents=True, exist_ok=True)
        self.bus.subscribe("heartbeat/*", on_message=self._on_heartbeat)
        if isinstance(self.clock, DrivenClock):
            self.bus.subscribe("sim/clock", on_message=lambda _topic, tick: self.clock.advance(tick.t))
        self._liveliness_sub = self.bus.watch_alive(lambda name, alive: self._liveliness.put((name, alive)))
        self.bus.serve("supervisor/status", lambda _request: self.status())
        self.bus.declare_alive()
        for child in self.children.values():
            self._spawn(child)
        self._publish_state()

    def step(self) -> None:
        """One round of checks; call it every check_period_s (run() does)."""
        outer = self._loop_ident is None
        if outer:
            self._loop_ident = threading.get_ident()
        try:
            if self._stop_requested.is_set():
                self._shutdown_once()
                return
            if not self._started:
                self.start()
            now = time.monotonic()
            self._take_heartbeats()
            self._take_liveliness()
            for child in self.children.values():
                if child.state in (ProcessState.STARTING, ProcessState.RUNNING):
                    failure = (
                        self._check_exit(child)
                        or self._check_liveliness(child, now)
                        or self._check_heartbeat(child, now)
                    )
                    if failure is not None:
                        self._fail(child, failure)
                    elif child.state is ProcessState.RUNNING:
                        self._check_silence(child)
                elif child.state is ProcessState.RESTARTING and time.monotonic() >= child.restart_at:
                    self._spawn(child)
            self.bus.poll_services()
            self._own_heartbeat()
            if (
                self._changed
                or time.monotonic() - self._last_state_pub >= STATE_PERIOD_S
                or self.clock.now() - self._last_state_stack >= STATE_PERIOD_S
            ):
                self._publish_state()
        finally:
            if outer:
                self._loop_ident = None

    def run(self, stop_event: threading.Event | None = None) -> None:
        """Check every check_period_s until stop_event is set (then return; the caller calls
        stop()) or stop() is requested (then the loop stops everything before returning)."""
        wake = stop_event if stop_event is not None else self._stop_requested
        self._loop_ident = threading.get_ident()
        try:
            self.start()
            next_t = time.monotonic()
            while not wake.is_set() and not self._stop_requested.is_set():
                self.step()
                next_t += self.check_period_s
                delay = next_t - time.monotonic()
                if delay < 0:  # fell behind (a slow restart): don't catch up in a burst
                    next_t, delay = time.monotonic(), 0.0
                wake.wait(delay)
        except BaseException:
            self._stop_requested.set()  # never leave children behind on a crash
            raise
        finally:
            self._loop_ident = None
            if self._stop_requested.is_set():
                self._shutdown_once()

    def stop(self) -> None:
        """Stop every process: SIGTERM to each group, up to stop_timeout_s, then SIGKILL; close
        the bus (and with it the embedded router). Idempotent. Called from a signal handler
        that interrupted the loop (or a step) it only sets a flag and the loop does the work;
        called from another thread while run() loops, it waits for the loop to finish."""
        self._stop_requested.set()
        me = threading.get_ident()
        if me in (self._loop_ident, self._shutdown_ident):
            return
        if self._loop_ident is not None:
            self._stopped.wait(self.stop_timeout_s + 5.0)
            return
        self._shutdown_once()

    def inject(self, process: str, fault: str) -> str:
        """A scenario's process fault: kill (SIGKILL), stop (SIGTERM: it exits) or hang (SIGSTOP:
        alive, its loop stands still). The supervisor then finds it dead or hung as it would any
        other time. Returns what was done."""
        # busy: SIGUSR1, which a process spawned for a soak (ARES_FAULT_INJECTION=1) answers by
        # busy-looping with the GIL held (ares.core.launch); any other process it would end
        signals = {"kill": signal.SIGKILL, "stop": signal.SIGTERM, "hang": signal.SIGSTOP, "busy": signal.SIGUSR1}
        if process not in self.children:
            raise KeyError(f"no process {process!r} in this run ({', '.join(self.children)})")
        pid = self.children[process].pid
        if pid is None:
            return f"{process} is not running: nothing to {fault}"
        _signal_group(pid, signals[fault])
        return f"{fault} {process} (pid {pid})"

    @property
    def stopping(self) -> bool:
        return self._stop_requested.is_set()

    @property
    def stopped(self) -> bool:
        return self._stopped.is_set()

    # ---- state -------------------------------------------------------------------------------
    def status(self) -> SupervisorState:
        now = time.monotonic()
        return SupervisorState(t=self.clock.now(), processes=[c.status(now) for c in self.children.values()])

    def _publish_state(self) -> None:
        if self._closed or not self.publishes_state:
            return
        self._changed = False
        self._last_state_pub = time.monotonic()
        self._last_state_stack = self.clock.now()
        try:
            self.bus.publish("supervisor/state", self.status())
        except Exception:
            log.exception("could not publish supervisor/state")

    def _own_heartbeat(self) -> None:
        wall = time.time()
        if wall - self._hb_last < self.heartbeat_period_s:
            return
        self._hb_last = wall
        self.bus.publish(
            f"heartbeat/{NAME}",
            Heartbeat(t=self.clock.now(), process=NAME, seq=self._hb_seq, pid=os.getpid(), wall=wall),
        )
        self._hb_seq += 1

    # ---- what Zenoh saw (callbacks: record and return) ---------------------------------------
    def _on_heartbeat(self, topic: str, msg: Heartbeat) -> None:
        self._heartbeats[topic.rsplit("/", 1)[-1]] = (time.monotonic(), msg)

    def _take_heartbeats(self) -> None:
        for child in self.children.values():
            seen = self._heartbeats.get(child.name)
            # only this incarnation's heartbeats count: a late one from the process we just
            # killed must not vouch for its replacement
            if seen is None or child.pid is None or seen[1].pid != child.pid or seen[0] < child.started_at:
                continue
            child.last_heartbeat = seen[0]
            child.outputs, child.outputs_at = seen[1].outputs, seen[1].t
            if child.state is ProcessState.STARTING:
                child.state, child.running_since = ProcessState.RUNNING, seen[0]
                self._changed = True
                log.info("%s running (pid %d)", child.name, child.pid)

    def _take_liveliness(self) -> None:
        while True:
            try:
                name, alive = self._liveliness.get_nowait()
            except queue.Empty:
                return
            child = self.children.get(name)
            # a token change only concerns a live incarnation: the loss of the token of a
            # process already being restarted is old news
            if child is None or child.state not in (ProcessState.STARTING, ProcessState.RUNNING):
                continue
            if alive:
                child.token_seen = True
            elif child.token_seen and child.token_lost_at is None:
                child.token_lost_at = time.monotonic()

    # ---- detection: one method per way of dying -------------------------------------------------
    def _check_exit(self, child: Child) -> Failure | None:
        code = child.proc.poll() if child.proc is not None else None
        return None if code is None else Failure(describe_exit(code), code)

    def _check_liveliness(self, child: Child, now: float) -> Failure | None:
        # A process that exits (or is killed) loses its token a moment before its exit is seen:
        # wait that moment out, so that the more precise reason (the exit code or signal) is the
        # one recorded; a token lost for longer is a process cut off or stopped.
        if child.token_lost_at is None or now - child.token_lost_at < self.settings.token_exit_grace_s:
            return None
        return Failure("liveliness token lost")

    def _check_heartbeat(self, child: Child, now: float) -> Failure | None:
        if child.last_heartbeat is None:
            if now - child.started_at > self.start_grace_s:
                return Failure(f"no heartbeat within {self.start_grace_s:g} s of start")
            return None
        age = now - child.last_heartbeat
        if age > self.stale_after_s:
            return Failure(f"heartbeat stale for {age:.1f} s")
        return None

    def _check_silence(self, child: Child) -> None:
        # judged by the heartbeat's own stamp: both times come from the child's clock, and a child
        # whose heartbeats stop is the liveness check's business, not this one's
        now = child.outputs_at
        silent = []
        for topic, (rate, last) in child.outputs.items():
            # judged once the output has been heard: before its first message a process is waiting
            # for its inputs (a path manager before the first pose), which is not news
            limit = max(self.settings.silent_after_periods / rate, self.settings.silent_min_s)
            if last is not None and now - last > limit:
                silent.append(topic)
        if silent == child.silent:
            return
        began, ended = sorted(set(silent) - set(child.silent)), sorted(set(child.silent) - set(silent))
        child.silent = silent
        self._changed = True
        for topic in began:
            rate = child.outputs[topic][0]
            self._publish_event(
                "process_silent",
                EventLevel.WARNING,
                f"{child.name} is alive but silent on {topic} (declared {rate:g} Hz)",
                process=child.name,
                topic=topic,
                rate_hz=rate,
            )
        for topic in ended:
            self._publish_event(
                "process_output_back",
                EventLevel.INFO,
                f"{child.name} publishes {topic} again",
                process=child.name,
                topic=topic,
            )

    def _publish_event(self, kind: str, level: EventLevel, message: str, **data) -> None:
        log.log(logging.WARNING if level != EventLevel.INFO else logging.INFO, "%s", message)
        try:
            self.bus.publish(
                "events", Event(t=self.clock.now(), source=NAME, kind=kind, level=level, message=message, data=data)
            )
        except Exception:
            log.exception("could not publish the %s event", kind)

    # ---- acting -------------------------------------------------------------------------------
    def _fail(self, child: Child, failure: Failure) -> None:
        now = time.monotonic()
        code = self._kill(child)  # a hung process is still there: it must go first
        exit_code = failure.exit_code if failure.exit_code is not None else code
        healthy_for = now - child.running_since if child.running_since is not None else 0.0
        if healthy_for >= self.backoff_reset_after_s:
            child.failures_in_a_row = 0
        delay = self.backoff_s[min(child.failures_in_a_row, len(self.backoff_s) - 1)] if self.backoff_s else 0.0
        child.failures_in_a_row += 1
        child.backoff_s = delay
        child.restart_at = now + delay
        child.state = ProcessState.RESTARTING
        child.silent = []
        child.outputs = {}
        child.last_failure = failure.reason
        child.last_exit_code = exit_code
        self._changed = True
        level = EventLevel.FAULT if child.spec.safety_relevant else EventLevel.WARNING
        log.warning("%s failed: %s; restarting in %.1f s", child.name, failure.reason, delay)
        try:
            self.bus.publish(
                "events",
                Event(
                    t=self.clock.now(),
                    source=NAME,
                    kind="process_restart",
                    level=level,
                    message=f"{child.name}: {failure.reason}; restarting in {delay:g} s",
                    data={
                        "process": child.name,
                        "reason": failure.reason,
                        "exit_code": exit_code,
                        "restarts": child.restarts,
                        "backoff_s": delay,
                        "safety_relevant": child.spec.safety_relevant,
                    },
                ),
            )
        except Exception:
            log.exception("could not publish the restart event of %s", child.name)

    def _kill(self, child: Child) -> int | None:
        """SIGKILL the child's group if it is still there; reap it. Returns its exit code."""
        proc = child.proc
        if proc is None:
            return None
        if proc.poll() is None:
            _signal_group(proc.pid, signal.SIGKILL)
            try:
                proc.wait(timeout=2.0)
            except subprocess.TimeoutExpired:  # stuck in the kernel; subprocess reaps it later
                log.error("%s (pid %d) survived SIGKILL for 2 s", child.name, proc.pid)
        _signal_group(proc.pid, signal.SIGKILL)  # whatever it left behind in its group
        return proc.returncode

    def _cpus_of(self, spec: Process) -> list[int] | None:
        return self.cpus.simulator if spec.sim_only else self.cpus.vehicle

    def _spawn(self, child: Child) -> None:
        spec = child.spec
        env = dict(os.environ)
        env.update(self.clock.env())
        # children import the same `ares` as the supervisor, wherever they are started from
        root = str(Path(ares.__file__).resolve().parent.parent)
        env["PYTHONPATH"] = os.pathsep.join(p for p in (root, env.get("PYTHONPATH", "")) if p)
        # a dozen processes on a few cores: a BLAS thread pool per process only fights the others
        # (a 3 x 3 product over a LiDAR sweep took 30 ms instead of 1 ms while the other core was busy)
        for pool in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
            env.setdefault(pool, "1")
        env.update(
            {
                config.RUN_CONFIG_ENV: str(self.config_path),
                PROCESS_ENV: spec.name,
                NICE_ENV: str(spec.nice),
                affinity.CPUS_ENV: affinity.as_env(self._cpus_of(spec)),
                INCARNATION_ENV: str(child.spawns),
                "PYTHONUNBUFFERED": "1",
            }
        )
        attempt = "start" if child.spawns == 0 else f"restart {child.restarts + 1}"
        try:
            with (self.log_dir / f"{spec.name}.log").open("ab") as out:
                out.write(
                    f"==== {time.strftime('%Y-%m-%d %H:%M:%S')} supervisor: {attempt} of "
                    f"{spec.name} ({spec.node})\n".encode()
                )
                out.flush()
                # its own process group: the terminal's Ctrl-C reaches the supervisor only,
                # which then stops the children in order
                proc = subprocess.Popen(
                    [sys.executable, "-m", "ares.core.launch", spec.node],
                    env=env,
                    stdin=subprocess.DEVNULL,
                    stdout=out,
                    stderr=subprocess.STDOUT,
                    process_group=0,
                    close_fds=True,
                )
        except OSError as exc:
            child.proc = None
            child.started_at = time.monotonic()
            self._fail(child, Failure(f"could not start: {exc}"))
            return
        if child.spawns > 0:
            child.restarts += 1
        child.spawns += 1
        child.proc = proc
        child.state = ProcessState.STARTING
        child.started_at = time.monotonic()
        child.running_since = child.last_heartbeat = None
        child.token_seen, child.token_lost_at = False, None
        self._changed = True
        log.info("%s %s (pid %d)", attempt, spec.name, proc.pid)

    def _shutdown_once(self) -> None:
        if not self._shutdown_guard.acquire(blocking=False):
            if threading.get_ident() != self._shutdown_ident:
                self._stopped.wait(self.stop_timeout_s + 5.0)  # another thread is doing it
            return
        self._shutdown_ident = threading.get_ident()
        try:
            self._shutdown()
        finally:
            self._stopped.set()

    def _shutdown(self) -> None:
        live = [c for c in self.children.values() if c.proc is not None and c.proc.poll() is None]
        for child in live:
            _signal_group(child.proc.pid, signal.SIGTERM)
        deadline = time.monotonic() + self.stop_timeout_s
        while any(c.proc.poll() is None for c in live) and time.monotonic() < deadline:
            time.sleep(0.02)
        for child in self.children.values():
            if child.proc is not None:
                if child.proc.poll() is None:
                    log.warning(
                        "%s (pid %d) ignored SIGTERM for %.1f s: SIGKILL",
                        child.name,
                        child.proc.pid,
                        self.stop_timeout_s,
                    )
                code = self._kill(child)
                if child in live:
                    child.last_exit_code = code
            child.state = ProcessState.STOPPED
        self._changed = True
        self._publish_state()
        self._closed = True
        try:
            self.bus.close()
        except Exception:
            log.exception("error closing the bus")
        log.info("stopped")


def serve_until_stopped(supervisor: Supervisor, banner: str, stop: threading.Event | None = None) -> int:
    """Run `supervisor` in the foreground until `stop` or SIGINT/SIGTERM (the fleet server, the
    simulator serving its wires): its processes started, `banner` printed, then stopped; 0."""
    logging.basicConfig(
        level=os.environ.get("ARES_LOG_LEVEL", "INFO"),
        format="%(asctime)s %(name)s %(levelname)s: %(message)s",
        stream=sys.stderr,
    )
    stop = stop or threading.Event()
    previous = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        supervisor.start()
        print(banner, file=sys.stderr, flush=True)
        supervisor.run(stop)
    finally:
        supervisor.stop()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return 0


def default_run_dir() -> Path:
    return Path(os.environ.get(RUN_DIR_ENV) or Path("runs") / time.strftime("%Y%m%d-%H%M%S"))


def main() -> None:
    """`python -m ares.app.supervisor`: the whole table on the run's config (ARES_RUN_CONFIG, else
    the defaults) until SIGINT/SIGTERM."""
    setup_logging(NAME)
    cfg = config.current()
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    supervisor = Supervisor(cfg, for_config(cfg), default_run_dir(), Clock.from_env())
    try:
        supervisor.start()
        supervisor.run(stop)
    finally:
        supervisor.stop()


if __name__ == "__main__":
    main()
