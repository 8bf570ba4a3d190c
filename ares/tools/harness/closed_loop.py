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
    extra: dict = dict(overrides or {})
    if cruise_speed_mps is not None:
        extra = config.deep_merge(extra, {"speed_profile": {"cruise_speed_mps": float(cruise_speed_mps)}})
    if seed is not None:
        extra = config.deep_merge(extra, {"sim": {"seed": int(seed)}})
    cfg = (
        run_config.build(overrides=extra) if cfg is None else run_config.build(overrides=config.deep_merge(cfg, extra))
    )
    core: CoreConfig = config.core(cfg)
    sim = config.section(cfg, "sim", SimParams)
    route = route or load_route(core)
    profile = core.vehicle_profile
    bridge_params = config.section(cfg, "dbw_bridge", DbwBridgeParams)
    if seconds is None and laps is None:
        laps = 1.0
    t_end = math.inf if seconds is None else float(seconds)
    distance_goal = math.inf if laps is None else float(laps) * route.length
    # a lap that takes much longer than at walking pace is stuck: stop it there
    t_limit = min(t_end, distance_goal / 0.3 + 60.0)

    frame = LocalFrame(core.origin_utm)
    plant = VehiclePlant(route, profile, sim, s0=s0)
    faults = load_scenario(core.scenario).faults if core.scenario else ()  # the scenario's sensor errors
    sensors = SensorSuite(route, sim, frame, profile.wheel_radius_m, faults=faults)
    fix_of = gnss_source(GnssProjector(frame, config.section(cfg, "gnss", GnssParams)), sensors.gnss, gnss_path)
    localizer = Localizer(config.section(cfg, "localization", LocalizationParams), profile)
    navigator = _Navigator(cfg, route, controller)
    scorer = OdometryScorer.from_params(config.section(cfg, "odometry_manager", OdometryParams))
    board = BridgeLoop(profile, bridge_params)
    if setpoint_delay_s is None:
        setpoint_delay_s = 1.0 / float(cfg["control_manager"]["rate_hz"])
    # the safety driver's button, then the software's request: Manual -> Ready -> Automatic
    board.handle(Event.button(plant.state.t))
    board.handle(Event.set_automatic(plant.state.t))

    dt = 1.0 / sim.physics_hz
    periods = {
        "can": 1.0 / sim.can_hz,
        "imu": 1.0 / sim.imu_hz,
        "gnss": 1.0 / sim.gnss_hz,
        "control": 1.0 / navigator.rate_hz,
        "dbw": 1.0 / bridge_params.rate_hz,
        "record": 1.0 / record_hz,
    }
    next_due = {k: 0.0 for k in periods}
    st = plant.state

    def due(name: str) -> bool:
        if st.t + 1e-9 < next_due[name]:
            return False
        next_due[name] = max(next_due[name] + periods[name], st.t)
        return True

    rows: list[tuple] = []
    last_can: CanFrame | None = None
    last_imu: Imu | None = None
    setpoints: list[tuple[float, float, float]] = []  # (t, v, kappa) on their way to the bridge
    steer_effort = drive_effort = 0.0
    progress = 0.0
    last_s = st.s
    lap_s_hint: float | None = None
    started = time.perf_counter()

    while st.t < t_limit - 1e-9 and progress < distance_goal:
        t = st.t
        # sensors, in the simulator node's order, each at the time of the state it reads
        if due("can"):
            last_can = CanFrame(t=t, **sensors.can.measure(st))
            localizer.push("can", last_can)
        if due("imu"):
            last_imu = Imu(t=t, **sensors.imu.measure(st))
            localizer.push("imu", last_imu)
        if due("gnss") and sensors.gnss.fix_available(st.s, t):
            fix = fix_of(st)
            if fix is not None:
                localizer.push("gnss", fix)
        # as the node: messages are applied hold_back_s late, the pose carried forward to t
        localizer.process_until(t - localizer.hold_back_s)

        if due("control"):
            # the wheels where the last CAN frame put them, as the controller nodes see them
            delta, delta_age = (
                (st.wheel_angle_rad, 0.0)
                if last_can is None
                else (profile.road_wheel_angle(last_can.steering_wheel_deg), t - last_can.t)
            )
            if use_truth_pose:
                cmd = navigator.command(t, st.x, st.y, st.yaw, st.v, delta=delta, delta_age_s=delta_age)
            else:
                pose = localizer.pose(t)
                cmd = (
                    None
                    if pose is None
                    else navigator.command(
                        t, pose.x, pose.y, pose.yaw, pose.v, pose.var_yaw, delta=delta, delta_age_s=delta_age
                    )
                )
            if cmd is not None:
                setpoints.append((t, *cmd))

        if due("dbw"):
            # as the bridge node's period: the setpoints that arrived, time passes, the inner loops
            arrived = [sp for sp in setpoints if sp[0] + setpoint_delay_s <= t + 1e-9]
            for t_set, v_cmd, kappa_cmd in arrived:
                board.handle(Event.setpoint(v_cmd, kappa_cmd, t_set))
            del setpoints[: len(arrived)]
            board.handle(Event.tick(t))
            out = board.efforts(t, last_can, None if last_imu is None else last_imu.pitch)
            steer_effort, drive_effort = out.steer_effort, out.drive_effort

        if record and due("record"):
            pose = localizer.pose(t)
            s_proj, xte, _ = route.project(st.x, st.y, lap_s_hint)
            lap_s_hint = s_proj
            if pose is None:
                est = (math.nan,) * 3 + (math.nan, math.nan, 0.0)
            else:
                cov = pose_covariance(pose)
                est = (pose.x, pose.y, pose.yaw, pose.var_yaw, cov, scorer(cov))
            rows.append(
                (
                    t,
                    st.x,
                    st.y,
                    st.yaw,
                    st.v,
                    st.s,
                    progress,
                    st.odometer,
                    xte,
                    sensors.gnss.rtk_available(st.s, t),
                    pose is not None,
                )
                + est
            )

        plant.step(steer_effort, drive_effort, dt)
        progress += route.step_between(last_s, st.s)
        last_s = st.s

    names = (
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
    cols = list(zip(*rows)) if rows else [[] for _ in names]
    out: dict = {
        name: np.asarray(col, dtype=bool if name in ("rtk_available", "has_pose") else float)
        for name, col in zip(names, cols)
    }
    out["wall_s"] = time.perf_counter() - started
    out["progress_m"] = progress
    out["counts"] = dict(localizer.counts)
    out["summary"] = summarize(out) if rows else {}
    out["summary"]["wall_s"] = round(out["wall_s"], 1)
    if navigator.solve_ms:
        out["summary"]["mpc_solve_p50_ms"] = percentile(navigator.solve_ms, 50, 3)
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
