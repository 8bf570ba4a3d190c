"""The one percentile the benches, the evaluations and the harnesses report."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


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
