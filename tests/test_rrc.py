"""Road Reactive Control (control/rrc.py, ARES eqs. 14-15) in closed loop with a kinematic vehicle,
the road view computed from its true pose (what road detection would publish, with its scatter)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from control.mpc import predict
from control.rrc import RememberedRoad, RoadReactiveControl, RoadView, RrcParams, agree, disagreement

WHEELBASE = 3.0


def view_of(x, y, yaw, radius, rng=None, confidence=0.9):
    """The road's centre line (a straight along x, or a left circle of `radius` about (0, radius))
    as seen from the pose: offset, heading and the centre line as a quadratic in the vehicle frame."""
    if math.isinf(radius):
        offset, road_yaw, kappa = y, 0.0, 0.0
    else:
        dx, dy = x, y - radius
        offset = radius - math.hypot(dx, dy)  # + inside the bend = left of the centre
        road_yaw, kappa = math.atan2(dy, dx) + math.pi / 2, 1.0 / radius
    heading = math.remainder(yaw - road_yaw, 2 * math.pi)
    noise = (rng.normal(0, 0.03), rng.normal(0, math.radians(1.0))) if rng is not None else (0.0, 0.0)
    # centre line in the vehicle frame, to second order: y = −offset/cos(h) − tan(h) x + κ/2 x² (1 + tan²h)^1.5
    c0, c1 = -offset / math.cos(heading), -math.tan(heading)
    c2 = kappa / 2 * (1 + c1 * c1) ** 1.5
    return RoadView(offset + noise[0], heading + noise[1], [c0, c1, c2], confidence), offset


def drive(radius, offset0=0.8, yaw0=0.0, seconds=40.0, rng=None, params=None):
    rrc = RoadReactiveControl(params)
    x, y, yaw = 0.0, offset0, yaw0
    if not math.isinf(radius):
        x, y = 0.0, offset0  # on the circle's bottom, heading +x
    dt, errors, commands = 0.1, [], []
    for _ in range(int(seconds / dt)):
        view, truth = view_of(x, y, yaw, radius, rng)
        last = commands[-1] if commands else None  # the command driven since the last step
        cmd = rrc.step(view, last.v * dt if last else 0.0, last.kappa if last else 0.0)
        commands.append(cmd)
        errors.append(truth)
        x, y, yaw, _ = predict(x, y, yaw, cmd.v, math.atan(cmd.kappa * WHEELBASE), 0.0, dt, WHEELBASE)
    return np.array(errors), commands


def test_the_offset_is_taken_out_on_a_straight():
    errors, commands = drive(math.inf)
    assert commands[0].kappa < 0  # left of the centre: turn right
    assert abs(errors[-100:]).max() < 0.03  # settled within 30 s (75 m)
    assert errors.min() > -0.2  # overshoot (measured 0.14 m) well under the start's 0.8


@pytest.mark.parametrize("radius", [30.0, 60.0])
def test_bends_are_followed_with_the_road_curvature_fed_forward(radius):
    errors, commands = drive(radius, offset0=0.0)
    assert abs(errors).max() < 0.08  # measured 3.7 cm at 30 m, 1.4 cm at 60 m
    assert np.mean([c.feedforward for c in commands]) == pytest.approx(1.0 / radius, rel=0.05)


def test_the_scatter_of_road_detection_is_not_amplified():
    errors, _ = drive(30.0, offset0=0.0, rng=np.random.default_rng(3))
    assert np.sqrt(np.mean(errors[50:] ** 2)) < 0.05  # 3 cm, 1° of scatter: measured 2.7 cm


def test_no_confident_detection_no_candidate_and_the_integral_starts_again():
    rrc = RoadReactiveControl(RrcParams(memory_m=0.0))  # nothing remembered
    view, _ = view_of(0.0, 0.5, 0.0, math.inf)
    assert rrc.step(view, 1.0) is not None and rrc.integral == pytest.approx(0.5)
    assert rrc.step(None, 1.0) is None and rrc.integral == 0.0
    low, _ = view_of(0.0, 0.5, 0.0, math.inf, confidence=RrcParams().min_confidence * 0.9)
    assert rrc.step(low, 1.0) is None
    nan = RoadView(math.nan, 0.0, [0.0], 0.9)
    assert rrc.step(nan, 1.0) is None


def test_a_lost_road_is_remembered_for_a_stop_then_forgotten():
    p = RrcParams()
    rrc = RoadReactiveControl(p)
    view, _ = view_of(0.0, 0.5, 0.0, math.inf)
    seen = rrc.step(view, 1.0)
    lost = rrc.step(None, 0.0)
    assert (
        lost.remembered and lost.v == 0.0 and lost.kappa == pytest.approx(seen.kappa)
    )  # the same road, from the same place
    assert rrc.step(None, p.memory_m + 0.1) is None and rrc.integral == 0.0 and rrc.memory is None


@pytest.mark.parametrize("radius", [math.inf, 30.0])
def test_a_stop_steered_along_the_remembered_road_keeps_to_its_line(radius):
    """Seen up to the loss, then driven 8 m on the remembered road alone, slowing to a stop from
    2.5 m/s: the true offset stays where the road seen would have kept it."""
    rrc = RoadReactiveControl()
    x, y, yaw, v, dt = 0.0, 0.3, 0.0, 2.5, 0.05
    kappa = 0.0
    for step in range(200):
        seen = step < 40  # 2 s seen (5 m), then lost
        view, truth = view_of(x, y, yaw, radius)
        cmd = rrc.step(view if seen else None, v * dt, kappa)
        if not seen:
            assert cmd is not None and cmd.remembered and cmd.v == 0.0
            v = max(0.0, v - 1.0 * dt)  # the control manager's controlled stop
        kappa = cmd.kappa
        x, y, yaw, _ = predict(x, y, yaw, v, math.atan(kappa * WHEELBASE), 0.0, dt, WHEELBASE)
        if v == 0.0:
            break
    _, truth = view_of(x, y, yaw, radius)
    assert abs(truth) < 0.25  # steered back towards the centre, not rolled off
    assert rrc.memory.travelled_m == pytest.approx(3.125 + 2.5 * dt * 0.5, abs=0.15)  # v²/2a of the stop


def test_speed_falls_with_confidence_and_commands_stay_bounded():
    p = RrcParams()
    rrc = RoadReactiveControl(p)
    full, _ = view_of(0.0, 0.0, 0.0, math.inf, confidence=1.0)
    half, _ = view_of(0.0, 0.0, 0.0, math.inf, confidence=(p.min_confidence + p.full_speed_confidence) / 2)
    assert rrc.step(full, 0.1).v == p.max_speed_mps
    assert rrc.step(half, 0.1).v == pytest.approx(p.max_speed_mps / 2)
    far = RoadView(50.0, 1.0, [0.0], 1.0)
    for _ in range(1000):
        cmd = rrc.step(far, 1.0)
    assert abs(cmd.kappa) <= p.max_kappa and abs(rrc.integral) <= p.integral_limit_m2


def test_the_road_at_the_wheels_is_read_from_the_frames_seen_metres_back():
    """Where a tight bend begins ahead, a frame's fit is good within its points (from ~4 m ahead)
    but far off extrapolated back to the vehicle. The offset and heading come from the frames seen
    3-6 m back, moved by what was driven since; a frame seen again is not a new one."""

    def law(params):
        rrc = RoadReactiveControl(params)
        for k in range(17):  # 4 m straight on, 0.2 m left of the centre
            view, _ = view_of(0.25 * k, 0.2, 0.0, math.inf)
            rrc.step(RoadView(*dataclasses.astuple(view)[:4], stamp=float(k)), 0.25 if k else 0.0)
        rrc.step(RoadView(*dataclasses.astuple(view)[:4], stamp=16.0), 0.25)  # the same frame again
        assert len(rrc.seen) == 17
        # This frame's fit bends towards a bend ahead: it has the vehicle 0.3 m right of the centre, turned 10° left.
        h = math.radians(10.0)
        bent = RoadView(-0.3, h, [0.3 / math.cos(h), -math.tan(h), 0.02], 0.9, stamp=17.0)
        return rrc.step(bent, 0.0)

    cmd = law(RrcParams())
    assert cmd.error_m == pytest.approx(0.2, abs=1e-9) and cmd.heading_rad == pytest.approx(0.0, abs=1e-9)
    assert cmd.kappa < cmd.feedforward  # left of the centre: right of the bend's curvature
    extrapolated = law(RrcParams(view_from_m=0.0, view_to_m=0.0))  # read at x = 0 of the newest frame
    assert extrapolated.error_m == pytest.approx(-0.3)


def test_without_a_measured_speed_only_the_newest_frame_is_kept():
    rrc = RoadReactiveControl()
    for k in range(5):
        view, _ = view_of(0.5 * k, 0.2, 0.0, math.inf)
        rrc.step(view, 0.5 if k else 0.0)
    assert len(rrc.seen) == 5
    view, _ = view_of(2.5, -0.1, 0.0, math.inf)
    cmd = rrc.step(view, None)  # the frames cannot be moved: read the newest
    assert len(rrc.seen) == 1 and cmd.error_m == pytest.approx(-0.1)


def test_a_frame_is_read_where_the_vehicle_is_now_not_where_the_sweep_was_taken():
    rrc = RoadReactiveControl()
    yaw = math.radians(5.0)
    view, _ = view_of(0.0, 0.2, yaw, math.inf)  # turned 5° left, 0.2 m left of the centre
    cmd = rrc.step(view, 0.0, 0.0, since_frame_m=1.0)  # perception's latency: 1 m driven since
    assert cmd.error_m == pytest.approx(0.2 + math.sin(yaw), abs=1e-3)


def test_the_frames_are_kept_at_walking_pace_and_bounded_at_standstill():
    """A 20 Hz loop, 10 Hz frames: at 0.5 m/s the frames lie 5 cm apart, closer than the spacing;
    the history must still reach back 3-6 m (not collapse to the newest), and stay small standing."""

    def history(speed, seconds):
        rrc = RoadReactiveControl()
        for k in range(int(seconds * 20)):
            view, _ = view_of(0.0, 0.1, 0.0, math.inf)
            rrc.step(RoadView(*dataclasses.astuple(view)[:4], stamp=float(k // 2)), speed * 0.05)
        return rrc.seen

    walking = history(0.5, 20.0)  # 10 m
    assert walking[0].travelled_m > RrcParams().view_to_m
    assert all(a.travelled_m - b.travelled_m >= 0.1 - 1e-9 for a, b in zip(walking[:-2], walking[1:-1]))
    assert len(history(0.0, 20.0)) <= 2


def test_a_frame_with_a_non_finite_centre_line_is_not_followed():
    rrc = RoadReactiveControl(RrcParams(memory_m=0.0))
    assert rrc.step(RoadView(0.0, 0.0, [0.0, 0.0, math.nan], 0.9), 0.1) is None
    assert rrc.seen == [] and rrc.integral == 0.0


def test_no_memory_means_no_stop_candidate_even_standing():
    rrc = RoadReactiveControl(RrcParams(memory_m=0.0))
    view, _ = view_of(0.0, 0.1, 0.0, math.inf)
    assert rrc.step(view, 0.0) is not None
    assert rrc.step(None, 0.0) is None


def test_backing_up_moves_the_frames_back():
    rrc = RoadReactiveControl()
    yaw = math.radians(5.0)
    view, _ = view_of(0.0, 0.2, yaw, math.inf)
    rrc.step(RoadView(*dataclasses.astuple(view)[:4], stamp=0.0), 0.0)
    rrc.step(RoadView(*dataclasses.astuple(view)[:4], stamp=0.0), 4.0)
    cmd = rrc.step(RoadView(*dataclasses.astuple(view)[:4], stamp=0.0), -1.0)  # 4 m on, 1 m back
    assert cmd.error_m == pytest.approx(0.2 + 3.0 * math.sin(yaw), abs=1e-3)


# ---- a new frame checked against the road remembered ---------------------------------------------


def stamped(view: RoadView, stamp: float) -> RoadView:
    return dataclasses.replace(view, stamp=stamp)


def remembering_a_straight(rrc: RoadReactiveControl) -> float:
    """5 m driven along a straight, 0.1 m left of its centre, a frame every 0.25 m; then standing.
    The time of the last frame."""
    view, _ = view_of(0.0, 0.1, 0.0, math.inf)
    for k in range(21):
        assert not rrc.step(stamped(view, k * 0.1), 0.25 if k else 0.0).remembered
    return 2.0


def test_a_frame_that_disagrees_with_the_road_remembered_is_not_followed():
    rrc = RoadReactiveControl()
    t = remembering_a_straight(rrc)
    wrong = RoadView(0.0, 0.0, [-0.1, math.tan(math.radians(48.0))], 0.37)  # the road pointed 48° left
    cmd = rrc.step(stamped(wrong, t + 1.0), 0.0)
    assert cmd.remembered and cmd.v == 0.0 and cmd.error_m == pytest.approx(0.1, abs=1e-6)
    assert rrc.step(stamped(wrong, t + 1.0), 0.0).remembered  # seen again: still not followed
    assert len(rrc.doubted) == 1
    right, _ = view_of(0.0, 0.1, 0.0, math.inf)
    cmd = rrc.step(stamped(right, t + 1.1), 0.0)
    assert not cmd.remembered and cmd.v > 0 and rrc.doubted == []


def test_frames_that_agree_with_one_another_replace_a_memory_they_disagree_with():
    p = RrcParams()
    rrc = RoadReactiveControl(p)
    t = remembering_a_straight(rrc)
    other, _ = view_of(0.0, 2.0, 0.0, math.inf)  # the centre 2 m to the right
    for k in range(1, p.doubt_frames):
        assert rrc.step(stamped(other, t + k * 0.1), 0.0).remembered
    rrc.integral = 1.0
    cmd = rrc.step(stamped(other, t + p.doubt_frames * 0.1), 0.0)
    assert not cmd.remembered and cmd.error_m == pytest.approx(2.0, abs=1e-6)
    assert all(f.centre == other.centre for f in rrc.seen) and rrc.doubted == []
    assert rrc.replaced and rrc.integral == 0.0  # the integral starts again
    assert not rrc.step(stamped(other, t + (p.doubt_frames + 1) * 0.1), 0.0).remembered and not rrc.replaced


def test_doubts_count_only_in_a_row():
    """A cycle without a road to follow (none, not confident, not measured) ends a spell of doubts."""
    p = RrcParams()
    other, _ = view_of(0.0, 2.0, 0.0, math.inf)
    for gap in (None, dataclasses.replace(other, confidence=p.min_confidence / 2)):
        rrc = RoadReactiveControl(p)
        t = remembering_a_straight(rrc)
        for k in range(1, 2 * p.doubt_frames - 1):  # doubt_frames - 2 before the gap, - 1 after
            if k == p.doubt_frames - 1:
                assert rrc.step(gap, 0.0).remembered and rrc.doubted == []
            else:
                assert rrc.step(stamped(other, t + k * 0.1), 0.0).remembered, k
    rrc = RoadReactiveControl(p)
    t = remembering_a_straight(rrc)
    rrc.step(stamped(other, t + 0.1), 0.0)
    rrc.step(None, None)  # no speed measured
    assert rrc.doubted == []


def test_without_memory_for_a_stop_a_doubted_frame_is_still_not_followed():
    rrc = RoadReactiveControl(RrcParams(memory_m=0.0))
    t = remembering_a_straight(rrc)
    wrong = RoadView(0.0, 0.0, [-0.1, math.tan(math.radians(48.0))], 0.37)
    assert rrc.step(stamped(wrong, t + 0.1), 0.0) is None  # no stop candidate, as set ...
    assert rrc.step(stamped(wrong, t + 0.2), 0.0) is None  # ... and still not followed
    assert len(rrc.seen) > 1 and len(rrc.doubted) == 2


def test_doubted_frames_are_moved_along_while_driving():
    """Driving on straight along x, 0.2 m a frame, frames of another road, the line y = −2 + m x
    (3° to the left), agree with one another once moved along: they replace the memory."""
    p = RrcParams()
    rrc = RoadReactiveControl(p)
    t = remembering_a_straight(rrc)
    m = math.tan(math.radians(3.0))
    for k in range(p.doubt_frames):
        x = 0.2 * k  # the vehicle's x
        view = RoadView(2.0, -math.atan(m), [-2.0 + m * x, m], 0.9, stamp=t + (k + 1) * 0.1)
        cmd = rrc.step(view, 0.2 if k else 0.0)
        assert cmd.remembered == (k < p.doubt_frames - 1), k
    assert rrc.replaced


def test_frames_in_a_row_that_disagree_with_one_another_are_none_of_them_followed():
    p = RrcParams()
    rrc = RoadReactiveControl(p)
    t = remembering_a_straight(rrc)
    for k in range(3 * p.doubt_frames):
        wild, _ = view_of(0.0, 2.0 * (-1) ** k, 0.0, math.inf)  # 2 m right, 2 m left, ...
        assert rrc.step(stamped(wild, t + (k + 1) * 0.1), 0.0).remembered
    assert len(rrc.doubted) == 1


@given(
    st.floats(30.0, 200.0),
    st.sampled_from([-1.0, 1.0]),
    st.floats(0.0, 4.0),
    st.floats(-0.5, 0.5),
    st.floats(-10.0, 10.0),
    st.floats(-0.5, 0.5),
    st.floats(-10.0, 10.0),
)
def test_frames_of_one_road_agree(radius, side, ahead, offset0, heading0, offset1, heading1):
    """Two frames of one bend (30 m or gentler, either way, as second-order expansions about the
    vehicle), taken up to 4 m apart from anywhere 0.5 m and 10° about its centre line, agree to
    well within agree_m (0.19 m at worst on a grid). Tighter bends: the fits below (an expansion
    about x = 0 is cruder than a fit 4-12 m ahead there)."""

    def frame_at(s, offset, heading_deg):
        angle = s / radius  # along a left circle about (0, radius)
        x, y = (radius - offset) * math.sin(angle), radius - (radius - offset) * math.cos(angle)
        yaw = angle + math.radians(heading_deg)
        view, _ = view_of(x, y, yaw, radius)
        return (
            RememberedRoad(list(view.centre), x, y, yaw)
            if side > 0
            else RememberedRoad([-c for c in view.centre], x, -y, -yaw)
        )

    old, new = frame_at(0.0, offset0, heading0), frame_at(ahead, offset1, heading1)
    # the old frame's vehicle has since moved to the new one: its pose in the old frame
    dx, dy = new.x - old.x, new.y - old.y
    c, s = math.cos(old.yaw), math.sin(old.yaw)
    moved = RememberedRoad(old.centre, c * dx + s * dy, -s * dx + c * dy, new.yaw - old.yaw)
    here = RememberedRoad(new.centre)
    apart = disagreement(here, moved)
    assert apart is not None and apart < 0.5 * RrcParams().agree_m


def test_frames_that_saw_different_stretches_are_not_compared():
    old, new = RememberedRoad([0.0], x=9.0), RememberedRoad([5.0])  # 9 m on: the old frame saw up to 3 m ahead
    assert disagreement(new, old) is None and agree(new, [old], 1.0)
    assert disagreement(new, RememberedRoad([0.0], x=2.0)) == pytest.approx(5.0)


def test_frames_of_a_straight_running_into_a_12_m_bend_agree():
    """Quadratics fitted, as road detection fits them, to the centre line 4-12 m ahead of poses
    along a straight that runs into a 12 m bend, on it and 0.5 m either side, turned up to 10°
    either way, each pair up to 5 m apart: they agree within agree_m (0.69 m at worst, across the
    road, inside the bend, turned 10° out of it; 0.23 m without the turn)."""
    radius = 12.0

    def centre_at(s):
        if s <= 0:
            return s, 0.0, 0.0
        return radius * math.sin(s / radius), radius * (1 - math.cos(s / radius)), s / radius

    def frame(s, off, turned_deg):
        x0, y0, yaw0 = centre_at(s)
        x0, y0, yaw0 = x0 - math.sin(yaw0) * off, y0 + math.cos(yaw0) * off, yaw0 + math.radians(turned_deg)
        points = np.array([centre_at(v)[:2] for v in np.linspace(s - 2.0, s + 20.0, 111)])
        dx, dy = points[:, 0] - x0, points[:, 1] - y0
        xv, yv = math.cos(yaw0) * dx + math.sin(yaw0) * dy, -math.sin(yaw0) * dx + math.cos(yaw0) * dy
        seen = (xv >= 4.0) & (xv <= 12.0)
        return list(np.polynomial.polynomial.polyfit(xv[seen], yv[seen], 2)), (x0, y0, yaw0)

    worst = 0.0
    for s in np.arange(-14.0, 20.0, 1.0):
        for apart in (1.0, 2.5, 5.0):
            for off in (-0.5, 0.0, 0.5):
                for turned in ((0, 0), (-10, 0), (10, 0), (0, -10), (0, 10), (-10, 10), (10, -10)):
                    (c1, (x1, y1, yaw1)), (c2, (x2, y2, yaw2)) = (
                        frame(s, off, turned[0]),
                        frame(s + apart, off, turned[1]),
                    )
                    c, si = math.cos(yaw1), math.sin(yaw1)
                    old = RememberedRoad(
                        c1, c * (x2 - x1) + si * (y2 - y1), -si * (x2 - x1) + c * (y2 - y1), yaw2 - yaw1
                    )
                    apart_m = disagreement(RememberedRoad(c2), old)
                    worst = max(worst, apart_m if apart_m is not None else 0.0)
    assert 0.3 < worst < RrcParams().agree_m
