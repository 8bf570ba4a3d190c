"""A soak's fault plan: which fault, when, on what and for how long, from a seed alone.

`fault_plan(seed, hours, count, ...)` is a pure function: the same arguments give the same plan.
The soak's time is cut into `count` equal slots, one fault per slot; the kinds come round in
turn, each round a shuffle of every kind, so that every kind is injected about as often as the
others; each fault begins within the first quarter of its slot and lasts at most half of it, so
that at least a quarter of a slot (and of every slot after a long one) is left to handle it,
recover and move on before the next begins. Times are seconds from the soak's start, in stack
(vehicle) time.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np

MIN_SLOT_S = 4.0  # shorter slots leave no time to handle a fault before the next


@dataclass(frozen=True)
class FaultKind:
    doc: str
    duration_s: tuple[float, float]  # how long it holds, drawn in this range (0, 0: a moment)
    safety_relevant: bool  # the shuttle must reach its safe state (the movement gate stops it)
    target: str | None = None  # "process" or "lidar": it picks one; None: it has none
    needs_lidars: bool = False


KINDS: dict[str, FaultKind] = {
    "kill_process": FaultKind("SIGKILL a process", (0.0, 0.0), True, "process"),
    "hang_process": FaultKind("SIGSTOP a process: alive, its loop stands still", (0.0, 0.0), True, "process"),
    "busy_process": FaultKind("a process busy-looping while it holds the GIL", (0.0, 0.0), True, "process"),
    "gnss_outage": FaultKind("no GNSS fix at all", (5.0, 30.0), False),
    "rtk_loss": FaultKind("no RTK corrections: a float fix", (10.0, 60.0), False),
    "imu_frozen": FaultKind("the IMU repeats its last reading", (2.0, 10.0), True),
    "lidar_covered": FaultKind("an opaque cover over one LiDAR", (2.0, 8.0), True, "lidar", needs_lidars=True),
    "lidar_silent": FaultKind(
        "the simulated LiDARs' process killed: every LiDAR silent until it is back", (0.0, 0.0), True, None, True
    ),
    "router_restart": FaultKind("the Zenoh router killed and started again", (0.5, 3.0), False),
    "store_unavailable": FaultKind("the black box's store locked: no write gets through", (5.0, 40.0), False),
    "bad_api_burst": FaultKind(
        "a burst of bad requests to the black box's API (bad tokens, routes, ranges)", (0.0, 0.0), False
    ),
    "pedestrian_in_path": FaultKind(
        "a pedestrian crossing the road ahead of the shuttle", (8.0, 20.0), False, needs_lidars=True
    ),
    "parked_object_in_path": FaultKind(
        "a parked cart on the path ahead, later driven away", (5.0, 25.0), False, needs_lidars=True
    ),
}
OBSTACLE_KINDS = ("pedestrian_in_path", "parked_object_in_path")
# where they appear ahead of the shuttle's rear axle (m): far enough to stop before them (the front bumper
# is ~3 m further on; from 4 m/s the shuttle needs ~10 m), near enough that a pedestrian who stops in the
# middle of the road for a while (runner.py) is still there when the shuttle would come
AHEAD_M = {"pedestrian_in_path": (25.0, 35.0), "parked_object_in_path": (18.0, 30.0)}


def kinds_for(lidars: bool) -> list[str]:
    """Every kind a stack with (or without) LiDARs can take."""
    return [name for name, kind in KINDS.items() if lidars or not kind.needs_lidars]


@dataclass(frozen=True)
class PlannedFault:
    index: int
    at_s: float  # from the soak's start, stack time
    kind: str
    duration_s: float
    target: str | None = None  # the process or the LiDAR
    requests: int = 0  # bad_api_burst: how many
    ahead_m: float = 0.0  # obstacles: how far ahead of the shuttle they appear

    @property
    def ends_s(self) -> float:
        return self.at_s + self.duration_s

    def as_dict(self) -> dict:
        return {k: v for k, v in asdict(self).items() if v not in (None, 0, 0.0) or k in ("index", "at_s")}


def fault_plan(
    seed: int,
    hours: float,
    count: int,
    kinds: Sequence[str],
    processes: Sequence[str] = (),
    lidars: Sequence[str] = (),
) -> list[PlannedFault]:
    """`count` faults over `hours` of stack time, of the given kinds, on the given processes and
    LiDARs (see the module's docstring). ValueError if they do not fit."""
    if count < 1 or hours <= 0:
        raise ValueError("a soak needs at least one fault and some time")
    unknown = sorted(set(kinds) - set(KINDS))
    if unknown or not kinds:
        raise ValueError(f"unknown fault kinds: {unknown}" if unknown else "no fault kinds")
    slot = hours * 3600.0 / count
    if slot < MIN_SLOT_S:
        raise ValueError(
            f"{count} faults in {hours:g} h leave {slot:.1f} s per fault: at least {MIN_SLOT_S:g} s are needed"
        )
    for name in kinds:
        if KINDS[name].target == "process" and not processes:
            raise ValueError(f"{name} needs processes to pick from")
        if KINDS[name].target == "lidar" and not lidars:
            raise ValueError(f"{name} needs LiDARs to pick from")
    rng = np.random.default_rng(seed)
    ordered = sorted(kinds)  # the caller's order does not change the plan
    plan: list[PlannedFault] = []
    while len(plan) < count:
        for name in rng.permutation(ordered):
            if len(plan) == count:
                break
            kind = KINDS[str(name)]
            index = len(plan)
            low, high = kind.duration_s
            duration = round(min(float(rng.uniform(low, high)), slot / 2), 2)
            at = round(index * slot + float(rng.uniform(0.0, slot / 4)), 2)
            target = None
            if kind.target == "process":
                target = str(processes[int(rng.integers(len(processes)))])
            elif kind.target == "lidar":
                target = str(lidars[int(rng.integers(len(lidars)))])
            plan.append(
                PlannedFault(
                    index=index,
                    at_s=at,
                    kind=str(name),
                    duration_s=duration,
                    target=target,
                    requests=int(rng.integers(20, 61)) if name == "bad_api_burst" else 0,
                    ahead_m=round(float(rng.uniform(*AHEAD_M[str(name)])), 1) if name in OBSTACLE_KINDS else 0.0,
                )
            )
    return plan
