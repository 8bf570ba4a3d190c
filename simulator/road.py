"""The road under the simulated vehicle's wheels.

Its large-scale shape is the route's elevation profile: the height at arc length s comes from
the Route itself, the grade from `grade_at`. On top of it, RoadRoughness is the small-scale
surface the suspension feels.
"""

from __future__ import annotations

import math

import numpy as np

from ares.core.route import Route


def grade_at(route: Route, s: float) -> float:
    """The route's grade dz/ds at arc length s, interpolated between its samples."""
    s = route.wrap_s(s)
    i = route.index_at(s)
    n = len(route.s)
    j = (i + 1) % n if route.closed else min(i + 1, n - 1)
    seg = (route.length if j == 0 else route.s[j]) - route.s[i]
    f = 0.0 if seg <= 0 else min(max((s - route.s[i]) / seg, 0.0), 1.0)
    return float(route.grade[i] + f * (route.grade[j] - route.grade[i]))


ROUGHNESS_STREAM = 1  # the surface has its own random stream: the plant and the world draw the same one


def roughness_for(route: Route, sim, wheelbase_m: float) -> RoadRoughness:
    """The road surface of this route and simulation (the same in the plant and the world)."""
    return RoadRoughness(
        sim.road_roughness_m,
        wheelbase_m,
        sim.roughness_wavelength_m,
        sim.suspension.natural_hz,
        sim.suspension.damping_ratio,
        np.random.default_rng([sim.seed, ROUGHNESS_STREAM]),
        period_m=route.length if route.closed else None,
    )


class RoadRoughness:
    """A random but repeatable road surface felt through the suspension.

    The surface height is a sum of sinusoids in the route's arc length s, with random phases and
    wavelengths between the configured bounds, amplitudes growing with wavelength (longer
    undulations are larger, as in real road profiles) and scaled so the surface RMS is
    `sigma_m`. On a closed tour each wavelength is rounded to a whole number of waves per lap,
    so the surface joins itself at the start line. The 3-D world the LiDARs see
    (simulator/world.py) is built from the same surface, so the wheels ride what the sensors see.
    The body follows through a second-order suspension, which gives
    the IMU its vertical acceleration; the height difference between the front and rear axle
    tilts the body (pitch jitter). Nothing moves while the vehicle stands still.
    """

    N_WAVES = 12

    def __init__(
        self,
        sigma_m: float,
        wheelbase_m: float,
        wavelength_m: tuple[float, float],
        natural_hz: float,
        damping_ratio: float,
        rng: np.random.Generator,
        period_m: float | None = None,
    ):
        self.wheelbase_m = wheelbase_m
        lam = np.geomspace(wavelength_m[0], wavelength_m[1], self.N_WAVES)
        if period_m:
            lam = period_m / np.maximum(np.round(period_m / lam), 1.0)
        self.k = 2.0 * np.pi / lam  # rad per metre
        amp = lam / lam.max()
        rms = math.sqrt(float(np.sum(amp**2)) / 2.0)
        self.amp = amp * (sigma_m / rms if rms > 0 else 0.0)
        self.phase = rng.uniform(0.0, 2.0 * np.pi, self.N_WAVES)
        self.wn = 2.0 * math.pi * natural_hz
        self.zeta = damping_ratio
        self.z_body = 0.0  # body height over the mean road surface
        self.vz_body = 0.0
        self.az_body = 0.0

    def settle(self, distance_m: float) -> None:
        """Body at rest on the road at this distance (no bounce at standstill)."""
        self.z_body = self.height(distance_m)
        self.vz_body = 0.0
        self.az_body = 0.0

    def height(self, d: float) -> float:
        return float(np.sum(self.amp * np.sin(self.k * d + self.phase)))

    def heights(self, s: np.ndarray) -> np.ndarray:
        """The surface at many arc lengths at once (the world's mesh)."""
        return np.sin(np.multiply.outer(np.asarray(s, dtype=float), self.k) + self.phase) @ self.amp

    def slope(self, d: float) -> float:
        return float(np.sum(self.amp * self.k * np.cos(self.k * d + self.phase)))

    def step(self, distance_m: float, v: float, dt: float) -> None:
        h = self.height(distance_m)
        hdot = self.slope(distance_m) * v
        # Suspension: spring and damper between the road under the wheel and the body.
        self.az_body = self.wn**2 * (h - self.z_body) + 2.0 * self.zeta * self.wn * (hdot - self.vz_body)
        self.vz_body += self.az_body * dt  # semi-implicit Euler: stable at 100 Hz
        self.z_body += self.vz_body * dt

    def pitch_jitter(self, distance_m: float) -> float:
        """Body pitch from the surface height under the front and rear axles (REP-103 sign:
        front higher than rear is nose up, a negative pitch)."""
        front = self.height(distance_m)
        rear = self.height(distance_m - self.wheelbase_m)
        return -math.atan2(front - rear, self.wheelbase_m)
