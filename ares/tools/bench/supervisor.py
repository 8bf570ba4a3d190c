"""`ares bench supervisor`: how fast the supervisor notices a dead or hung process and has it
running again, measured (the tests check that it does, not how fast).

Each round starts a supervisor hosting its router on a free port over three ticker nodes
(ares.tools.bench.ticker), then:
- SIGKILL one: time until its replacement sends its first heartbeat (running again);
- SIGSTOP one: time until it is noticed (its liveliness token lapses with the lease);
- make one busy-loop holding the GIL: time until it is noticed (only its heartbeat tells).
Wall seconds from the signal, medians over the rounds.
"""

from __future__ import annotations

import os
import signal
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from ares.app import run_config
from ares.app.processes import Process
from ares.app.supervisor import Supervisor
from ares.core import config
from ares.core.clock import WallClock
from ares.core.localhost import free_port
from ares.core.messages import ProcessState
from ares.tools.bench.common import BenchError, percentile, versions
from ares.tools.bench.ticker import CONTROL_DIR_ENV, control_file

TICKER = "ares.tools.bench.ticker:Ticker"


def _drive(sup: Supervisor, condition: Callable[[], bool], timeout_s: float, what: str) -> float:
    """Run the supervisor's checks until condition(); the wall seconds it took."""
    started = time.monotonic()
    while not condition():
        if time.monotonic() - started > timeout_s:
            raise BenchError(f"timed out after {timeout_s:g} s waiting for {what}")
        sup.step()
        time.sleep(sup.check_period_s / 4)
    return time.monotonic() - started


def _round(control_dir: Path) -> dict:
    cfg = run_config.build(
        overrides={"bus": {"router": f"tcp/127.0.0.1:{free_port()}"}, "supervisor": {"restart_backoff_s": [0.0]}}
    )
    names = ("victim", "frozen", "spinner")
    with tempfile.TemporaryDirectory(prefix="ares-bench-sup-") as run_dir:
        sup = Supervisor(cfg, [Process(n, TICKER, safety_relevant=True) for n in names], Path(run_dir), WallClock())
        try:
            sup.start()
            running = lambda name: sup.children[name].state is ProcessState.RUNNING  # noqa: E731
            start_s = _drive(sup, lambda: all(running(n) for n in names), 60, "every ticker running")
            old = sup.children["victim"].pid
            os.kill(old, signal.SIGKILL)
            killed_s = _drive(
                sup,
                lambda: running("victim") and sup.children["victim"].pid != old,
                30,
                "the killed ticker running again",
            )
            os.kill(sup.children["frozen"].pid, signal.SIGSTOP)
            stopped_s = _drive(
                sup, lambda: sup.children["frozen"].state is ProcessState.RESTARTING, 30, "the stopped ticker noticed"
            )
            stopped_reason = sup.children["frozen"].last_failure
            control_file(control_dir, "spinner").write_text("hang")
            hung_s = _drive(
                sup, lambda: sup.children["spinner"].state is ProcessState.RESTARTING, 30, "the hung ticker noticed"
            )
            hung_reason = sup.children["spinner"].last_failure
        finally:
            sup.stop()
    return {
        "start_all_s": start_s,
        "sigkill_running_again_s": killed_s,
        "sigstop_noticed_s": stopped_s,
        "sigstop_reason": stopped_reason,
        "gil_hang_noticed_s": hung_s,
        "gil_hang_reason": hung_reason,
    }


def run_supervisor_bench(rounds: int = 3, progress: Callable[[str], None] | None = None) -> dict:
    say = progress or (lambda _msg: None)
    results = []
    with tempfile.TemporaryDirectory(prefix="ares-bench-control-") as control:
        previous = os.environ.get(CONTROL_DIR_ENV)
        os.environ[CONTROL_DIR_ENV] = control  # the tickers read their orders there
        try:
            for k in range(rounds):
                for leftover in Path(control).iterdir():
                    leftover.unlink()
                say(f"round {k + 1} of {rounds}: start, SIGKILL, SIGSTOP, a loop holding the GIL")
                results.append(_round(Path(control)))
        finally:
            if previous is None:
                os.environ.pop(CONTROL_DIR_ENV, None)
            else:
                os.environ[CONTROL_DIR_ENV] = previous
    defaults = config.core_defaults()
    out: dict = {"bench": "supervisor", "rounds": rounds}
    for key in ("start_all_s", "sigkill_running_again_s", "sigstop_noticed_s", "gil_hang_noticed_s"):
        values = [r[key] for r in results]
        out[f"{key}_median"] = percentile(values, 50, 3)
        out[f"{key}_all"] = [round(v, 3) for v in values]
    out["sigstop_reasons"] = sorted({r["sigstop_reason"] for r in results})
    out["gil_hang_reasons"] = sorted({r["gil_hang_reason"] for r in results})
    out["lease_ms"] = defaults["bus"]["lease_ms"]
    out["heartbeat_stale_after_s"] = defaults["heartbeat"]["stale_after_s"]
    out["cpus"] = os.cpu_count()
    out.update(versions("eclipse-zenoh"))
    return out
