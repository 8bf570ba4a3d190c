"""The whole vehicle loop in one process, for fast experiments and tests (no bus, no processes).

    VehiclePlant (100 Hz physics) -> SensorSuite (CAN, IMU, GNSS at their sim.* rates)
      -> GNSS sentences -> fix (perception.gnss, as the gnss node does; see `gnss_source`)
      -> Localizer (perception.localization: the same UKF pipeline as the localization node)
      -> PathTracker (managers.path) + PurePursuit (control.pure_pursuit) or the MPC (control.mpc,
         `controller="mpc"`), at its rate_hz, driving from the ESTIMATED pose (the truth only with
         use_truth_pose=True)
      -> the drive-by-wire bridge's own loop (control.dbw_bridge.BridgeLoop: mode machine,
         watchdog, command gate, the two inner PIDs and the standstill brake) at dbw_bridge.rate_hz,
         switched to Automatic at the start as the button and set_automatic_mode would
      -> VehiclePlant.

Each message is processed at its own stack time, after the same hold-back as in the
localization node, and the pose is carried forward to the controller's time as the node
does; what this loop lacks compared to the process stack is only the bus's latency and the
processes' loop phases.

`run(...)` returns a dict of numpy arrays sampled at `record_hz` (truth, estimate,
covariance, odometry score, cross-track error, RTK availability) plus `summary`: the goals'
figures, measured as the stack's headless run does (position and yaw error where RTK has been
available for SETTLE_S, position error anywhere inside the RTK-loss zones, score with RTK
and after SETTLE_S inside the zones, cross-track error of the true pose).

    python -m ares.tools.harness.closed_loop --laps 1        # prints the summary as JSON
"""

from __future__ import annotations

import argparse
import json
import math
import time
from collections.abc import Callable

import numpy as np
import yaml

from ares.app import run_config
from ares.core import config
from ares.core.config import CoreConfig
from ares.core.geodesy import LocalFrame
from ares.core.geometry import wrap_angle
from ares.core.messages import CanFrame, GnssFix, Imu
from ares.core.route import Route, load_route
from ares.tools.bench.common import percentile
from control.dbw_bridge import BridgeLoop, DbwBridgeParams, Event
from control.mpc import Mpc, MpcParams
from control.mpc import VehicleState as MpcState
from control.mpc_node import MpcNodeParams
from control.pure_pursuit import ControllerParams, PurePursuit
from managers.odometry import OdometryParams, OdometryScorer, pose_covariance
from managers.path import PathManagerParams, PathTracker
from managers.speed import SpeedProfileParams, speed_limits
from perception.gnss import GnssParams, GnssProjector, pair_epochs
from perception.localization import LocalizationParams, Localizer
from perception.nmea_parser import NmeaReader
from simulator.params import SimParams
from simulator.scenario import load_scenario
from simulator.sensors import GnssSensor, SensorSuite
from simulator.vehicle import VehiclePlant, VehicleState

SETTLE_S = 2.0  # as the headless run's metrics: after the start and after RTK comes or goes


# ---- GNSS: sentences -> fix --------------------------------------------------------------------


def gnss_source(
    projector: GnssProjector, sensor: GnssSensor, path: str = "nmea"
) -> Callable[[VehicleState], GnssFix | None]:
    """A function turning the vehicle's state into the fix the localization receives.

    "nmea": the receiver's GGA + GST sentences, parsed and projected by the gnss node's own
    classes. "direct": the same error (GnssSensor.error) added to the truth, with the variances
    the GST would carry — no NMEA rounding, no parsing.
    """
    if path == "nmea":
        reader = NmeaReader()

        def via_nmea(state: VehicleState) -> GnssFix | None:
            sentences = [reader.parse(line) for line in sensor.measure(state)["sentences"]]
            pairs = pair_epochs([s for s in sentences if s is not None])
            return projector.fix(*pairs[0], t=state.t) if pairs else None

        return via_nmea

    def direct(state: VehicleState) -> GnssFix:
        err, fix = sensor.error(state)
        rtk = fix.quality == 4
        kind = "rtk" if rtk else "float"
        sig_h, sig_v = sensor.sigmas(fix)
        x, y = state.x + err[0], state.y + err[1]
        lat, lon = sensor.local_to_latlon(x, y)
        easting, northing = sensor.frame.utm_of(x, y)
        return GnssFix(
            t=state.t,
            x=x,
            y=y,
            z=state.z + err[2],
            lat=lat,
            lon=lon,
            easting=easting,
            northing=northing,
            zone=sensor.frame.zone,
            hemisphere="N" if sensor.frame.northern else "S",
            quality=fix.quality,
            rtk=rtk,
            satellites=int(sensor.satellites[kind]),
            hdop=float(sensor.hdop[kind]),
            var_x=sig_h**2,
            var_y=sig_h**2,
            var_z=sig_v**2,
        )

    return direct


# ---- path following: the path manager's tracker and the controller's geometry -----------------


class _Navigator:
    """Pose -> (v, kappa) with the same classes the path manager and controller nodes use."""

    def __init__(self, cfg: dict, route: Route, controller: str = "pure_pursuit"):
        profile = config.core(cfg).vehicle_profile
        limits = speed_limits(route, config.section(cfg, "speed_profile", SpeedProfileParams), profile)
        self.tracker = PathTracker(route, config.section(cfg, "path_manager", PathManagerParams), limits)
        self.pursuit = PurePursuit(config.section(cfg, "pure_pursuit", ControllerParams), profile)
        self.mpc_params = config.section(cfg, "mpc", MpcNodeParams)
        self.mpc = (
            Mpc(profile, MpcParams(**{k: getattr(self.mpc_params, k) for k in MpcParams.model_fields}))
            if controller == "mpc"
            else None
        )
        self.rate_hz = (
            self.mpc_params.rate_hz if self.mpc else config.section(cfg, "pure_pursuit", ControllerParams).rate_hz
        )
        self.solve_ms: list[float] = []
        self.latency_s = self.mpc_params.pipeline_latency_s  # as the node: the command's way to the wheels
        self._accel = 0.0

    def command(
        self,
        t: float,
        x: float,
        y: float,
        yaw: float,
        v: float,
        var_yaw: float = 0.0,
        delta: float = 0.0,
        delta_age_s: float = 0.0,
    ) -> tuple[float, float] | None:
        _, match = self.tracker.update(t, x, y, yaw, var_yaw)
        if match is None:
            return None
        if self.mpc is not None and math.sqrt(max(var_yaw, 0.0)) <= self.mpc_params.max_heading_sigma_rad:
            cmd = self.mpc.solve(
                MpcState(x, y, yaw, v, delta, self._accel),
                match.ahead_x,
                match.ahead_y,
                match.ahead_speed,
                latency_s=self.latency_s,
                delta_age_s=delta_age_s,
            )
            self._accel = cmd.accel
            self.solve_ms.append(cmd.solve_ms)
            return cmd.v, cmd.kappa
        cmd = self.pursuit.command(
            x,
            y,
            yaw,
            v,
            match.ahead_x,
            match.ahead_y,
            match.ahead_speed,
            match.distance_to_end_m,
            heading_sigma=math.sqrt(max(var_yaw, 0.0)),
            ahead_curvature=match.ahead_curvature,
        )
        return cmd.v, cmd.kappa


# ---- the loop ------------------------------------------------------------------------------------


def settled_masks(
    t: np.ndarray, rtk_available: np.ndarray, settle_s: float = SETTLE_S
) -> tuple[np.ndarray, np.ndarray]:
    """(RTK settled, RTK-loss settled): samples that have been on their side of the last change
    of RTK availability (or of the start) for at least settle_s."""
    t = np.asarray(t)
    rtk = np.asarray(rtk_available, dtype=bool)
    since = np.empty_like(t)
    last = t[0] if len(t) else 0.0
    for i in range(len(t)):
        if i > 0 and rtk[i] != rtk[i - 1]:
            last = t[i]
        since[i] = t[i] - last
    settled = since >= settle_s
    return settled & rtk, settled & ~rtk


def summarize(r: dict) -> dict:
    rtk_ok, lost_ok = settled_masks(r["t"], r["rtk_available"], SETTLE_S)
    have = r["has_pose"]
    err = np.hypot(r["est_x"] - r["x"], r["est_y"] - r["y"])
    yaw_err = np.degrees(wrap_angle(r["est_yaw"] - r["yaw"]))
    in_zone = have & ~r["rtk_available"]
    xte = np.abs(r["xte"])

    def stat(fn, values):
        return None if len(values) == 0 else round(float(fn(values)), 4)

    return {
        "vehicle_time_s": round(float(r["t"][-1]), 1) if len(r["t"]) else 0.0,
        "distance_m": round(float(r["odometer"][-1]), 1) if len(r["t"]) else 0.0,
        "pos_rmse_rtk_m": stat(lambda v: np.sqrt(np.mean(v**2)), err[have & rtk_ok]),
        "yaw_rmse_rtk_deg": stat(lambda v: np.sqrt(np.mean(v**2)), yaw_err[have & rtk_ok]),
        "pos_max_rtk_loss_m": stat(np.max, err[in_zone]),
        "score_min_rtk": stat(np.min, r["score"][have & rtk_ok]),
        "score_max_rtk_loss": stat(np.max, r["score"][have & lost_ok]),
        "cov_max_rtk_m2": stat(np.max, r["cov"][have & rtk_ok]),
        "cov_min_rtk_loss_m2": stat(np.min, r["cov"][have & lost_ok]),
        "xte_rmse_m": stat(lambda v: np.sqrt(np.mean(v**2)), xte),
        "xte_max_m": stat(np.max, xte),
    }


RECORDED = (
    "t",
    "x",
    "y",
    "yaw",
    "v",
    "s",
    "progress",
    "odometer",
    "xte",
    "rtk_available",
    "has_pose",
    "est_x",
    "est_y",
    "est_yaw",
    "var_yaw",
    "cov",
    "score",
)


def run(
    route: Route | None = None,
    seconds: float | None = None,
    laps: float | None = None,
    cfg: dict | None = None,
    cruise_speed_mps: float | None = None,
    seed: int | None = None,
    record: bool = True,
    record_hz: float = 20.0,
    use_truth_pose: bool = False,
    gnss_path: str = "nmea",
    s0: float = 0.0,
    overrides: dict | None = None,
    controller: str = "pure_pursuit",
    setpoint_delay_s: float | None = None,
) -> dict:
    """Drive `route` (default: the configured tour) for `seconds` of vehicle time or `laps`
    laps (default one lap), and return the recorded arrays and the summary.

    `cruise_speed_mps` overrides speed_profile.cruise_speed_mps; `overrides` is merged over the
    configuration (e.g. {"sim": {"imu": {"yaw_offset_rad": 0.3}}}); `seed` replaces sim.seed.
    `setpoint_delay_s`: how long a setpoint takes to reach the bridge (default: as in the stack,
    one period of the control manager, which forwards it; the bridge then takes it at its next
    period, a whole period later when the controller and the bridge step together).
    """
    loop = _Loop(
        loop_config(cfg, overrides, cruise_speed_mps, seed),
        route,
        s0=s0,
        controller=controller,
        use_truth_pose=use_truth_pose,
        gnss_path=gnss_path,
        setpoint_delay_s=setpoint_delay_s,
        record_hz=record_hz,
    )
    if seconds is None and laps is None:
        laps = 1.0
    t_end = math.inf if seconds is None else float(seconds)
    distance_goal = math.inf if laps is None else float(laps) * loop.route.length
    # a lap that takes much longer than at walking pace is stuck: stop it there
    t_limit = min(t_end, distance_goal / 0.3 + 60.0)
    started = time.perf_counter()
    while loop.st.t < t_limit - 1e-9 and loop.progress < distance_goal:
        loop.step(record)
    return _results(loop, time.perf_counter() - started)


def loop_config(cfg: dict | None, overrides: dict | None, cruise_speed_mps: float | None, seed: int | None) -> dict:
    """The run configuration (`cfg`, else the defaults) with `overrides`, the cruise speed and the seed."""
    extra: dict = dict(overrides or {})
    if cruise_speed_mps is not None:
        extra = config.deep_merge(extra, {"speed_profile": {"cruise_speed_mps": float(cruise_speed_mps)}})
    if seed is not None:
        extra = config.deep_merge(extra, {"sim": {"seed": int(seed)}})
    return run_config.build(overrides=extra if cfg is None else config.deep_merge(cfg, extra))


class _Loop:
    """The vehicle's loop (see the module's docstring), one physics step at a time (`step`)."""

    def __init__(
        self,
        cfg: dict,
        route: Route | None,
        s0: float,
        controller: str,
        use_truth_pose: bool,
        gnss_path: str,
        setpoint_delay_s: float | None,
        record_hz: float,
    ):
        core: CoreConfig = config.core(cfg)
        sim = config.section(cfg, "sim", SimParams)
        self.route = route = route or load_route(core)
        self.profile = core.vehicle_profile
        bridge_params = config.section(cfg, "dbw_bridge", DbwBridgeParams)
        frame = LocalFrame(core.origin_utm)
        self.plant = VehiclePlant(route, self.profile, sim, s0=s0)
        faults = load_scenario(core.scenario).faults if core.scenario else ()  # the scenario's sensor errors
        self.sensors = SensorSuite(route, sim, frame, self.profile.wheel_radius_m, faults=faults)
        self.fix_of = gnss_source(
            GnssProjector(frame, config.section(cfg, "gnss", GnssParams)), self.sensors.gnss, gnss_path
        )
        self.localizer = Localizer(config.section(cfg, "localization", LocalizationParams), self.profile)
        self.navigator = _Navigator(cfg, route, controller)
        self.scorer = OdometryScorer.from_params(config.section(cfg, "odometry_manager", OdometryParams))
        self.board = BridgeLoop(self.profile, bridge_params)
        self.use_truth_pose = use_truth_pose
        self.setpoint_delay_s = (
            1.0 / float(cfg["control_manager"]["rate_hz"]) if setpoint_delay_s is None else setpoint_delay_s
        )
        # the safety driver's button, then the software's request: Manual -> Ready -> Automatic
        self.board.handle(Event.button(self.plant.state.t))
        self.board.handle(Event.set_automatic(self.plant.state.t))

        self.dt = 1.0 / sim.physics_hz
        self.periods = {
            "can": 1.0 / sim.can_hz,
            "imu": 1.0 / sim.imu_hz,
            "gnss": 1.0 / sim.gnss_hz,
            "control": 1.0 / self.navigator.rate_hz,
            "dbw": 1.0 / bridge_params.rate_hz,
            "record": 1.0 / record_hz,
        }
        self.next_due = {k: 0.0 for k in self.periods}
        self.st = self.plant.state
        self.rows: list[tuple] = []
        self.last_can: CanFrame | None = None
        self.last_imu: Imu | None = None
        self.setpoints: list[tuple[float, float, float]] = []  # (t, v, kappa) on their way to the bridge
        self.steer_effort = self.drive_effort = 0.0
        self.progress = 0.0
        self.last_s = self.st.s
        self.lap_s_hint: float | None = None

    def due(self, name: str) -> bool:
        if self.st.t + 1e-9 < self.next_due[name]:
            return False
        self.next_due[name] = max(self.next_due[name] + self.periods[name], self.st.t)
        return True

    def step(self, record: bool) -> None:
        """The sensors, the localization, the controller, the bridge, the record that are due, then physics."""
        st = self.st
        t = st.t
        self._sense(t)
        # as the node: messages are applied hold_back_s late, the pose carried forward to t
        self.localizer.process_until(t - self.localizer.hold_back_s)
        if self.due("control"):
            self._control(t)
        if self.due("dbw"):
            self._bridge(t)
        if record and self.due("record"):
            self._record(t)
        self.plant.step(self.steer_effort, self.drive_effort, self.dt)
        self.progress += self.route.step_between(self.last_s, st.s)
        self.last_s = st.s

    def _sense(self, t: float) -> None:
        """The sensors, in the simulator node's order, each at the time of the state it reads."""
        st, sensors, localizer = self.st, self.sensors, self.localizer
        if self.due("can"):
            self.last_can = CanFrame(t=t, **sensors.can.measure(st))
            localizer.push("can", self.last_can)
        if self.due("imu"):
            self.last_imu = Imu(t=t, **sensors.imu.measure(st))
            localizer.push("imu", self.last_imu)
        if self.due("gnss") and sensors.gnss.fix_available(st.s, t):
            fix = self.fix_of(st)
            if fix is not None:
                localizer.push("gnss", fix)

    def _control(self, t: float) -> None:
        """The controller's setpoint, from the estimated pose (or the truth), on its way to the bridge."""
        st, last_can = self.st, self.last_can
        # the wheels where the last CAN frame put them, as the controller nodes see them
        delta, delta_age = (
            (st.wheel_angle_rad, 0.0)
            if last_can is None
            else (self.profile.road_wheel_angle(last_can.steering_wheel_deg), t - last_can.t)
        )
        if self.use_truth_pose:
            cmd = self.navigator.command(t, st.x, st.y, st.yaw, st.v, delta=delta, delta_age_s=delta_age)
        else:
            pose = self.localizer.pose(t)
            cmd = (
                None
                if pose is None
                else self.navigator.command(
                    t, pose.x, pose.y, pose.yaw, pose.v, pose.var_yaw, delta=delta, delta_age_s=delta_age
                )
            )
        if cmd is not None:
            self.setpoints.append((t, *cmd))

    def _bridge(self, t: float) -> None:
        """As the bridge node's period: the setpoints that arrived, time passes, the inner loops."""
        arrived = [sp for sp in self.setpoints if sp[0] + self.setpoint_delay_s <= t + 1e-9]
        for t_set, v_cmd, kappa_cmd in arrived:
            self.board.handle(Event.setpoint(v_cmd, kappa_cmd, t_set))
        del self.setpoints[: len(arrived)]
        self.board.handle(Event.tick(t))
        out = self.board.efforts(t, self.last_can, None if self.last_imu is None else self.last_imu.pitch)
        self.steer_effort, self.drive_effort = out.steer_effort, out.drive_effort

    def _record(self, t: float) -> None:
        """One row of RECORDED: the truth, the estimate, its covariance and score."""
        st = self.st
        pose = self.localizer.pose(t)
        s_proj, xte, _ = self.route.project(st.x, st.y, self.lap_s_hint)
        self.lap_s_hint = s_proj
        if pose is None:
            est = (math.nan,) * 3 + (math.nan, math.nan, 0.0)
        else:
            cov = pose_covariance(pose)
            est = (pose.x, pose.y, pose.yaw, pose.var_yaw, cov, self.scorer(cov))
        rtk = self.sensors.gnss.rtk_available(st.s, t)
        self.rows.append(
            (t, st.x, st.y, st.yaw, st.v, st.s, self.progress, st.odometer, xte, rtk, pose is not None) + est
        )


def _results(loop: _Loop, wall_s: float) -> dict:
    """The recorded rows as arrays, the counts and the summary."""
    cols = list(zip(*loop.rows)) if loop.rows else [[] for _ in RECORDED]
    out: dict = {
        name: np.asarray(col, dtype=bool if name in ("rtk_available", "has_pose") else float)
        for name, col in zip(RECORDED, cols)
    }
    out["wall_s"] = wall_s
    out["progress_m"] = loop.progress
    out["counts"] = dict(loop.localizer.counts)
    out["summary"] = summarize(out) if loop.rows else {}
    out["summary"]["wall_s"] = round(wall_s, 1)
    if loop.navigator.solve_ms:
        out["summary"]["mpc_solve_p50_ms"] = percentile(loop.navigator.solve_ms, 50, 3)
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description="Closed loop in one process: plant, sensors, UKF, pure pursuit or the MPC, DBW PIDs."
    )
    parser.add_argument("--laps", type=float, default=None)
    parser.add_argument("--seconds", type=float, default=None)
    parser.add_argument("--seed", type=int, default=None)
    parser.add_argument("--truth", action="store_true", help="drive from the true pose (baseline)")
    parser.add_argument("--gnss", choices=("nmea", "direct"), default="nmea")
    parser.add_argument("--controller", choices=("pure_pursuit", "mpc"), default="pure_pursuit")
    parser.add_argument("--route", help="a built-in tour or a tour's YAML (default: the configured tour)")
    parser.add_argument("--vehicle", help="vehicle profile")
    parser.add_argument(
        "--setpoint-delay",
        type=float,
        default=None,
        help="seconds from a setpoint to the bridge (default: the control manager's period)",
    )
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="SECTION.KEY=VALUE",
        help="a configuration override, e.g. mpc.w_cte=100 (repeatable)",
    )
    args = parser.parse_args(argv)
    over: dict = {}
    if args.route:
        over["tour"] = args.route
    if args.vehicle:
        over["vehicle"] = args.vehicle
    for item in args.set:
        key, _, value = item.partition("=")
        *path, leaf = key.split(".")
        node = over
        for part in path:
            node = node.setdefault(part, {})
        node[leaf] = yaml.safe_load(value)  # typed as in a config file
    result = run(
        seconds=args.seconds,
        laps=args.laps,
        seed=args.seed,
        use_truth_pose=args.truth,
        gnss_path=args.gnss,
        controller=args.controller,
        overrides=over,
        setpoint_delay_s=args.setpoint_delay,
    )
    print(json.dumps({**result["summary"], "counts": result["counts"]}))


if __name__ == "__main__":
    main()
