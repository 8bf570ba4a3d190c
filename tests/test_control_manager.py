"""The control manager as a node (managers/control_node.py) on the in-memory bus with a manual clock:
what reaches control/setpoint, the switches as events with their causes, the stand-in for a
failing MPC, the speed manager's limit, a pinned controller; and the RRC node's candidate from
road detection (control/rrc_node.py)."""

from __future__ import annotations

import pytest

from ares.core import config
from ares.core.clock import ManualClock
from ares.core.membus import MemoryNetwork
from ares.core.messages import (
    CarState,
    ControlCandidate,
    ControllerStatus,
    DriveMode,
    OdometryScore,
    PathMatch,
    Pose,
    RoadBoundary,
    RoadDetection,
    SpeedLimits,
)
from control.rrc_node import RrcNode
from managers.control_node import ControlManager

PERIOD = 0.05


def match(
    t: float, force: bool = False, to_end: float | None = None, road_width: float | None = 6.0, xte: float = 0.02
) -> PathMatch:
    return PathMatch(
        t=t,
        index=10,
        s=5.0,
        lap=0,
        xte=xte,
        heading_error=0.01,
        zones=["intersection"] if force else [],
        force_odometry=force,
        distance_to_end_m=to_end,
        road_width_ahead_m=road_width,
        ahead_x=[0.0, 1.0],
        ahead_y=[0.0, 0.0],
        ahead_yaw=[0.0, 0.0],
        ahead_curvature=[0.0, 0.0],
        ahead_speed=[3.0, 3.0],
        ahead_s=[5.0, 6.0],
    )


def pose(t: float, covariance: float, gnss_age_s: float | None) -> Pose:
    std = covariance**0.5
    return Pose(
        t=t, x=0.0, y=0.0, z=0.0, yaw=0.0, v=0.0, yaw_rate=0.0, cov_xx=covariance, cov_xy=0.0, cov_yy=covariance,
        var_yaw=1e-4, var_v=1e-4, position_std_m=std, rtk=False, gnss_age_s=gnss_age_s,
    )  # fmt: skip


def road(t: float, confidence: float = 0.9, offset: float = 0.1) -> RoadDetection:
    centre = RoadBoundary(coefficients=[-offset, 0.0, 0.0], x_min=0.0, x_max=15.0, points=30)
    return RoadDetection(
        t=t,
        found=confidence > 0,
        centre=centre,
        left=None,
        right=None,
        lateral_offset_m=offset,
        heading_rad=0.0,
        width_m=6.0,
        confidence=confidence,
    )


class Harness:
    def __init__(self, cfg: dict, **params):
        cfg = config.deep_merge(cfg, {"control_manager": params}) if params else cfg
        self.clock = ManualClock()
        self.network = MemoryNetwork()
        self.node = ControlManager(cfg, clock=self.clock, bus=self.network.bus("control_manager", self.clock))
        self.node.setup()
        self.bus = self.network.bus("test", self.clock)
        self.setpoints = self.bus.subscribe("control/setpoint", queue=1000)
        self.status = self.bus.subscribe("control/status", queue=1000)
        self.events = self.bus.subscribe("events", queue=1000)
        self.t = 0.0

    def step(
        self,
        *,
        score: float | None = 1.0,
        confidence: float | None = None,
        force: bool = False,
        mpc: tuple | None = (3.0, 0.01),
        rrc: tuple | None = None,
        pure_pursuit: tuple | None = (3.0, 0.02),
        handover: bool = False,
        limit: float | None = None,
        to_end: float | None = None,
        covariance: float = 1e-4,
        pose_age_s: float = 0.02,
        road_width: float | None = 6.0,
        gnss_age_s: float | None = 0.1,
        xte: float = 0.02,
    ):
        t = self.t = round(self.t + PERIOD, 9)
        self.clock.set(t)
        pub = self.bus.publish
        if score is not None:
            pub("odometry/score", OdometryScore(t=t, score=score, covariance=covariance, pose_age_s=pose_age_s))
        if confidence is not None:
            pub("perception/road", road(t, confidence))
        pub("path/match", match(t, force, to_end, road_width, xte))
        pub("localization/pose", pose(t, covariance, gnss_age_s))
        for name, cand in (("mpc", mpc), ("rrc", rrc), ("pure_pursuit", pure_pursuit)):
            if cand is not None:
                pub(
                    f"control/candidate/{name}",
                    ControlCandidate(
                        t=t, controller=name, v=cand[0], kappa=cand[1], handover=handover and name == "mpc"
                    ),
                )
        if limit is not None:
            pub(
                "speed/limits",
                SpeedLimits(
                    t=t,
                    s=5.0,
                    section=0,
                    kind="cruise",
                    limit_mps=limit,
                    next_section=1,
                    next_limit_mps=limit,
                    distance_to_next_m=10.0,
                ),
            )
        self.node.step_once(t)
        return self.setpoints.latest, self.status.latest

    def run(self, seconds: float, **inputs):
        for _ in range(round(seconds / PERIOD)):
            out = self.step(**inputs)
        return out

    def switches(self) -> list[dict]:
        return [e.data for _, e in self.events.drain() if e.kind == "controller_switch"]


def test_the_mpc_drives_while_the_score_is_high_and_the_rrc_takes_over_when_it_falls(run_config):
    h = Harness(run_config)
    setpoint, status = h.run(1.5, confidence=0.9, rrc=(2.0, -0.01))
    assert status.controller == "mpc" and setpoint.source == "mpc" and setpoint.v == 3.0
    assert [(s["from"], s["to"], s["cause"]) for s in h.switches()] == [("stop", "mpc", "score_ok")]
    setpoint, status = h.run(0.5, score=0.2, confidence=0.9, rrc=(2.0, -0.01))
    assert status.controller == "rrc" and status.mode == "rrc" and status.reason == "road confidence 0.90"
    assert setpoint.v == 2.0 and setpoint.source == "rrc"
    assert [(s["from"], s["to"], s["cause"]) for s in h.switches()] == [("mpc", "rrc", "score_low")]


def test_a_stale_candidate_is_never_forwarded(run_config):
    h = Harness(run_config)
    h.run(1.5)
    # the MPC and pure pursuit go quiet: within candidate_max_age_s the last one still counts ...
    max_age = h.node.params.candidate_max_age_s
    for _ in range(round(max_age / PERIOD) + 2):
        setpoint, status = h.step(mpc=None, pure_pursuit=None)
    # ... then nothing deserves trust: a controlled stop, slowing at stop_decel_mps2
    assert status.controller == "stop" and setpoint.source == "stop" and setpoint.v < 3.0
    v = setpoint.v
    setpoint, _ = h.step(mpc=None, pure_pursuit=None)
    assert setpoint.v == pytest.approx(max(v - h.node.params.stop_decel_mps2 * PERIOD, 0.0))


def test_a_stop_with_nothing_trusted_creeps_on_the_odometry_while_the_pose_allows(run_config):
    h = Harness(run_config)
    h.run(1.5, confidence=0.9, rrc=(2.0, -0.01))
    p = h.node.params
    # RTK lost (score 0, σ 5 cm) and the road lost: a stop, standing creep_after_s, then a creep
    lost = {"score": 0.0, "covariance": 0.05**2, "confidence": 0.0}
    setpoint, status = h.run(3.0 + p.creep_after_s + 0.2, **lost)
    assert status.controller == "creep" and status.mode == "creep" and setpoint.source == "creep"
    assert setpoint.v == p.creep_speed_mps and "pose σ 0.05 m" in status.reason
    causes = [(s["from"], s["to"], s["cause"]) for s in h.switches()]
    assert causes[-2:] == [("mpc", "stop", "score_low"), ("stop", "creep", "creep")]
    setpoint, _ = h.run(1.0, **lost)
    assert setpoint.kappa == pytest.approx(0.01)  # the MPC's, once the ramp from the stop's has caught up
    # its distance crept, it stands again
    setpoint, status = h.run(p.creep_distance_m / p.creep_speed_mps - 1.0, **lost)
    assert status.controller == "stop" and setpoint.v < p.creep_speed_mps
    assert h.switches()[-1]["cause"] == "crept"
    # a pose too uncertain for the road (σ 0.4 m: within 0.57 m on a 6 m road, not 0.23 m on a 4 m one),
    # too old, the road's width unknown
    # or dead-reckoned (no GNSS fix for 3 s, or none at all):
    for stale in (
        {"covariance": 0.4**2, "road_width": 4.0},
        {"pose_age_s": 2.0},
        {"road_width": None},
        {"gnss_age_s": 3.0},
        {"gnss_age_s": None},
    ):
        setpoint, status = h.run(p.creep_after_s + 3.0, **{**lost, **stale})
        assert status.controller == "stop" and setpoint.v == 0.0, stale


@pytest.mark.parametrize("xte, creeps", [(0.02, True), (-0.6, False)])
def test_a_stop_off_the_path_has_less_room_to_creep_in(run_config, xte, creeps):
    # σ 0.45 m on a 6 m road: within (6 - 1.99) / 2 - 0.02 - 0.3 = 1.69 m / 3 = 0.56 m on the path,
    # beyond (2.0 - 0.6 - 0.3) / 3 = 0.37 m with the shuttle 0.6 m to the right of it
    h = Harness(run_config)
    h.run(1.5)
    lost = {"score": 0.0, "covariance": 0.45**2, "confidence": 0.0, "xte": xte}
    _, status = h.run(3.0 + h.node.params.creep_after_s + 0.2, **lost)
    assert (status.controller == "creep") is creeps, status.reason


def test_creeping_is_off_with_a_zero_distance(run_config):
    h = Harness(run_config, creep_distance_m=0.0)
    h.run(1.5)
    setpoint, status = h.run(10.0, score=0.0, covariance=0.05**2, confidence=0.0)
    assert status.controller == "stop" and setpoint.v == 0.0


def test_pure_pursuit_stands_in_for_an_mpc_that_hands_over(run_config):
    h = Harness(run_config)
    h.run(1.5)
    h.switches()
    setpoint, status = h.step(handover=True)
    assert status.controller == "pure_pursuit" and status.mode == "odometry"
    assert [(s["from"], s["to"], s["cause"]) for s in h.switches()] == [("mpc", "pure_pursuit", "stand_in")]
    _, status = h.step()
    assert status.controller == "mpc"


def test_the_speed_limit_caps_the_forwarded_speed_and_the_route_end_stops(run_config):
    h = Harness(run_config)
    setpoint, _ = h.run(1.5, limit=2.5)
    assert setpoint.v == 2.5
    setpoint, status = h.step(to_end=0.2)
    assert setpoint.v == 0.0 and status.finished


def test_a_forced_zone_keeps_odometry_control_whatever_the_score(run_config):
    h = Harness(run_config)
    h.run(1.5, confidence=0.9, rrc=(2.0, 0.0))
    _, status = h.run(2.0, score=0.1, confidence=0.9, rrc=(2.0, 0.0), force=True)
    assert status.controller == "mpc" and "forces odometry" in status.reason


@pytest.mark.parametrize("pinned,expected", [("mpc", "mpc"), ("pure_pursuit", "pure_pursuit"), ("rrc", "rrc")])
def test_a_pinned_controller_drives_alone_whatever_the_trust(run_config, pinned, expected):
    h = Harness(run_config, pinned=pinned)
    _, status = h.run(2.0, score=0.1, confidence=0.1, rrc=(2.0, 0.0))
    assert status.controller == expected
    # without its candidate: a stop, never another controller (a comparison shows one alone)
    _, status = h.run(1.0, score=1.0, confidence=0.9, **{expected: None}, handover=pinned == "mpc")
    assert status.controller == "stop"


def test_the_curvature_ramps_at_the_steering_rate_across_a_switch(run_config):
    h = Harness(run_config)
    h.run(1.5, mpc=(3.0, 0.0), confidence=0.9, rrc=(2.0, 0.1))
    before, _ = h.step(mpc=(3.0, 0.0), confidence=0.9, rrc=(2.0, 0.1))
    after, status = h.step(score=0.1, mpc=(3.0, 0.0), confidence=0.9, rrc=(2.0, 0.1))
    assert status.controller == "rrc"
    rate = h.node.selector.p.max_kappa_rate
    assert after.kappa - before.kappa == pytest.approx(rate * PERIOD)


class RrcHarness:
    def __init__(self, cfg: dict):
        self.clock = ManualClock()
        self.network = MemoryNetwork()
        self.node = RrcNode(cfg, clock=self.clock, bus=self.network.bus("rrc", self.clock))
        self.node.setup()
        self.bus = self.network.bus("test", self.clock)
        self.candidates = self.bus.subscribe("control/candidate/rrc", queue=1000)

    def step(self, t: float, detection: RoadDetection | None, speed: float = 2.0, driving: str | None = None):
        self.clock.set(t)
        if detection is not None:
            self.bus.publish("perception/road", detection)
        if driving is not None:
            self.bus.publish(
                "control/status",
                ControllerStatus(
                    t=t,
                    controller=driving,
                    mode=driving,
                    reason="",
                    s=None,
                    xte=None,
                    heading_error=None,
                    target_speed=speed,
                ),
            )
        self.bus.publish(
            "dbw/car_state",
            CarState(
                t=t,
                mode=DriveMode.AUTOMATIC,
                engaged=True,
                watchdog_tripped=False,
                setpoint_age_s=0.05,
                v_command=speed,
                kappa_command=0.0,
                speed_mps=speed,
                steering_wheel_deg=0.0,
            ),
        )
        self.node.step_once(t)
        return [c for _, c in self.candidates.drain()]


def test_the_rrc_node_steers_back_to_the_centre_and_remembers_a_lost_road_for_a_stop_only(run_config):
    h = RrcHarness(run_config)
    got = h.step(0.05, road(0.05, 0.9, offset=0.5))  # half a metre left of the centre: steer right
    assert len(got) == 1 and got[0].kappa < 0 and got[0].v > 0 and got[0].controller == "rrc"
    assert not got[0].stop_only
    lost = h.step(0.10, road(0.10, 0.01))  # not confident: the road seen at 0.05 s, remembered
    assert len(lost) == 1 and lost[0].stop_only and lost[0].v == 0.0 and lost[0].kappa < 0
    assert "road lost" in lost[0].note
    again = h.step(0.15, road(0.15, 0.9, offset=0.5))[0]  # seen again: driving again
    assert not again.stop_only and again.v > 0 and again.kappa < 0
    t = 0.15
    while h.node.rrc.memory is not None and t < 10.0:  # stale detection: remembered for memory_m
        t += 0.05
        got = h.step(t, None)
    assert got == [] and 3.5 < t < 5.0  # 8 m at 2 m/s, after the road's timeout


def test_the_rrc_node_does_not_follow_a_frame_that_disagrees_with_the_road_seen_and_says_so(run_config):
    h = RrcHarness(run_config)
    events = h.bus.subscribe("events", queue=100)
    t = 0.0
    for _ in range(40):  # 4 m along the road, 0.1 m left of its centre
        t += 0.1
        assert not h.step(t, road(t, 0.9))[0].stop_only
    for _ in range(3):  # standing: a frame sees the centre 3 m to the right
        t += 0.1
        got = h.step(t, road(t, 0.5, offset=3.0), speed=0.0)
        assert got[0].stop_only and got[0].v == 0.0 and "disagrees with the road seen" in got[0].note
    doubts = [e for _, e in events.drain() if e.kind == "road_doubted"]
    assert len(doubts) == 1 and doubts[0].data["confidence"] == 0.5  # once for the spell
    t += 0.1
    assert not h.step(t, road(t, 0.9), speed=0.0)[0].stop_only  # the road seen again
    for _ in range(30):  # spells 0.2 s apart for 6 s, then 12 s on
        t += 0.1
        h.step(t, road(t, 0.5, offset=3.0), speed=0.0)
        t += 0.1
        h.step(t, road(t, 0.9), speed=0.0)
    t += 12.0
    h.step(t, road(t, 0.5, offset=3.0), speed=0.0)
    doubts = [e for _, e in events.drain() if e.kind == "road_doubted"]
    assert [e.data["spells"] for e in doubts] == [31]  # not one event each: one, counting them


def test_the_rrc_integrates_its_offset_only_while_it_drives(run_config):
    """The RRC computes all the time; a reading a little off while the MPC drives must not fill its
    integral (it would steer the shuttle aside at the hand-over)."""
    h = RrcHarness(run_config)
    t = 0.0
    for _ in range(20):  # the MPC drives, 0.3 m off the road seen
        t += 0.05
        h.step(t, road(t, 0.9, offset=0.3), driving="mpc")
    assert h.node.rrc.integral == 0.0
    for _ in range(20):  # the RRC drives: 2 m at 2 m/s
        t += 0.05
        h.step(t, road(t, 0.9, offset=0.3), driving="rrc")
    assert h.node.rrc.integral == pytest.approx(0.3 * 1.9, rel=0.1)
    h.step(t + 0.05, road(t + 0.05, 0.9, offset=0.3), driving="stop")
    assert h.node.rrc.integral == 0.0
