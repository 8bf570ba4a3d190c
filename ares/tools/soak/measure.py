"""What a soak measures, from the messages the stack publishes (no bus here: the runner feeds them).

| figure                | how                                                                          |
|-----------------------|------------------------------------------------------------------------------|
| time to safe state    | from a fault's injection to the first moment the shuttle is commanded to stop: |
|                       | the movement gate stopping, latched or under a limit of 0, the bridge's      |
|                       | watchdog or emergency, or the board's own fail-safe                          |
| standstill            | ... and to the shuttle standing (< 0.05 m/s)                                 |
| time to recover       | from the injection to the first moment after the fault's end with every      |
|                       | process running, awareness nominal, the gate neither latched nor stopping    |
|                       | and the shuttle moving again (>= 0.5 m/s)                                    |
| overlapped            | injected while the shuttle was not yet back from the one before (or already |
|                       | held): its time to the safe state says nothing, and is left out of the figures |
| availability          | the share of the soak's time the shuttle moved (> 0.05 m/s) or stood at a POI |
|                       | for its actions (the mission AT_POI)                                         |
| lost time per fault   | the time it was not available, given to the fault injected last before      |

Collisions and the movement gate's invariants are ares.app.evaluation.safety_eval's (the runner
feeds a SafetyTracker beside this one).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ares.core.messages import ProcessState
from ares.tools.soak.plan import PlannedFault

MOVING_MPS = 0.05
RESUMED_MPS = 0.5
TIMELINE_PERIOD_S = 1.0  # one point of the picture per stack second
GIVE_UP_S = 600.0  # stack seconds after its end a fault may take to recover before it is written down as not


@dataclass
class FaultOutcome:
    fault: PlannedFault
    at_t: float  # stack time it was injected
    safety_relevant: bool
    injected: bool
    detail: str
    process: str | None = None  # a process fault's process: recovered only once it has been restarted
    restarts_before: int = 0
    overlapped: bool = False
    safe_at: float | None = None
    safe_wall_s: float | None = None  # wall seconds from the injection to the safe state being seen here
    at_wall: float = 0.0
    standstill_at: float | None = None
    recovered_at: float | None = None
    lost_s: float = 0.0
    extra: dict = field(default_factory=dict)

    @property
    def ends_t(self) -> float:
        return self.at_t + self.fault.duration_s

    def as_dict(self) -> dict:
        def after(t: float | None) -> float | None:
            return None if t is None else round(t - self.at_t, 3)

        return {
            **self.fault.as_dict(),
            "t": round(self.at_t, 3),
            "injected": self.injected,
            "detail": self.detail,
            "safety_relevant": self.safety_relevant,
            "overlapped": self.overlapped,
            "time_to_safe_state_s": after(self.safe_at),
            "time_to_safe_state_wall_s": None if self.safe_wall_s is None else round(self.safe_wall_s, 3),
            "time_to_standstill_s": after(self.standstill_at),
            "time_to_recover_s": after(self.recovered_at),
            "lost_s": round(self.lost_s, 2),
            **self.extra,
        }


@dataclass
class SoakTracker:
    """Per fault: its safe state, standstill and recovery; the soak's availability and time line."""

    t_start: float
    faults: list[FaultOutcome] = field(default_factory=list)
    open: list[FaultOutcome] = field(default_factory=list)  # not yet recovered
    v: float = 0.0
    level: int | None = None
    at_poi: bool = False
    all_running: bool = True
    process_states: dict[str, ProcessState] = field(default_factory=dict)
    restarts: dict[str, int] = field(default_factory=dict)
    gate_held: bool = False  # stopping or latched
    stops: dict[str, bool] = field(default_factory=dict)  # each source of a commanded stop: active now?
    last_t: float | None = None
    available_s: float = 0.0
    total_s: float = 0.0
    timeline: list[tuple[float, float, int]] = field(default_factory=list)  # (t, v, level; -1: unknown)

    # ---- inputs -----------------------------------------------------------------------------------
    def add_gate(
        self, t: float, latched: bool, stopping: bool, limit_mps: float | None, wall: float | None = None
    ) -> None:
        self.gate_held = latched or stopping
        self._stop_signal(t, "gate", latched or stopping or limit_mps == 0.0, wall)

    def add_car(self, t: float, watchdog_tripped: bool, emergency: bool, wall: float | None = None) -> None:
        self._stop_signal(t, "bridge", watchdog_tripped or emergency, wall)

    def add_awareness(self, level: int) -> None:
        self.level = level

    def add_mission(self, state: str) -> None:
        self.at_poi = state == "AT_POI"

    def add_processes(self, processes: list[tuple[str, ProcessState, int]]) -> None:
        """The supervisor's view: each process's (name, state, restarts)."""
        self.all_running = all(state == ProcessState.RUNNING for _, state, _ in processes)
        self.process_states = {name: state for name, state, _ in processes}
        self.restarts = {name: restarts for name, _, restarts in processes}

    def add_truth(self, t: float, v: float, board_failsafe: bool, wall: float | None = None) -> None:
        """The simulator's truth: the clock of every figure here."""
        self.v = v
        self._stop_signal(t, "board", board_failsafe, wall)
        if self.last_t is not None and t > self.last_t:
            dt = t - self.last_t
            self.total_s += dt
            if abs(v) > MOVING_MPS or self.at_poi:
                self.available_s += dt
            elif self.faults:
                self.faults[-1].lost_s += dt
        self.last_t = t
        if not self.timeline or t - self.timeline[-1][0] >= TIMELINE_PERIOD_S:
            self.timeline.append((round(t, 2), round(v, 3), -1 if self.level is None else self.level))
        for outcome in list(self.open):
            if outcome.safe_at is not None and outcome.standstill_at is None and abs(v) <= MOVING_MPS:
                outcome.standstill_at = t
            if t >= outcome.ends_t and self.normal() and self.restarted(outcome):
                outcome.recovered_at = t
                self.open.remove(outcome)

    def injected(self, outcome: FaultOutcome, wall: float = 0.0) -> None:
        outcome.at_wall = wall
        if outcome.process is not None:
            outcome.restarts_before = self.restarts.get(outcome.process, 0)
        outcome.overlapped = bool(self.open) or self.held() or not self.normal()
        if self.held() and outcome.safety_relevant:
            outcome.safe_at = outcome.at_t  # held already: it is in its safe state (and overlapped)
        self.faults.append(outcome)
        self.open.append(outcome)

    def give_up(self, now: float, after_s: float) -> None:
        """Faults open longer than after_s (stack time) are left unrecovered: a soak that never gets
        back to normal still writes them down."""
        self.open = [o for o in self.open if now - o.ends_t <= after_s]

    # ---- state --------------------------------------------------------------------------------------
    def restarted(self, outcome: FaultOutcome) -> bool:
        """A process fault is over once the supervisor has restarted the process and it runs again."""
        if outcome.process is None:
            return True
        return (
            self.restarts.get(outcome.process, 0) > outcome.restarts_before
            and self.process_states.get(outcome.process) == ProcessState.RUNNING
        )

    def held(self) -> bool:
        return any(self.stops.values())

    def normal(self) -> bool:
        """Back to normal: everything running, nothing wrong, driving again."""
        return (
            self.all_running
            and self.level == 0
            and not self.gate_held
            and not self.held()
            and (self.v >= RESUMED_MPS or self.at_poi)
        )

    def _stop_signal(self, t: float, source: str, active: bool, wall: float | None = None) -> None:
        self.stops[source] = active
        if not active:
            return
        for outcome in self.open:
            if outcome.safe_at is None and t >= outcome.at_t:
                outcome.safe_at = t
                if wall is not None:
                    outcome.safe_wall_s = wall - outcome.at_wall

    # ---- figures -------------------------------------------------------------------------------------
    def availability(self) -> float | None:
        return None if self.total_s <= 0 else self.available_s / self.total_s


def percentile(values: list[float], q: float) -> float | None:
    return None if not values else round(float(np.percentile(values, q, method="higher")), 3)


def summarise(records: list[dict]) -> dict:
    """The figures per fault kind and in all, from the per-fault records (FaultOutcome.as_dict, or
    the lines of a soak's faults.jsonl: a partial soak is summarised the same way)."""

    def figures(rows: list[dict]) -> dict:
        relevant = [r for r in rows if r["safety_relevant"] and r["injected"] and not r["overlapped"]]
        safe = [r["time_to_safe_state_s"] for r in relevant if r["time_to_safe_state_s"] is not None]
        wall = [r["time_to_safe_state_wall_s"] for r in relevant if r.get("time_to_safe_state_wall_s") is not None]
        recover = [r["time_to_recover_s"] for r in rows if r["time_to_recover_s"] is not None]
        return {
            "injected": sum(r["injected"] for r in rows),
            "planned": len(rows),
            "overlapped": sum(r["overlapped"] for r in rows),
            "safety_relevant": len(relevant),
            "safe_state_missed": len(relevant) - len(safe),
            "time_to_safe_state_max_s": max(safe) if safe else None,
            "time_to_safe_state_p99_s": percentile(safe, 99),
            "time_to_safe_state_p50_s": percentile(safe, 50),
            "time_to_safe_state_wall_max_s": max(wall) if wall else None,
            "time_to_safe_state_wall_p99_s": percentile(wall, 99),
            "not_recovered": sum(r["time_to_recover_s"] is None for r in rows),
            "time_to_recover_p50_s": percentile(recover, 50),
            "time_to_recover_max_s": max(recover) if recover else None,
            "lost_s": round(sum(r["lost_s"] for r in rows), 1),
        }

    kinds = sorted({r["kind"] for r in records})
    return {
        "all": figures(records),
        "per_kind": {kind: figures([r for r in records if r["kind"] == kind]) for kind in kinds},
    }
