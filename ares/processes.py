"""Every process of the stack, in one declarative table (started in this order).

`rate_key` names the config entry holding the process's loop rate (stack Hz);
`safety_relevant` processes are the ones whose loss must bring the vehicle to a safe state.
The simulator runs only in simulation (`sim_only`). The embedded Zenoh router is not listed:
the supervisor hosts it in its own session.
"""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class ProcessSpec:
    name: str
    module: str                 # run as `python -m <module>`; the module's main() runs the node
    rate_key: str | None
    safety_relevant: bool
    sim_only: bool = False


PROCESSES: list[ProcessSpec] = [
    ProcessSpec("sim", "ares.sim.node", "sim.physics_hz", safety_relevant=True, sim_only=True),
    ProcessSpec("gnss", "perception.gnss_node", "gnss.rate_hz", safety_relevant=True),
    ProcessSpec("localization", "perception.localization", "localization.rate_hz", safety_relevant=True),
    ProcessSpec("odometry_manager", "managers.odometry", "odometry_manager.rate_hz", safety_relevant=True),
    ProcessSpec("path_manager", "managers.path", "path_manager.rate_hz", safety_relevant=True),
    ProcessSpec("dbw_bridge", "control.dbw_bridge", "dbw.rate_hz", safety_relevant=True),
    ProcessSpec("controller", "control.pure_pursuit", "controller.rate_hz", safety_relevant=True),
    # the black box: losing it never stops the vehicle (the recorder spools; see blackbox/recorder.py)
    ProcessSpec("blackbox", "blackbox.recorder", "blackbox.rate_hz", safety_relevant=False),
    ProcessSpec("api", "blackbox.api_server", None, safety_relevant=False),
]


def by_name(name: str) -> ProcessSpec:
    for spec in PROCESSES:
        if spec.name == name:
            return spec
    raise KeyError(f"unknown process {name!r}; known: {', '.join(p.name for p in PROCESSES)}")
