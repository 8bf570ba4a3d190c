"""`ares run --fleet N`: N simulated shuttles on one router, for the fleet page.

Each shuttle is a whole stack of its own (its supervisor, simulator and every process, its REST
API on its own port) under its own vehicle id; they share the router the first one hosts, the
clock and the black box store (the fleet's records side by side, as a depot's store would hold
them). They start at different places of the route (past a POI, clear of the RTK-loss zones and
crossings) so the map shows them apart. Interactive only, at real time or scaled (`--speed max`
has each simulator drive the clock: one clock cannot have N drivers).
"""

from __future__ import annotations

import re
import threading
import time
from pathlib import Path

from ares.app import processes
from ares.app.supervisor import Supervisor
from ares.core import config
from ares.core.clock import Clock
from ares.core.messages import ProcessState

# where along the default tour each shuttle starts (m): the depot, then past POIs, clear of zones
START_S_M = (0.0, 340.0, 710.0, 1460.0, 800.0, 1000.0, 400.0, 250.0)
MAX_FLEET = len(START_S_M)
STARTUP_WAIT_S = 40.0  # wall seconds for one shuttle's processes to come up before the next starts


def fleet_ids(first: str, n: int) -> list[str]:
    """shuttle01 -> shuttle01, shuttle02, ...; another id gets -2, -3 ..."""
    m = re.fullmatch(r"(.*?)(\d+)", first)
    if m:
        stem, digits = m[1], m[2]
        return [f"{stem}{int(digits) + i:0{len(digits)}d}" for i in range(n)]
    return [first] + [f"{first}-{i + 1}" for i in range(1, n)]


def fleet_configs(cfg: dict, n: int, route_length_m: float) -> list[dict]:
    """The first vehicle's configuration made into n: ids, API ports, starts, the shared router."""
    if not 1 <= n <= MAX_FLEET:
        raise config.ConfigError(f"--fleet takes 1 to {MAX_FLEET} shuttles")
    out = []
    for i, vehicle_id in enumerate(fleet_ids(cfg["vehicle_id"], n)):
        one = config.deep_merge(
            cfg,
            {
                "vehicle_id": vehicle_id,
                "sim": {"start_s_m": START_S_M[i] % max(route_length_m, 1.0)},
                "api": {"port": int(cfg["api"]["port"]) + i},
            },
        )
        if i > 0:  # the first hosts the router (or all join the external one)
            one["bus"] = {**one["bus"], "embedded_router": False}
        out.append(one)
    return out


def start_fleet(
    cfgs: list[dict],
    clock: Clock,
    run_dir: Path,
    stop: threading.Event,
    up_timeout_s: float = STARTUP_WAIT_S,
    started: list | None = None,
) -> list[Supervisor]:
    """Start every shuttle's supervisor (the router's host first) and its loop thread, one shuttle
    at a time: each waits until the one before has every process running (all at once, 15
    processes a shuttle starting on two cores miss their first heartbeat and are restarted).
    `started` is filled as they start, so that a failure midway leaves the caller what to stop."""
    supervisors = started if started is not None else []
    for cfg in cfgs:
        sup = Supervisor(cfg, processes.for_config(cfg), run_dir / cfg["vehicle_id"], clock)
        sup.start()
        threading.Thread(target=sup.run, args=(stop,), name=f"supervisor-{cfg['vehicle_id']}", daemon=True).start()
        supervisors.append(sup)
        deadline = time.monotonic() + up_timeout_s
        while not stop.is_set() and time.monotonic() < deadline and not all_running(sup):
            time.sleep(0.2)
    return supervisors


def all_running(sup: Supervisor) -> bool:
    return all(p.state is ProcessState.RUNNING for p in sup.status().processes)
