"""What every benchmark reports alike: the versions it ran with (percentiles: ares.core.stats)."""

from __future__ import annotations

import platform
from importlib import metadata

from ares.core.stats import percentile

__all__ = ["BenchError", "percentile", "versions"]


class BenchError(RuntimeError):
    pass


def versions(*distributions: str) -> dict:
    """Python's and each distribution's version ("eclipse-zenoh" reported as "zenoh")."""
    out = {"python": platform.python_version()}
    for dist in distributions:
        try:
            out[dist.replace("eclipse-", "")] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist.replace("eclipse-", "")] = None
    return out
