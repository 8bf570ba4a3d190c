"""Awareness manager: how well the shuttle knows itself (ARES §3.7), every 0.5 s.

Sensor awareness from the sensors' own messages (the IMU's and GNSS's rates and readings, the
LiDARs' rates and road points from perception's status) and software awareness from the
supervisor's table of processes (every safety-relevant process must be running; the supervisor
restarts one that is not), and the black box's own status (a record lost is level 2). The checks
and their thresholds are in managers/awareness.py.
The level goes to the movement manager, which acts on it (1: emergency stop until re-armed; 2:
a controlled stop, resumed by itself), and to the black box; every change of level is an event
with its causes.
"""

from __future__ import annotations

import re

from ares.core.messages import AwarenessState, EventLevel
from ares.core.node import Input, Node, Output
from managers.awareness import CRITICAL, NOMINAL, AwarenessChecks, AwarenessParams

LEVEL_NAMES = {NOMINAL: "nominal", CRITICAL: "level 1 (critical)", 2: "level 2 (low)"}


def _kinds(causes: list[str]) -> list[str]:
    """The causes without their figures: "no RTK corrections for 301 s" is the cause it was a
    second before (an event each second would bury the ones that matter)."""
    return [re.sub(r"\d+(\.\d+)?", "#", cause) for cause in causes]


class AwarenessManager(Node):
    """Sensor and software self-awareness: a level (0, 1 critical, 2 low) and its causes."""

    name = "awareness_manager"
    Params = AwarenessParams
    imu = Input("sensors/imu", queue=256, doc="rate; frozen readings")
    gnss = Input("gnss/fix", queue=64, doc="rate, variance, RTK corrections")
    corrections = Input("gnss/corrections", doc="the corrections' link and age: the named cause of a loss of RTK")
    lidar = Input("perception/lidar_status", doc="each LiDAR's rate and road points")
    supervisor = Input("supervisor/state", doc="every process's state")
    blackbox = Input("blackbox/status", queue=8, doc="the black box's writer: a store down, records lost")
    state = Output("awareness/state", rate="rate_hz", doc="the level and its causes")

    def setup(self) -> None:
        lidars = sorted(self.vehicle.lidars) if self.core.lidars else []
        self.checks = AwarenessChecks(self.params, lidars, started_at=self.clock.now())
        self._level = NOMINAL
        self._causes: list[str] = []

    def step(self, now: float) -> None:
        for _, imu in self.imu.drain():
            self.checks.on_imu(imu)
        for _, fix in self.gnss.drain():
            self.checks.on_gnss(fix)
        self.checks.on_corrections(self.corrections.latest)
        for _, status in self.blackbox.drain():
            self.checks.on_blackbox(status)
        found = self.checks.assess(now, self.lidar.latest, self.supervisor.latest)
        if found.level != self._level or (found.level != NOMINAL and _kinds(found.causes) != _kinds(self._causes)):
            level = (
                EventLevel.INFO
                if found.level == NOMINAL
                else EventLevel.FAULT
                if found.level == CRITICAL
                else EventLevel.WARNING
            )
            text = LEVEL_NAMES[found.level] + (": " + "; ".join(found.causes) if found.causes else "")
            self.event("awareness", text, level, level_from=self._level, level_to=found.level)
        self._level, self._causes = found.level, found.causes
        self.state.put(
            AwarenessState(
                t=now, level=found.level, causes=found.causes, sensors=found.sensors, processes=found.processes
            )
        )
