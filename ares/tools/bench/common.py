"""What every benchmark reports alike: the versions it ran with, its goals and whether each was
met (percentiles: ares.core.stats)."""

from __future__ import annotations

import platform
from dataclasses import dataclass
from importlib import metadata

from ares.core.stats import percentile

__all__ = ["BenchError", "Goal", "figure", "judge", "missed_goals", "percentile", "versions"]


class BenchError(RuntimeError):
    pass


@dataclass(frozen=True)
class Goal:
    """A bound on one figure of a bench's result: at most `limit`, or at least it."""

    limit: float
    at_least: bool = False

    def met(self, value: object) -> bool:
        if not isinstance(value, int | float):  # no figure (JSON null): nothing met
            return False
        return value >= self.limit if self.at_least else value <= self.limit

    def as_json(self) -> dict[str, float]:
        return {"at_least" if self.at_least else "at_most": self.limit}


def figure(result: dict, path: str) -> object:
    """The value at a dotted path of a result (`lidar.VLP-16.p50_ms`), None where it has none."""
    value: object = result
    for part in path.split("."):
        if not isinstance(value, dict) or part not in value:
            return None
        value = value[part]
    return value


def judge(result: dict, goals: dict[str, Goal]) -> dict:
    """The result, with its `goals` (each `{"at_most"|"at_least": limit}`, by the figure's dotted
    path) and `goals_met` (each goal's verdict) added."""
    result["goals"] = {path: goal.as_json() for path, goal in goals.items()}
    result["goals_met"] = {path: goal.met(figure(result, path)) for path, goal in goals.items()}
    return result


def missed_goals(result: dict) -> list[str]:
    """One line per goal the result missed (`figure value, goal at most limit`), from its JSON form
    alone: a result read back from a file is judged the same."""
    missed = []
    for path, met in result.get("goals_met", {}).items():
        if met:
            continue
        bound = result.get("goals", {}).get(path, {})
        limit = ", ".join(f"goal {side.replace('_', ' ')} {value:g}" for side, value in bound.items())
        missed.append(f"{path} {figure(result, path)}" + (f", {limit}" if limit else ""))
    return missed


def versions(*distributions: str) -> dict:
    """Python's and each distribution's version ("eclipse-zenoh" reported as "zenoh")."""
    out = {"python": platform.python_version()}
    for dist in distributions:
        try:
            out[dist.replace("eclipse-", "")] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist.replace("eclipse-", "")] = None
    return out
