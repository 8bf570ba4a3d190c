"""The RTK corrections of a drive (a headless run's `corrections` figures): where they came from,
how old they were, how often their link was lost, and how much of the drive the fix was RTK fixed.

Fed `gnss/corrections` (once a second: the NTRIP client's, or the simulated 4G link's) and
`gnss/fix` (each fix's GGA quality), from the moment the drive starts.
"""

from __future__ import annotations

from collections import Counter
from typing import Any

import numpy as np

from ares.core.messages import FIX_QUALITY_NAMES


def _key(quality: int) -> str:
    """A fix quality's name as a JSON key: "RTK fixed" -> "rtk_fixed"."""
    return FIX_QUALITY_NAMES.get(quality, str(quality)).lower().replace(" ", "_")


class CorrectionsTracker:
    def __init__(self) -> None:
        self.ages: list[float] = []
        self.source = ""
        self.links: Counter[str] = Counter()  # status messages by link state
        self.outages = 0  # the link going from streaming to anything else
        self._last_link: str | None = None
        self._reported_outages: tuple[int, int] | None = None  # (first, latest) of the client's own count
        self.qualities: Counter[int] = Counter()

    def add_status(self, status: Any) -> None:
        self.source = status.source
        self.links[status.link] += 1
        if status.age_s is not None:
            self.ages.append(status.age_s)
        if self._last_link == "streaming" and status.link != "streaming":
            self.outages += 1
        self._last_link = status.link
        first = self._reported_outages[0] if self._reported_outages else status.outages
        self._reported_outages = (first, status.outages)

    def add_fix(self, fix: Any) -> None:
        self.qualities[fix.quality] += 1

    def summary(self) -> dict:
        if not self.links and not self.qualities:
            return {}
        fixes = sum(self.qualities.values())
        reported = self._reported_outages[1] - self._reported_outages[0] if self._reported_outages else 0
        ages = np.array(self.ages) if self.ages else None
        return {
            "corrections": {
                "source": self.source or "none",
                "rtk_fixed_share": round(self.qualities[4] / fixes, 4) if fixes else None,
                "fix_shares": {_key(q): round(n / fixes, 4) for q, n in sorted(self.qualities.items())},
                "age_s_p50": round(float(np.percentile(ages, 50)), 2) if ages is not None else None,
                "age_s_max": round(float(ages.max()), 2) if ages is not None else None,
                "outages": max(self.outages, reported),
                "link_seconds": dict(sorted(self.links.items())),
            }
        }
