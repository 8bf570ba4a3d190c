"""Control manager: which controller's candidate reaches the drive-by-wire bridge (ARES §3.6, §4).

Every controller computes all the time and publishes its candidate on its own topic: the MPC,
road reactive control and pure pursuit. This process is the only publisher of control/setpoint.
managers/control.py decides, each cycle, in a fixed order of trust: the odometry
controller where the path manager forces it or while the odometry score deserves it; the RRC
while road detection is confident; otherwise a controlled stop, and from a stop that has stood
still a while, a creep on the odometry at walking pace for a few metres while the pose's own
standard deviation allows it (so that road detection gets another view). Hysteresis, a minimum
dwell and a curvature ramp at the steering's rate make the switches few and bumpless.

The odometry controller is `odometry_controller` (the MPC by default); when its candidate is
missing or it asks for a hand-over (a solver that keeps failing), the other odometry controller
(pure pursuit) stands in for it under the same trust. `pinned` (`ares run --controller`) lets one
controller drive alone, for comparisons.

The forwarded speed never exceeds the speed manager's limit where the vehicle is (when fresh).
Every switch is an event (kind `controller_switch`, with from, to and cause), which the black box
keeps; control/status says who is in charge and why, every cycle.

Thresholds (docs/control.md, "The thresholds, from simulated laps"): the odometry score is ~1 with
RTK and falls below 0.3 within 1.4 s of losing it (docs/odometry_score.md), so odometry is trusted
from 0.8 and kept down to 0.5; right road detections on grass verges score only 0.07 (p05) to 0.16
(p50), so road detection's confidence is trusted from 0.15 and kept down to 0.04.
"""

from __future__ import annotations

import math
from typing import Literal

from ares.core.config import Params, param
from ares.core.messages import ControlCandidate, ControllerStatus, Setpoint
from ares.core.node import Input, Node, Output
from managers.control import Candidate, ControlSelector, Inputs, Mode, SelectionParams

# in the order they stand in for one another (stanley runs only when chosen: ares/app/processes.py)
ODOMETRY_CONTROLLERS = ("mpc", "pure_pursuit", "stanley")
CONTROLLERS = ("mpc", "rrc", "pure_pursuit", "stanley")


class ControlManagerParams(Params):
    rate_hz: float = param(
        50.0,
        "loop and setpoint rate: a candidate waits at most one period here on its way to "
        "the bridge (at 25 km/h, 20 Hz's extra 50 ms made both controllers weave)",
        unit="Hz",
        gt=0,
    )
    odometry_controller: Literal["mpc", "pure_pursuit", "stanley"] = param(
        "mpc", "the controller trusted while the odometry deserves it; the other stands in for it"
    )
    pinned: Literal["mpc", "rrc", "pure_pursuit", "stanley"] | None = param(
        None, "only this controller drives (comparisons: ares run --controller); null: the order of trust"
    )
    candidate_max_age_s: float = param(
        0.5,
        "an older candidate is never forwarded (the MPC solves at 10 Hz; at --speed 5 this is 0.1 s of wall time)",
        unit="s",
        gt=0,
    )
    input_timeout_s: float = param(
        1.0, "an older odometry score, road detection or path match counts as missing", unit="s", gt=0
    )
    score_enter: float = param(0.8, "odometry score from which the odometry controller is trusted", ge=0, le=1)
    score_exit: float = param(0.5, "... and below which it loses the trust", ge=0, le=1)
    road_enter: float = param(0.15, "road detection confidence from which the RRC is trusted", ge=0, le=1)
    road_exit: float = param(0.04, "... and below which it loses the trust", ge=0, le=1)
    min_dwell_s: float = param(
        1.0, "least time a controller stays in charge before a better one may take over", unit="s", ge=0
    )
    steering_rate_share: float = param(
        1.0, "the curvature ramps at this share of the steering motor's rate", gt=0, le=1
    )
    stop_decel_mps2: float = param(1.0, "a controlled stop's deceleration", unit="m/s^2", gt=0)
    creep_after_s: float = param(
        2.0, "a stop with nothing trusted stands this long before it creeps on the odometry", unit="s", ge=0
    )
    creep_speed_mps: float = param(0.8, "a creep's speed (walking pace)", unit="m/s", gt=0)
    creep_distance_m: float = param(
        4.0,
        "a creep goes this far, then stands again (0: never creep; road detection's guide after a loss reaches 5 m)",
        unit="m",
        ge=0,
    )
    creep_fix_age_s: float = param(
        2.0,
        "a creep drives by a pose that a GNSS fix (RTK or float) anchored this recently, never by dead reckoning",
        unit="s",
        gt=0,
    )
    stop_steer_fix_age_s: float = param(
        30.0,
        "a controlled stop steers by a pose good enough to creep by, or dead-reckoned no longer than this "
        "(the few metres of a stop; else by the RRC's road); at least creep_fix_age_s",
        unit="s",
        gt=0,
    )
    creep_clearance_m: float = param(
        0.3, "a creep keeps this much room between the shuttle's side and the road's edge", unit="m", ge=0
    )
    creep_sigmas_enter: float = param(
        3.0,
        "a creep begins while the road's room (less the clearance) holds this many of the pose's σ (without "
        "RTK σ grows ~1e-3 m^2/s standing, ~3e-3 driving; docs/odometry_score.md)",
        gt=0,
    )
    creep_sigmas_exit: float = param(2.5, "... and goes on while it holds this many", gt=0)
    finish_distance_m: float = param(0.5, "an open route is finished this close to its end", unit="m", gt=0)


class ControlManager(Node):
    """Forwards the candidate that deserves trust: the MPC, road reactive control, or a controlled stop."""

    name = "control_manager"
    Params = ControlManagerParams
    mpc = Input("control/candidate/mpc", max_age="candidate_max_age_s", doc="the MPC's (v, kappa)")
    rrc = Input("control/candidate/rrc", max_age="candidate_max_age_s", doc="road reactive control's (v, kappa)")
    pure_pursuit = Input(
        "control/candidate/pure_pursuit", max_age="candidate_max_age_s", doc="pure pursuit's (v, kappa)"
    )
    stanley = Input(
        "control/candidate/stanley", max_age="candidate_max_age_s", doc="the Stanley law's (v, kappa), when chosen"
    )
    score = Input("odometry/score", max_age="input_timeout_s", doc="trust in the pose (eq. 6)")
    pose = Input("localization/pose", max_age="input_timeout_s", doc="when a GNSS fix last anchored the pose")
    road = Input("perception/road", max_age="input_timeout_s", doc="road detection's confidence")
    match = Input("path/match", max_age="input_timeout_s", doc="zones; the errors; the route's end; the road's width")
    limits = Input("speed/limits", max_age="input_timeout_s", doc="the speed limit where the vehicle is")
    setpoint = Output("control/setpoint", rate="rate_hz", doc="(v, kappa) to the drive-by-wire bridge")
    status = Output("control/status", rate="rate_hz", doc="who is in charge, why, and the errors")

    def setup(self) -> None:
        p, vehicle = self.params, self.vehicle
        pinned = None if p.pinned is None else (Mode.RRC if p.pinned == "rrc" else Mode.ODOMETRY)
        self.selector = ControlSelector(
            SelectionParams(
                score_enter=p.score_enter,
                score_exit=p.score_exit,
                road_enter=p.road_enter,
                road_exit=p.road_exit,
                min_dwell_s=p.min_dwell_s,
                max_kappa_rate=vehicle.max_curvature_rate * p.steering_rate_share,
                stop_decel_mps2=p.stop_decel_mps2,
                pinned=pinned,
                creep_after_s=p.creep_after_s,
                creep_speed_mps=p.creep_speed_mps,
                creep_distance_m=p.creep_distance_m,
                creep_fix_age_s=p.creep_fix_age_s,
                stop_steer_fix_age_s=p.stop_steer_fix_age_s,
                creep_clearance_m=p.creep_clearance_m,
                creep_sigmas_enter=p.creep_sigmas_enter,
                creep_sigmas_exit=p.creep_sigmas_exit,
            )
        )
        primary = p.pinned if p.pinned in ODOMETRY_CONTROLLERS else p.odometry_controller
        # pinned: no stand-in (a comparison must show the pinned controller alone)
        self.odometry_order = [primary] if p.pinned else [primary, *(c for c in ODOMETRY_CONTROLLERS if c != primary)]
        self.in_charge = "stop"
        self.switches = 0

    def _odometry_candidate(self, now: float) -> tuple[str, ControlCandidate] | None:
        for name in self.odometry_order:
            cand = getattr(self, name).fresh(now)
            if cand is not None and not cand.handover:
                return name, cand
        return None

    def step(self, now: float) -> None:
        score, road, match, limits, pose = (
            self.score.fresh(now),
            self.road.fresh(now),
            self.match.fresh(now),
            self.limits.fresh(now),
            self.pose.fresh(now),
        )
        odometry = self._odometry_candidate(now)
        rrc = self.rrc.fresh(now)
        decision = self.selector.step(
            now,
            Inputs(
                odometry_score=None if score is None else score.score,
                road_confidence=None if road is None or not road.found else road.confidence,
                force_odometry=bool(match is not None and match.force_odometry),
                odometry=None if odometry is None else Candidate(odometry[1].v, odometry[1].kappa),
                rrc=None if rrc is None else Candidate(rrc.v, rrc.kappa, rrc.stop_only),
                pose_std_m=None
                if score is None or score.pose_age_s > self.params.input_timeout_s
                else math.sqrt(max(score.covariance, 0.0)),
                road_room_m=None
                if match is None or match.road_width_ahead_m is None
                else (match.road_width_ahead_m - self.vehicle.width_m) / 2 - abs(match.xte),
                fix_age_s=None if pose is None or pose.gnss_age_s is None else pose.gnss_age_s + (now - pose.t),
            ),
        )
        controller = {
            Mode.ODOMETRY: odometry[0] if odometry else "stop",
            Mode.RRC: "rrc",
            Mode.CREEP: "creep" if odometry else "stop",
        }.get(decision.mode, "stop")
        if controller != self.in_charge:
            cause = decision.cause if decision.switched else "stand_in"
            reason = (
                decision.reason
                if decision.switched
                else f"{self.in_charge} has no fresh candidate or hands over: {controller} stands in"
            )
            self.switches += 1
            self.event(
                "controller_switch",
                f"{self.in_charge} -> {controller}: {reason}",
                **{"from": self.in_charge, "to": controller, "cause": cause, "reason": reason},
            )
            self.in_charge = controller
        v = decision.v
        if limits is not None:
            v = min(v, limits.limit_mps)
        finished = bool(
            match is not None
            and match.distance_to_end_m is not None
            and match.distance_to_end_m < self.params.finish_distance_m
        )
        if finished:
            v = 0.0
        self.setpoint.put(Setpoint(t=now, v=v, kappa=decision.kappa, source=controller))
        self.status.put(
            ControllerStatus(
                t=now,
                controller=controller,
                mode=decision.mode.value,
                reason=decision.reason,
                s=None if match is None else match.s,
                xte=None if match is None else match.xte,
                heading_error=None if match is None else match.heading_error,
                target_speed=v,
                odometry_score=None if score is None else score.score,
                road_confidence=None if road is None else road.confidence,
                finished=finished,
            )
        )
