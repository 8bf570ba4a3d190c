"""The control manager's choice of controller (managers/control.py): every mode × every
combination of inputs against the rule written out plainly, with creeping off and on, then
hypothesis properties over random sequences (no stale candidate forwarded, the dwell respected
unless the mode in charge fails, the curvature within the steering's rate, a controlled stop that
only slows, a creep only after standing, at its speed and for its distance)."""

from __future__ import annotations

import itertools

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from managers.control import Candidate, ControlSelector, Inputs, Mode, SelectionParams

P = SelectionParams(
    score_enter=0.6,
    score_exit=0.4,
    road_enter=0.6,
    road_exit=0.4,
    min_dwell_s=1.0,
    max_kappa_rate=0.2,
    stop_decel_mps2=1.0,
)
ODO, RRC = Candidate(3.0, 0.01), Candidate(2.0, -0.02)
RRC_REMEMBERED = Candidate(0.0, -0.03, stop_only=True)  # the road lost, remembered: steers a stop only
LEVELS = (None, 0.2, 0.5, 0.9)  # missing, below exit, between exit and enter, above enter
P_CREEP = SelectionParams(
    **{**P.__dict__, "creep_after_s": 2.0, "creep_speed_mps": 0.8, "creep_distance_m": 4.0},
)
STDS = (None, 0.1, 0.27, 0.5)  # the pose's σ: missing, within enter, between enter and exit, beyond exit
ROOM = 1.0  # (road width - vehicle width) / 2: σ within 0.7 / 3 = 0.23 m to begin a creep, 0.7 / 2.5 = 0.28 to go on
ROOMS = (None, 0.2, ROOM)  # the road's width unknown, narrower than the clearance, a 4 m road
FIX = 0.2  # a GNSS fix anchored the pose 0.2 s ago (the creep's limit: 2 s)
FIX_AGES = (None, FIX, 5.0)  # never a fix (or unknown), a fresh one, dead reckoning for 5 s


def rule(
    current: Mode, i: Inputs, dwelt: bool, p: SelectionParams = P, stood: bool = False, crept: bool = False
) -> Mode:
    """The module docstring's order of trust, as plainly as it reads. stood: standing still in a
    stop for creep_after_s; crept: the creep in charge has gone its distance."""

    def ok(mode: Mode) -> bool:
        holding = mode is current
        if mode is Mode.CREEP:
            return (
                p.creep_distance_m > 0
                and i.odometry is not None
                and i.pose_std_m is not None
                and i.fix_age_s is not None
                and i.fix_age_s <= p.creep_fix_age_s
                and i.road_room_m is not None
                and i.road_room_m > p.creep_clearance_m
                and i.pose_std_m
                <= (i.road_room_m - p.creep_clearance_m) / (p.creep_sigmas_exit if holding else p.creep_sigmas_enter)
                and (not crept if holding else stood)
            )
        if mode is Mode.ODOMETRY:
            return i.odometry is not None and (
                i.force_odometry
                or (i.odometry_score is not None and i.odometry_score >= (P.score_exit if holding else P.score_enter))
            )
        if mode is Mode.RRC:
            return (
                i.rrc is not None
                and not i.rrc.stop_only
                and not (i.force_odometry and i.odometry is not None)
                and i.road_confidence is not None
                and i.road_confidence >= (P.road_exit if holding else P.road_enter)
            )
        return True

    want = next((m for m in (Mode.ODOMETRY, Mode.RRC, Mode.CREEP) if ok(m)), Mode.STOP)
    return want if want is not current and (not ok(current) or dwelt) else current


CASES = list(
    itertools.product(Mode, LEVELS, LEVELS, (False, True), (None, ODO), (None, RRC, RRC_REMEMBERED), (False, True))
)


@pytest.mark.parametrize("current,score,road,force,odo,rrc,dwelt", CASES)
def test_every_mode_and_input(current, score, road, force, odo, rrc, dwelt):
    selector = ControlSelector(P, start=current)
    selector.since, selector.last_t = 0.0, 0.0
    inputs = Inputs(score, road, force, odo, rrc)
    decision = selector.step(1.5 if dwelt else 0.5, inputs)
    assert decision.mode is rule(current, inputs, dwelt)
    assert decision.switched == (decision.mode is not current) and decision.reason
    # never a stale candidate, never a stop-only one; forced odometry always wins when its candidate is there
    assert {Mode.ODOMETRY: odo, Mode.RRC: rrc}.get(decision.mode, "stop") is not None
    assert not (decision.mode is Mode.RRC and rrc.stop_only)
    if force and odo is not None and (current is not Mode.STOP or dwelt):
        assert decision.mode is Mode.ODOMETRY  # (a stop, once begun, lasts its dwell)
    if decision.mode is Mode.STOP and current is not Mode.STOP:
        assert rule(Mode.STOP, inputs, True) is Mode.STOP  # left for STOP only when nothing else would do


def test_every_mode_input_and_creep_state_with_creeping_on():
    """Every mode × input × pose σ × the road's room × the last fix's age × (stood long enough,
    crept its distance): in one test, not 110,592 parametrized ones."""
    checked = 0
    for (current, score, road, force, odo, rrc, dwelt), std, room, fix, stood, crept in itertools.product(
        CASES, STDS, ROOMS, FIX_AGES, (False, True), (False, True)
    ):
        t = 1.5 if dwelt else 0.5
        selector = ControlSelector(P_CREEP, start=current)
        selector.since, selector.last_t = 0.0, 0.0
        if current is Mode.STOP:
            selector.v, selector.standing_since = 0.0, (t - 3.0 if stood else None)
        if current is Mode.CREEP:
            selector.crept_m = P_CREEP.creep_distance_m if crept else 0.0
        inputs = Inputs(score, road, force, odo, rrc, std, room, fix)
        decision = selector.step(t, inputs)
        expected = rule(current, inputs, dwelt, P_CREEP, stood=stood and current is Mode.STOP, crept=crept)
        case = (current, score, road, force, odo, rrc, dwelt, std, room, fix, stood, crept)
        assert decision.mode is expected, case
        if decision.mode is Mode.CREEP:
            assert odo is not None and decision.v <= P_CREEP.creep_speed_mps, case
            assert std is not None and room is not None and fix is not None and fix <= P_CREEP.creep_fix_age_s, case
            assert std <= P_CREEP.creep_std_limit(room, holding=True), case
        checked += 1
    assert checked == len(CASES) * 144


def test_a_stop_that_stands_creeps_on_the_odometry_then_stands_again():
    selector = ControlSelector(P_CREEP, start=Mode.RRC)
    remembered = Inputs(0.0, 0.1, False, ODO, RRC_REMEMBERED, 0.1, ROOM, FIX)
    selector.step(0.0, Inputs(0.0, 0.9, False, ODO, RRC, 0.1, ROOM, FIX))
    t, modes = 0.0, []
    while t < 20.0:
        t = round(t + 0.1, 1)
        modes.append((t, selector.step(t, remembered)))
    stop_at = next(t for t, d in modes if d.mode is Mode.STOP)
    standing_at = next(t for t, d in modes if d.v == 0.0)
    creep_at = next(t for t, d in modes if d.mode is Mode.CREEP)
    assert stop_at == 0.1 and standing_at == pytest.approx(2.0)  # from 2 m/s at 1 m/s², the first 0.1 s at 0.1
    assert creep_at == pytest.approx(standing_at + P_CREEP.creep_after_s)  # stood 2 s
    creeping = [d for t, d in modes if d.mode is Mode.CREEP]
    assert all(d.v == pytest.approx(0.8) for d in creeping) and "pose σ 0.10 m" in creeping[0].reason
    # 4 m at 0.8 m/s: 5 s of creeping, then a stop that stands 2 s, and the next creep
    first_leg = [t for t, d in modes if d.mode is Mode.CREEP and t < creep_at + 6]
    assert len(first_leg) == pytest.approx(51, abs=1)
    after = [d for t, d in modes if t > creep_at and d.mode is not Mode.CREEP]
    assert (
        after[0].switched
        and after[0].mode is Mode.STOP
        and after[0].cause == "crept"
        and "standing again" in after[0].reason
    )
    assert any(d.mode is Mode.CREEP for t, d in modes if t > creep_at + 8.5)


def test_a_creep_ends_as_the_pose_grows_uncertain_or_a_trusted_mode_returns():
    selector = ControlSelector(P_CREEP, start=Mode.CREEP)
    selector.step(0.0, Inputs(0.0, None, False, ODO, None, 0.27, ROOM, FIX))  # between enter and exit: kept
    assert selector.mode is Mode.CREEP
    d = selector.step(0.1, Inputs(0.0, None, False, ODO, None, 0.29, ROOM, FIX))
    assert d.mode is Mode.STOP and d.cause == "pose_std_high"
    selector = ControlSelector(P_CREEP, start=Mode.CREEP)
    selector.step(0.0, Inputs(0.0, None, False, ODO, None, 0.1, ROOM, FIX))
    assert selector.step(0.5, Inputs(0.0, 0.9, False, ODO, RRC, 0.1, ROOM, FIX)).mode is Mode.CREEP  # the dwell
    assert selector.step(1.1, Inputs(0.0, 0.9, False, ODO, RRC, 0.1, ROOM, FIX)).mode is Mode.RRC
    assert selector.step(1.2, Inputs(0.0, None, False, None, None, 0.1, ROOM, FIX)).mode is Mode.STOP
    d = selector.step(9.0, Inputs(0.0, None, False, ODO, None, None, ROOM, FIX))  # standing, but no pose
    # the sentence names what each mode lacks, the creep's too: why a standing shuttle does not creep
    assert d.mode is Mode.STOP and d.reason.endswith("; no creep: no fresh pose to creep by")


def test_the_road_s_room_sets_how_uncertain_a_pose_may_be_to_creep_by():
    """σ 0.45 m: a creep on the tour's 6 m roads (room 2.0 m: within 0.57 m), none on a 4 m road
    (room 1.0 m: 0.23 m), none in its 3.2 m lane between walls, none where the width is unknown."""
    shuttle_width = 1.99
    for road_width, room, creeps, says in (
        (6.0, (6.0 - shuttle_width) / 2, True, "pose σ 0.45 m"),
        (4.0, (4.0 - shuttle_width) / 2, False, "the pose's σ 0.45 m is too large to creep by here (at most 0.23 m)"),
        (3.2, (3.2 - shuttle_width) / 2, False, "at most 0.10 m"),
        (2.5, (2.5 - shuttle_width) / 2, False, "the road leaves no room to creep by"),
        (None, None, False, "the road's width here is unknown"),
    ):
        selector = ControlSelector(P_CREEP, start=Mode.STOP)
        selector.step(0.0, Inputs(0.0, None, False, ODO, None, 0.45, room, FIX))
        d = selector.step(2.5, Inputs(0.0, None, False, ODO, None, 0.45, room, FIX))  # stood 2.5 s
        assert (d.mode is Mode.CREEP) is creeps and says in d.reason, (road_width, d.reason)


def test_a_dead_reckoned_pose_never_creeps_however_small_its_sigma():
    for fix, says in ((None, "the pose is dead-reckoned (no GNSS fix known)"), (2.5, "no GNSS fix for 2.5 s")):
        selector = ControlSelector(P_CREEP, start=Mode.STOP)
        selector.step(0.0, Inputs(0.0, None, False, ODO, None, 0.01, 2.0, fix))
        d = selector.step(5.0, Inputs(0.0, None, False, ODO, None, 0.01, 2.0, fix))
        assert d.mode is Mode.STOP and d.reason.endswith(f"no creep: {says}" if fix is None else f"({says})")
    # a creep under way ends when the fixes stop
    selector = ControlSelector(P_CREEP, start=Mode.CREEP)
    assert selector.step(0.0, Inputs(0.0, None, False, ODO, None, 0.01, 2.0, FIX)).mode is Mode.CREEP
    d = selector.step(0.1, Inputs(0.0, None, False, ODO, None, 0.01, 2.0, 2.1))
    assert d.mode is Mode.STOP and d.cause == "dead_reckoning"


def test_hysteresis_keeps_odometry_down_to_its_exit_threshold():
    selector = ControlSelector(P, start=Mode.STOP)
    t = 0.0
    selector.step(t, Inputs(None, None, False, None, None))  # at start-up: stopped
    for t, score, expected in (
        (1.1, 0.5, Mode.RRC),  # between the thresholds: not trusted yet
        (1.5, 0.65, Mode.RRC),  # trusted, but the RRC's dwell has not passed
        (2.2, 0.65, Mode.ODOMETRY),
        (3.5, 0.45, Mode.ODOMETRY),  # held down to the exit threshold
        (4.8, 0.39, Mode.RRC),
    ):
        assert selector.step(t, Inputs(score, 0.9, False, ODO, RRC)).mode is expected, (score, t)


def test_a_switch_ramps_the_curvature_at_the_steering_rate():
    selector = ControlSelector(P, start=Mode.ODOMETRY)
    selector.step(0.0, Inputs(0.9, 0.9, False, Candidate(3.0, 0.0), Candidate(3.0, 0.1)))
    d = selector.step(0.1, Inputs(0.1, 0.9, False, Candidate(3.0, 0.0), Candidate(3.0, 0.1)))
    assert d.mode is Mode.RRC and d.switched and d.kappa == pytest.approx(0.02)  # 0.2 /m/s × 0.1 s
    assert "odometry score 0.10 too low" in d.reason
    for t in (0.2, 0.3, 0.4, 0.5):  # 0.02 a step ...
        d = selector.step(t, Inputs(0.1, 0.9, False, Candidate(3.0, 0.0), Candidate(3.0, 0.1)))
    assert d.kappa == pytest.approx(0.1)  # ... caught up at 0.5 s
    d = selector.step(0.6, Inputs(0.1, 0.9, False, Candidate(3.0, 0.0), Candidate(3.0, 0.16)))
    assert d.kappa == 0.16  # then the RRC's own command, not delayed


def test_a_controlled_stop_slows_and_holds_the_curvature():
    selector = ControlSelector(P, start=Mode.ODOMETRY)
    selector.step(0.0, Inputs(0.9, None, False, Candidate(3.0, 0.05), None))
    d = selector.step(0.5, Inputs(None, None, False, None, None))
    assert d.mode is Mode.STOP and d.v == pytest.approx(2.5) and d.kappa == pytest.approx(0.05)
    assert "nothing deserves trust" in d.reason
    assert selector.step(5.0, Inputs(None, None, False, None, None)).v == 0.0


def test_a_controlled_stop_steers_along_the_rrc_at_the_steering_rate():
    selector = ControlSelector(P, start=Mode.RRC)
    selector.step(0.0, Inputs(None, 0.9, False, None, Candidate(2.5, 0.05)))
    d = selector.step(0.1, Inputs(None, 0.1, False, None, Candidate(0.0, -0.05, stop_only=True)))
    assert d.mode is Mode.STOP and d.v == pytest.approx(2.4) and d.kappa == pytest.approx(0.03)  # 0.2 /m/s × 0.1 s
    for t in (0.2, 0.3, 0.4, 0.5, 0.6):
        d = selector.step(t, Inputs(None, 0.1, False, None, Candidate(0.0, -0.05, stop_only=True)))
    assert d.kappa == pytest.approx(-0.05) and d.mode is Mode.STOP and d.v == pytest.approx(1.9)
    d = selector.step(0.7, Inputs(None, 0.1, False, None, None))  # the memory ran out: held
    assert d.kappa == pytest.approx(-0.05)


def test_a_stop_steers_by_the_odometry_while_the_pose_is_good_enough_to_creep_by():
    # before a crossing, in a GNSS outage, the RRC's remembered road bent away (k +0.05) while the
    # path ran straight: a pose good enough to creep by, or dead-reckoned for no longer than 30 s,
    # steers the stop along the path (k 0)
    bent, straight = Candidate(0.0, 0.05, stop_only=True), Candidate(3.0, 0.0)
    for std, fix, creeping, expected in (
        (0.05, FIX, P_CREEP, 0.0),
        (0.05, 20.0, P_CREEP, 0.0),  # dead-reckoned 20 s: too long to creep by, not to steer a stop by
        (0.05, 40.0, P_CREEP, 0.05),
        (0.05, None, P_CREEP, 0.05),
        (0.5, FIX, P_CREEP, 0.05),  # beyond what a 4 m road's room holds
        (None, FIX, P_CREEP, 0.05),
        (0.05, FIX, P, 0.05),  # creeping off
    ):
        selector = ControlSelector(creeping, start=Mode.STOP)
        selector.step(0.0, Inputs(0.0, None, False, straight, bent, std, ROOM, fix))
        for t in (0.5, 1.0):  # (the steering's rate: 0.2 /m/s; standing, a creep would begin at 2 s)
            d = selector.step(t, Inputs(0.0, None, False, straight, bent, std, ROOM, fix))
        assert d.mode is Mode.STOP and d.kappa == pytest.approx(expected), (std, fix, creeping.creep_distance_m)


def test_a_pinned_stop_holds_the_curvature_whatever_the_rrc_says():
    selector = ControlSelector(
        SelectionParams(0.6, 0.4, 0.6, 0.4, 1.0, 0.2, 1.0, pinned=Mode.ODOMETRY), start=Mode.ODOMETRY
    )
    selector.step(0.0, Inputs(0.9, None, False, Candidate(3.0, 0.05), None))
    d = selector.step(0.5, Inputs(0.9, 0.9, False, None, Candidate(2.0, -0.1)))
    assert d.mode is Mode.STOP and d.kappa == pytest.approx(0.05)


def test_thresholds_are_checked():
    with pytest.raises(ValueError):
        SelectionParams(0.4, 0.6, 0.6, 0.4, 1.0, 0.2, 1.0)
    with pytest.raises(ValueError):
        SelectionParams(0.6, 0.4, 0.6, 0.4, 1.0, 0.2, 1.0, creep_sigmas_enter=2.0, creep_sigmas_exit=3.0)
    with pytest.raises(ValueError):
        SelectionParams(0.6, 0.4, 0.6, 0.4, 1.0, 0.2, 1.0, creep_fix_age_s=5.0, stop_steer_fix_age_s=3.0)


maybe_level = st.one_of(st.none(), st.floats(0.0, 1.0))
maybe_candidate = st.one_of(st.none(), st.builds(Candidate, st.floats(0.0, 5.0), st.floats(-0.3, 0.3), st.booleans()))
maybe_std = st.one_of(st.none(), st.floats(0.0, 0.6))
maybe_room = st.one_of(st.none(), st.floats(0.0, 3.0))
maybe_fix_age = st.one_of(st.none(), st.floats(0.0, 5.0))
cycle = st.tuples(
    st.floats(0.01, 0.6),
    maybe_level,
    maybe_level,
    st.booleans(),
    maybe_candidate,
    maybe_candidate,
    maybe_std,
    maybe_room,
    maybe_fix_age,
)


@settings(max_examples=300, deadline=None)
@given(st.sampled_from(list(Mode)), st.lists(cycle, min_size=1, max_size=60), st.sampled_from([P, P_CREEP]))
def test_properties_over_random_sequences(start, cycles, p):
    selector = ControlSelector(p, start=start)
    t, last_switch, kappa, v, mode = 0.0, 0.0, None, None, start
    standing_since, crept = None, 0.0
    for dt, score, road, force, odo, rrc, std, room, fix in cycles:
        t += dt
        inputs = Inputs(score, road, force, odo, rrc, std, room, fix)
        held_ok, _, _ = selector.acceptable(mode, inputs, holding=True)
        ramping = selector.catching_up
        d = selector.step(t, inputs)
        assert {Mode.ODOMETRY: odo, Mode.RRC: rrc, Mode.CREEP: odo}.get(d.mode, "stop") is not None
        assert not (d.mode is Mode.RRC and rrc.stop_only)  # a stop-only candidate never drives
        if d.switched:
            assert held_ok is False or t - last_switch >= p.min_dwell_s - 1e-9  # early only when it had to
            last_switch = t
        if d.mode is Mode.CREEP:
            assert p.creep_distance_m > 0 and std is not None and room is not None
            assert fix is not None and fix <= p.creep_fix_age_s  # never on dead reckoning
            assert std <= p.creep_std_limit(room, holding=True)  # the road's room holds the pose's σ
            assert d.v <= p.creep_speed_mps
            if d.switched:  # only from a stop that stood still long enough
                assert mode is Mode.STOP and standing_since is not None and t - standing_since >= p.creep_after_s
                crept = 0.0
            crept += d.v * dt
            assert crept <= p.creep_distance_m + p.creep_speed_mps * 0.6  # its distance, give or take a cycle
        target = {Mode.ODOMETRY: odo, Mode.RRC: rrc, Mode.CREEP: odo}.get(d.mode)
        if kappa is not None and (d.switched or ramping or target is None):
            assert abs(d.kappa - kappa) <= p.max_kappa_rate * dt + 1e-9  # a switch, a stop: bumpless
        elif kappa is not None:
            assert d.kappa == target.kappa  # in charge and caught up: passed through, never delayed
        if d.mode is Mode.STOP and mode is Mode.STOP and v is not None:
            assert d.v <= v + 1e-9
        standing_since = (
            (standing_since if standing_since is not None else t) if d.mode is Mode.STOP and d.v == 0 else None
        )
        kappa, v, mode = d.kappa, d.v, d.mode


PINNED = [SelectionParams(0.6, 0.4, 0.6, 0.4, 1.0, 0.2, 1.0, pinned=mode) for mode in (Mode.ODOMETRY, Mode.RRC)]


@pytest.mark.parametrize("params", PINNED, ids=lambda p: p.pinned.value)
@pytest.mark.parametrize("current,score,road,force,odo,rrc,dwelt", CASES)
def test_a_pinned_mode_drives_whenever_its_candidate_is_there(params, current, score, road, force, odo, rrc, dwelt):
    selector = ControlSelector(params, start=current)
    selector.since, selector.last_t = 0.0, 0.0
    decision = selector.step(1.5 if dwelt else 0.5, Inputs(score, road, force, odo, rrc))
    pinned = {Mode.ODOMETRY: odo, Mode.RRC: rrc}[params.pinned]
    available = pinned is not None and not pinned.stop_only
    if available and (current is not Mode.STOP or dwelt):
        assert decision.mode is params.pinned and decision.cause == "pinned"
    elif not available:
        assert decision.mode is Mode.STOP
    assert decision.mode in (params.pinned, Mode.STOP) or decision.mode is current


def test_switch_causes_are_short_codes():
    selector = ControlSelector(P, start=Mode.ODOMETRY)
    selector.step(0.0, Inputs(0.9, 0.9, False, ODO, RRC))
    d = selector.step(2.0, Inputs(0.1, 0.9, False, ODO, RRC))
    assert (d.mode, d.switched, d.cause) == (Mode.RRC, True, "score_low")
    d = selector.step(4.0, Inputs(0.9, 0.9, True, ODO, RRC))
    assert (d.mode, d.switched, d.cause) == (Mode.ODOMETRY, True, "forced")
    d = selector.step(4.1, Inputs(0.9, 0.9, False, None, None))
    assert (d.mode, d.switched, d.cause) == (Mode.STOP, True, "no_candidate")
    selector = ControlSelector(P, start=Mode.RRC)
    selector.step(0.0, Inputs(0.1, 0.9, False, ODO, RRC))
    d = selector.step(0.1, Inputs(0.1, 0.9, False, ODO, RRC_REMEMBERED))
    assert (d.mode, d.switched, d.cause) == (Mode.STOP, True, "stop_only") and "only steers a stop" in d.reason
