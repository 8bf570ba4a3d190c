"""What every benchmark reports alike: percentiles, the versions it ran with."""

from __future__ import annotations

import platform
from collections.abc import Sequence
from importlib import metadata

import numpy as np


class BenchError(RuntimeError):
    pass


def percentile(values: Sequence[float] | np.ndarray, q: float, ndigits: int | None = None) -> float | None:
    """The q-th percentile (q in 0..100) of `values` as numpy defines it (np.percentile's default,
    linear method: between the two nearest ranks, so p50 is the median), rounded to `ndigits` if
    given; None when there are no values. The one definition the benches, the evaluations and the
    harnesses report."""
    data = np.asarray(values, dtype=float)
    if data.size == 0:
        return None
    value = float(np.percentile(data, q))
    return round(value, ndigits) if ndigits is not None else value


def versions(*distributions: str) -> dict:
    """Python's and each distribution's version ("eclipse-zenoh" reported as "zenoh")."""
    out = {"python": platform.python_version()}
    for dist in distributions:
        try:
            out[dist.replace("eclipse-", "")] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist.replace("eclipse-", "")] = None
    return out
