"""Speed limits along a route from its geometry (ARES §3.6.3, eqs. 16–17).

The path (x, y) = f(t) (eq. 16) has the curvature kappa of eq. 17 (Route.curvature). The limit
at every route sample is the curve speed sqrt(a_lat / |kappa|) — the speed at which a turn of
radius R = 1/|kappa| pulls a_lat sideways — capped by the cruise speed on straights (and a lower
cap in narrow lanes), then eased so that braking before a curve (and before the end of an open
route) and speeding up after it stay within the given deceleration and acceleration.

Grade (optional, `grade=`): decel and accel are what the brakes and the motor are asked for;
gravity adds g·grade to the braking on an uphill and takes it away on a downhill (g·sin θ ≈
g·grade for road grades), so the deceleration the vehicle achieves is decel + g·grade and the
acceleration accel − g·grade, never below MIN_RAMP_MPS2. Braking before a curve at the foot
of a descent therefore starts earlier: a 5 % descent alone (0.49 m/s²) takes all of a 0.5 m/s²
braking budget, and a profile eased on flat ground would bring the vehicle to the curve too fast.

Sections (ARES Figure 17): `sections()` reduces the profile to numbered single-speed sections —
cruise (the top speed), curve (the curve or narrow-lane limit itself), deceleration and
acceleration sectors, the ramps in steps of section_step_mps. A section's speed is the lowest
of the profile over it, so driving at a section's speed never exceeds the profile.

The path manager computes the flat profile (speed_limits without grade) and ships it ahead of
the vehicle in path/match (the stack's lap figures were made with it); the speed manager
(managers/speed_node.py) publishes the graded one and its sections.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from dataclasses import dataclass

import numpy as np

from ares.core.config import Params, VehicleProfile, param
from ares.core.messages import SpeedLimits, SpeedSection, SpeedSections
from ares.core.route import Route


class SpeedProfileParams(Params):
    """The `speed_profile` section: read by the path manager and the speed manager."""

    cruise_speed_mps: float | None = param(
        None,
        "a cap on the top speed on straights, below the road's speed limit "
        "(the tour's speed_limit_mps) and the vehicle's maximum (null: none)",
        unit="m/s",
        gt=0,
    )
    lateral_accel_mps2: float = param(
        0.35, "curve speed sqrt(a * R): keeps pure pursuit's corner cutting small", unit="m/s^2", gt=0
    )
    decel_mps2: float = param(0.5, "comfortable braking before curves and the end of an open route", unit="m/s^2", gt=0)
    accel_mps2: float = param(0.5, "comfortable acceleration after curves", unit="m/s^2", gt=0)
    narrow_speed_mps: float | None = param(2.5, "speed cap in narrow lanes (null: none)", unit="m/s", gt=0)
    section_step_mps: float = param(
        0.5, "speed step of the acceleration and deceleration sections (speed manager)", unit="m/s", gt=0
    )


G = 9.81  # m/s²
MIN_RAMP_MPS2 = 0.1  # a steep grade slows a ramp down, never to a standstill of the profile


def speed_profile(
    route: Route,
    cruise: float,
    lateral_accel: float,
    decel: float,
    accel: float,
    narrow_speed: float | None = None,
    grade: bool = False,
) -> np.ndarray:
    """Target speed at every route sample (ARES eqs. 16-17): the curve limit sqrt(a_lat / |kappa|),
    eased so that braking before a curve (and before the end of an open route) and speeding up
    after it stay within the given deceleration and acceleration (with `grade`: decel + g·grade
    and accel − g·grade, see the module's docstring)."""
    v = _curve_limit(route, cruise, lateral_accel, narrow_speed)
    n = len(v)
    # per-sample achievable ramps: a sample's grade acts over the step that leaves it
    if grade:
        slope = np.nan_to_num(route.grade)  # poses on top of each other have no grade
        dec = np.maximum(decel + G * slope, MIN_RAMP_MPS2).tolist()
        acc = np.maximum(accel - G * slope, MIN_RAMP_MPS2).tolist()
    else:
        dec, acc = [decel] * n, [accel] * n
    if not route.closed:
        v[-1] = 0.0
    ds = np.diff(route.s, append=route.s[-1] + (route.length - route.s[-1] if route.closed else 0.0))
    passes = 2 if route.closed else 1  # a loop's braking reaches back over its start
    v_list, ds_list = v.tolist(), ds.tolist()  # plain floats: this loop is sequential anyway
    for _ in range(passes):
        for i in range(n - 2, -1, -1) if not route.closed else range(n - 1, -1, -1):
            j = (i + 1) % n
            v_list[i] = min(v_list[i], math.sqrt(v_list[j] ** 2 + 2 * dec[i] * ds_list[i]))
        for i in range(1, n) if not route.closed else range(n):
            j = i - 1
            v_list[i] = min(v_list[i], math.sqrt(v_list[j] ** 2 + 2 * acc[j] * ds_list[j]))
    return np.array(v_list)


def _curve_limit(route: Route, cruise: float, lateral_accel: float, narrow_speed: float | None) -> np.ndarray:
    """The limit before easing: min(cruise, sqrt(a_lat / |kappa|)), and the narrow-lane cap."""
    curvature = np.abs(route.curvature)
    # judge a curve by its tightest part within a few metres, not by one noisy sample
    window = max(int(4.0 / max(np.median(np.diff(route.s)), 1e-3)), 1)
    if route.closed and window >= len(curvature):  # a loop shorter than the window: all of it counts
        tight = np.full(len(curvature), curvature.max())
    else:
        padded = (
            np.concatenate([curvature[-window:], curvature, curvature[:window]])
            if route.closed
            else np.pad(curvature, window, mode="edge")
        )
        tight = np.lib.stride_tricks.sliding_window_view(padded, 2 * window + 1).max(axis=1)
    v = np.minimum(cruise, np.sqrt(lateral_accel / np.maximum(tight, 1e-9)))
    if narrow_speed is not None:
        for zone in route.zones:
            if zone.kind == "narrow":
                inside = (route.s >= zone.s_start) & (route.s <= zone.s_end)
                v[inside] = np.minimum(v[inside], narrow_speed)
    return v


def speed_limits(route: Route, params: SpeedProfileParams, vehicle: VehicleProfile, grade: bool = False) -> np.ndarray:
    """The profile with the configured parameters, the cruise speed capped by the road's limit and the
    vehicle's maximum."""
    return speed_profile(
        route,
        cruise_speed(params, vehicle, route),
        params.lateral_accel_mps2,
        params.decel_mps2,
        params.accel_mps2,
        params.narrow_speed_mps,
        grade=grade,
    )


def cruise_speed(params: SpeedProfileParams, vehicle: VehicleProfile, route: Route) -> float:
    """The top speed on straights: the lowest of the road's limit, the configured cap and the
    vehicle's maximum (a speed limit is per road, a top speed per vehicle)."""
    caps = (route.speed_limit_mps, params.cruise_speed_mps, vehicle.max_speed_mps)
    return min(c for c in caps if c is not None)


# ---- single-speed sections (ARES Figure 17) ----------------------------------------------------

KINDS = ("cruise", "deceleration", "curve", "acceleration")
TOLERANCE_MPS = 1e-6


@dataclass(frozen=True)
class Section:
    index: int  # numbered from 0 in the order of s
    s_start: float  # m
    s_end: float  # m (the next section's s_start)
    speed: float  # m/s: the lowest of the profile over [s_start, s_end]
    kind: str  # one of KINDS


def sections(
    route: Route, profile: np.ndarray, cruise: float, lateral_accel: float, narrow_speed: float | None, step: float
) -> list[Section]:
    """The profile as contiguous single-speed sections covering [0, length] (Figure 17).

    Each step between two samples takes the lower of their speeds (the profile is linear
    in between, so the step never exceeds it) and a kind: cruise at the top speed, curve where
    the uneased limit holds, otherwise deceleration where the profile falls and acceleration
    where it rises. Ramps are cut in steps of `step` m/s (rounded down); a run of steps of the
    same kind and step becomes one section at the lowest speed in it.
    """
    n = len(profile)
    cap = _curve_limit(route, cruise, lateral_accel, narrow_speed)
    nxt = np.roll(np.arange(n), -1) if route.closed else np.arange(1, n)
    i = np.arange(len(nxt))
    edges = np.append(route.s[i], route.length if route.closed else route.s[-1])
    low = np.minimum(profile[i], profile[nxt])
    kind = np.where(
        low >= cruise - TOLERANCE_MPS,
        0,
        np.where(low >= np.minimum(cap[i], cap[nxt]) - TOLERANCE_MPS, 2, np.where(profile[nxt] < profile[i], 1, 3)),
    )
    band = np.where((kind == 1) | (kind == 3), np.floor(low / step + TOLERANCE_MPS), -1)
    # a new section wherever the kind or (on a ramp) the speed step changes, or a curve's limit does
    change = (kind[1:] != kind[:-1]) | (band[1:] != band[:-1]) | ((kind[1:] == 2) & (np.abs(low[1:] - low[:-1]) > step))
    starts = np.concatenate([[0], np.flatnonzero(change) + 1])
    ends = np.append(starts[1:], len(i))
    return [
        Section(
            index=k,
            s_start=float(edges[a]),
            s_end=float(edges[b]),
            speed=float(low[a:b].min()),
            kind=KINDS[int(kind[a])],
        )
        for k, (a, b) in enumerate(zip(starts, ends))
    ]


def speed_sections(
    route: Route, params: SpeedProfileParams, vehicle: VehicleProfile, profile: np.ndarray
) -> list[Section]:
    """`sections` with the configured parameters."""
    return sections(
        route,
        profile,
        cruise_speed(params, vehicle, route),
        params.lateral_accel_mps2,
        params.narrow_speed_mps,
        params.section_step_mps,
    )


class SpeedTable:
    """A route's graded profile and its sections; the limits at any s."""

    def __init__(self, route: Route, params: SpeedProfileParams, vehicle: VehicleProfile):
        self.route = route
        self.profile: np.ndarray = speed_limits(route, params, vehicle, grade=True)
        self.sections: list[Section] = speed_sections(route, params, vehicle, self.profile)
        self._starts = [sec.s_start for sec in self.sections]

    def section_at(self, s: float) -> Section:
        """The section holding s (wrapped on a closed route; clamped to the ends of an open one)."""
        if self.route.closed:
            s %= self.route.length
        k = bisect_right(self._starts, s) - 1
        return self.sections[min(max(k, 0), len(self.sections) - 1)]

    def limits(self, now: float, s: float) -> SpeedLimits:
        here = self.section_at(s)
        k = here.index + 1
        if k < len(self.sections):
            ahead: Section | None = self.sections[k]
        else:
            ahead = self.sections[0] if self.route.closed else None
        if self.route.closed:
            s %= self.route.length
        distance = None if ahead is None else max(here.s_end - s, 0.0)
        return SpeedLimits(
            t=now,
            s=s,
            section=here.index,
            kind=here.kind,
            limit_mps=here.speed,
            next_section=None if ahead is None else ahead.index,
            next_limit_mps=None if ahead is None else ahead.speed,
            distance_to_next_m=distance,
        )

    def message(self, now: float) -> SpeedSections:
        return SpeedSections(
            t=now,
            route=self.route.name,
            length_m=self.route.length,
            closed=self.route.closed,
            sections=[
                SpeedSection(index=sec.index, s_start=sec.s_start, s_end=sec.s_end, speed=sec.speed, kind=sec.kind)
                for sec in self.sections
            ],
        )
