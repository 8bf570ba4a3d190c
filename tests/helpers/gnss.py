"""GNSS fixes for the awareness tests, and the places on Earth (with a short road) that the
route-import tests write receivers' logs for."""

from __future__ import annotations

import math

import numpy as np

from ares.core.messages import (
    GnssFix,
)
from ares.core.route import Route
from tests.helpers.roads import road


def fix(t: float, rtk: bool = True, var: float = 2.5e-5) -> GnssFix:
    return GnssFix(
        t=t,
        x=0.0,
        y=0.0,
        z=0.0,
        lat=28.48,
        lon=-16.32,
        easting=0.0,
        northing=0.0,
        zone=28,
        hemisphere="N",
        quality=4 if rtk else 1,
        rtk=rtk,
        satellites=12,
        hdop=0.8,
        var_x=var,
        var_y=var,
        var_z=var,
    )


# a short service road from (0, 0): a bend, a hairpin of 14 m, a gentle bend; ~260 m, a low hill
SHORT_ROAD = [("L", 30), ("A", 20, 90), ("L", 40), ("A", 14, -180), ("L", 40), ("A", 25, 60), ("L", 50)]


def short_road(heading_deg: float = 0.0) -> Route:
    xy = road(SHORT_ROAD, heading_deg=heading_deg)
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])
    z = 3.0 * np.sin(math.pi * s / s[-1])
    return Route(name="short road", x=xy[:, 0], y=xy[:, 1], z=z, closed=False, width=np.full(len(xy), 5.0))


# where on Earth: (latitude, longitude, altitude, heading of the road's first straight)
PLACES = {
    "munich": (48.137, 11.575, 519.0, 0.0),
    "across 12 E": (48.0, 11.9995, 470.0, 0.0),  # the road runs east over the zone 32/33 boundary
    "hobart": (-42.8806, 147.3250, 20.0, 30.0),
    "across 150 E, south": (-33.9, 149.9993, 60.0, 0.0),  # zone 55/56 in the southern hemisphere
    "equator": (0.0004, 9.4500, 10.0, -90.0),  # southwards over the equator (Gabon)
}
