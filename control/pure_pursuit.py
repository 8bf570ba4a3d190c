"""Pure pursuit path tracking with a speed hold (the DBW paper's control module, after Coulter).

Inputs:  <controller.pose_topic> (x, y, yaw, v of the rear axle)
Outputs: control/setpoint (v, kappa), control/status
Params:  controller.* in stack.yaml; vehicle profile (max speed, max wheel angle, wheelbase)

Geometry: the goal point lies one lookahead distance ahead along the route; the arc from the
rear axle through it has curvature kappa = 2 sin(alpha) / L, where alpha is the goal's bearing
relative to the heading and L its distance. Pure pursuit cuts corners by roughly
R - sqrt(R^2 - L^2) on a curve of radius R, so the speed profile slows the vehicle in tight
curves and the lookahead shrinks with speed.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ares.messages import ControllerStatus, Setpoint
from ares.node import Node, run_node
from ares.route import Route, load_route


def speed_profile(route: Route, cruise: float, lateral_accel: float, decel: float,
                  accel: float, narrow_speed: float | None = None) -> np.ndarray:
    """Target speed at every route sample: the curve limit sqrt(a_lat / |kappa|), eased so that
    braking before a curve (and before the end of an open route) and speeding up after it stay
    within the given deceleration and acceleration."""
    curvature = np.abs(route.curvature)
    # judge a curve by its tightest part within a few metres, not by one noisy sample
    window = max(int(4.0 / max(np.median(np.diff(route.s)), 1e-3)), 1)
    padded = np.concatenate([curvature[-window:], curvature, curvature[:window]]) if route.closed \
        else np.pad(curvature, window, mode="edge")
    tight = np.array([padded[i:i + 2 * window + 1].max() for i in range(len(curvature))])
    v = np.minimum(cruise, np.sqrt(lateral_accel / np.maximum(tight, 1e-9)))
    if narrow_speed is not None:
        for zone in route.zones:
            if zone.kind == "narrow":
                v[(route.s >= zone.s_start) & (route.s <= zone.s_end)] = np.minimum(
                    v[(route.s >= zone.s_start) & (route.s <= zone.s_end)], narrow_speed)
    if not route.closed:
        v[-1] = 0.0
    ds = np.diff(route.s, append=route.s[-1] + (route.length - route.s[-1] if route.closed else 0.0))
    passes = 2 if route.closed else 1  # a loop's braking reaches back over its start
    n = len(v)
    for _ in range(passes):
        for i in range(n - 2, -1, -1) if not route.closed else range(n - 1, -1, -1):
            j = (i + 1) % n
            v[i] = min(v[i], math.sqrt(v[j] ** 2 + 2 * decel * ds[i]))
        for i in range(1, n) if not route.closed else range(n):
            j = i - 1
            v[i] = min(v[i], math.sqrt(v[j] ** 2 + 2 * accel * ds[j]))
    return v


@dataclass
class PursuitCommand:
    v: float
    kappa: float
    s: float
    xte: float
    heading_error: float
    lookahead_m: float
    finished: bool


class PurePursuit:
    def __init__(self, route: Route, params: dict, vehicle: dict):
        self.route = route
        self.lookahead_min = float(params["lookahead_min_m"])
        self.lookahead_gain = float(params["lookahead_gain_s"])
        self.lookahead_max = float(params["lookahead_max_m"])
        cruise = min(float(params["cruise_speed_mps"]), float(vehicle["max_speed_mps"]))
        self.speeds = speed_profile(route, cruise, float(params["lateral_accel_mps2"]),
                                    float(params["decel_mps2"]), float(params["accel_mps2"]),
                                    params.get("narrow_speed_mps"))
        self.max_kappa = math.tan(float(vehicle["max_wheel_angle_rad"])) / float(vehicle["wheelbase_m"])
        self.s_hint: float | None = None

    def command(self, x: float, y: float, yaw: float, v: float) -> PursuitCommand:
        s, xte, i = self.route.project(x, y, self.s_hint)
        self.s_hint = s
        heading_error = math.atan2(math.sin(yaw - self.route.yaw[i]), math.cos(yaw - self.route.yaw[i]))
        finished = not self.route.closed and s >= self.route.length - 0.5
        lookahead = min(max(self.lookahead_min + self.lookahead_gain * abs(v), self.lookahead_min),
                        self.lookahead_max)
        gx, gy, _, _ = self.route.point_at(s + lookahead)
        dx, dy = gx - x, gy - y
        distance = math.hypot(dx, dy)
        if distance < 1e-3 or finished:
            return PursuitCommand(0.0, 0.0, s, xte, heading_error, lookahead, finished)
        alpha = math.atan2(dy, dx) - yaw
        kappa = 2.0 * math.sin(alpha) / distance
        kappa = max(-self.max_kappa, min(self.max_kappa, kappa))
        return PursuitCommand(float(self.speeds[i]), kappa, s, xte, heading_error, lookahead, finished)


class PurePursuitNode(Node):
    name = "controller"
    rate_key = "controller.rate_hz"

    def setup(self) -> None:
        params = self.cfg["controller"]
        self.pursuit = PurePursuit(load_route(self.cfg), params, self.cfg["vehicle_profile"])
        self.pose = self.bus.subscribe(params["pose_topic"])
        self.pose_timeout_s = 0.5
        self.setpoints = self.bus.publisher("control/setpoint")
        self.status = self.bus.publisher("control/status")

    def step(self, now: float) -> None:
        pose = self.pose.latest
        if pose is None or self.pose.age(now) > self.pose_timeout_s:
            return  # no fresh pose: stay silent, so the bridge's watchdog stops the vehicle
        cmd = self.pursuit.command(pose.x, pose.y, pose.yaw, pose.v)
        self.setpoints.put(Setpoint(t=now, v=cmd.v, kappa=cmd.kappa, source=self.name))
        self.status.put(ControllerStatus(t=now, controller="pure_pursuit", s=cmd.s, xte=cmd.xte,
                                         heading_error=cmd.heading_error, lookahead_m=cmd.lookahead_m,
                                         target_speed=cmd.v, finished=cmd.finished))


def main() -> None:
    run_node(PurePursuitNode)


if __name__ == "__main__":
    main()
