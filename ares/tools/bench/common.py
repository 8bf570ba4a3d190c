"""What every benchmark reports alike: percentiles, the versions it ran with."""

from __future__ import annotations

import math
import platform
from importlib import metadata


class BenchError(RuntimeError):
    pass


def percentile(sorted_values: list[float], q: float) -> float:
    """Nearest-rank percentile of an already sorted list (q in 0..100)."""
    if not sorted_values:
        return float("nan")
    rank = max(1, min(len(sorted_values), math.ceil(q / 100.0 * len(sorted_values))))
    return sorted_values[rank - 1]


def versions(*distributions: str) -> dict:
    """Python's and each distribution's version ("eclipse-zenoh" reported as "zenoh")."""
    out = {"python": platform.python_version()}
    for dist in distributions:
        try:
            out[dist.replace("eclipse-", "")] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist.replace("eclipse-", "")] = None
    return out
