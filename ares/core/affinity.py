"""Which CPUs a process may run on (Linux's CPU affinity), for a run that gives the vehicle's own
processes a computer's share of this machine and the simulated shuttle the rest (`cpus:`).

A process is pinned as a whole: every thread it already has (Zenoh's, a thread pool's) and,
since threads inherit their creator's affinity, every thread it makes later. The supervisor tells
each child its CPUs through ARES_CPUS; the child pins itself before importing its node, so that
the threads numpy, open3d or Zenoh start are pinned from their birth.
"""

from __future__ import annotations

import os
from collections.abc import Iterable

CPUS_ENV = "ARES_CPUS"  # "0" or "0,2": the CPUs of this process; unset or empty: any


def available() -> set[int]:
    """The CPUs this process may run on now."""
    return set(os.sched_getaffinity(0))


def unavailable(cpus: Iterable[int]) -> list[int]:
    """Those of `cpus` this machine does not let us use."""
    return sorted(set(cpus) - available())


def pin_process(cpus: Iterable[int]) -> None:
    """Pin every thread of this process to `cpus`."""
    chosen = set(cpus)
    for task in os.listdir("/proc/self/task"):
        try:
            os.sched_setaffinity(int(task), chosen)
        except ProcessLookupError:  # a thread that ended meanwhile
            pass


def as_env(cpus: Iterable[int] | None) -> str:
    return ",".join(str(c) for c in sorted(set(cpus))) if cpus is not None else ""


def from_env() -> list[int] | None:
    text = os.environ.get(CPUS_ENV, "").strip()
    return [int(part) for part in text.split(",")] if text else None


def pin_from_env() -> None:
    """ARES_CPUS, if the supervisor set it."""
    cpus = from_env()
    if cpus is not None:
        pin_process(cpus)
