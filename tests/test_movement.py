"""The movement gate (managers/movement.py): every gate state × every combination of inputs
against the rule written out plainly, then hypothesis properties over random sequences (the
command never above an active limit, level 1 never cleared without a re-arm, the vehicle's
acceleration and the steering's rate respected)."""

from __future__ import annotations

import itertools

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from managers.movement import GateInputs, GateLimits, Level, MovementGate

LIMITS = GateLimits(
    max_accel_mps2=1.5, max_decel_mps2=1.5, max_jerk_mps3=2.0, max_kappa=0.11, max_kappa_rate=0.3, stop_decel_mps2=1.0
)
DT = 0.02
COMMANDS = (None, (3.0, 0.05), (0.5, -0.05))
SPEED_LIMITS = (None, 1.0, 5.0)
LEVELS = (None, Level.NOMINAL, Level.CRITICAL, Level.LOW)
STATES = ("cruising", "stopping", "latched")


def gate_in(state: str) -> MovementGate:
    """A gate at 2 m/s following a command, in the middle of a controlled stop, or latched."""
    gate = MovementGate(LIMITS)
    gate.v, gate.kappa = 2.0, 0.02
    if state == "stopping":
        gate.step(DT, GateInputs(command=(3.0, 0.02), limits={"speed": 5.0}, level=Level.LOW, level_cause="imu"))
    elif state == "latched":
        gate.step(DT, GateInputs(command=(3.0, 0.02), limits={"speed": 5.0}, level=Level.CRITICAL, level_cause="lidar"))
    return gate


@pytest.mark.parametrize("state,level,command,speed", list(itertools.product(STATES, LEVELS, COMMANDS, SPEED_LIMITS)))
def test_every_state_and_input(state, level, command, speed):
    gate = gate_in(state)
    v_before = gate.v
    out = gate.step(DT, GateInputs(command=command, limits={"speed": speed}, level=level, level_cause="cause"))
    if state == "latched" or level is Level.CRITICAL:
        # level 1, now or before: an emergency stop, latched
        assert out.emergency and out.v == 0.0 and gate.latched and out.limited_by == "emergency"
        return
    assert not out.emergency and not gate.latched
    must_stop = level in (None, Level.LOW) or command is None or speed is None
    assert out.stopping == must_stop
    if must_stop:
        # a controlled stop: slowing at the stop's deceleration at least, never faster than before
        assert out.v <= max(0.0, v_before - LIMITS.stop_decel_mps2 * DT) + 1e-12
        assert out.reason.startswith("stopping")
    else:
        assert out.v <= speed
        # below the limit, the speed moves towards the command no faster than the vehicle may
        wanted = min(speed, command[0])
        if out.v != speed:
            step = LIMITS.max_accel_mps2 if wanted > v_before else LIMITS.max_decel_mps2
            assert abs(out.v - v_before) <= step * DT + 1e-12
            assert min(v_before, wanted) - 1e-12 <= out.v <= max(v_before, wanted) + 1e-12
    assert out.v <= out.limit_mps + 1e-12
    assert abs(out.kappa - 0.02) <= LIMITS.max_kappa_rate * DT + 1e-12


def test_a_limit_applies_at_once_and_speed_comes_back_gently():
    gate = MovementGate(LIMITS)
    gate.v = 3.0
    out = gate.step(DT, GateInputs(command=(3.0, 0.0), limits={"speed": 1.0}))
    assert out.v == 1.0 and out.limited_by == "speed" and out.reason.startswith("limited by speed")
    speeds = [gate.step(DT, GateInputs(command=(3.0, 0.0), limits={"speed": 5.0})).v for _ in range(200)]
    steps = [b - a for a, b in zip([1.0, *speeds], speeds)]
    assert max(steps) <= LIMITS.max_accel_mps2 * DT + 1e-12
    assert steps[0] <= LIMITS.max_jerk_mps3 * DT * DT + 1e-12  # the acceleration builds up within the jerk
    assert speeds[-1] == pytest.approx(3.0)


def test_level_2_stops_under_control_and_goes_on_by_itself():
    gate = MovementGate(LIMITS)
    gate.v = 2.0
    low = GateInputs(command=(2.0, 0.0), limits={"speed": 5.0}, level=Level.LOW, level_cause="gnss: 2 Hz < 4")
    speeds = [gate.step(DT, low).v for _ in range(150)]
    assert speeds[-1] == 0.0 and speeds[0] == pytest.approx(2.0 - LIMITS.stop_decel_mps2 * DT)
    assert all(b <= a for a, b in zip(speeds, speeds[1:]))
    out = gate.step(DT, GateInputs(command=(2.0, 0.0), limits={"speed": 5.0}))
    assert not out.stopping and out.v > 0.0 and out.reason == "following the control manager"


def test_level_1_latches_until_a_rearm_that_is_refused_while_it_lasts():
    gate = MovementGate(LIMITS)
    gate.v = 2.0
    assert gate.rearm(Level.NOMINAL) == (False, "nothing to re-arm: no emergency stop is latched")
    gate.step(
        DT, GateInputs(command=(2.0, 0.0), limits={"speed": 5.0}, level=Level.CRITICAL, level_cause="lidar roof: blind")
    )
    for _ in range(50):  # cleared, but still latched
        assert gate.step(DT, GateInputs(command=(2.0, 0.0), limits={"speed": 5.0})).emergency
    accepted, reason = gate.rearm(Level.CRITICAL)
    assert not accepted and "level 1 persists (lidar roof: blind)" in reason and gate.latched
    accepted, reason = gate.rearm(Level.NOMINAL)
    assert accepted and reason == "re-armed after: lidar roof: blind" and not gate.latched
    out = gate.step(DT, GateInputs(command=(2.0, 0.0), limits={"speed": 5.0}))
    assert not out.emergency and out.v > 0.0


STEP = st.fixed_dictionaries(
    {
        "command": st.one_of(st.none(), st.tuples(st.floats(-1.0, 6.0), st.floats(-0.5, 0.5))),
        "speed": st.one_of(st.none(), st.floats(0.0, 6.0)),
        "obstacle": st.one_of(st.none(), st.floats(0.0, 6.0)),
        "level": st.sampled_from(LEVELS),
        "rearm": st.booleans(),
    }
)


@settings(max_examples=300, deadline=None)
@given(st.lists(STEP, min_size=1, max_size=80))
def test_properties_over_random_sequences(steps):
    gate = MovementGate(LIMITS)
    latched_without_rearm = False
    for s in steps:
        if s["rearm"]:
            accepted, _ = gate.rearm(s["level"])
            assert not accepted or s["level"] is not Level.CRITICAL
            if accepted:
                latched_without_rearm = False
        v_before, kappa_before = gate.v, gate.kappa
        out = gate.step(
            DT,
            GateInputs(command=s["command"], limits={"speed": s["speed"], "obstacle": s["obstacle"]}, level=s["level"]),
        )
        if s["level"] is Level.CRITICAL:
            latched_without_rearm = True
        # level 1 never clears without a re-arm
        assert out.emergency == latched_without_rearm
        # never above an active limit, never backwards
        active = [v for v in (s["speed"], s["obstacle"]) if v is not None]
        assert 0.0 <= out.v <= min(active, default=float("inf")) + 1e-12
        if out.emergency:
            assert out.v == 0.0
        # within the vehicle's acceleration; the curvature within its bound and rate
        assert out.v - v_before <= LIMITS.max_accel_mps2 * DT + 1e-12
        assert abs(out.kappa) <= LIMITS.max_kappa + 1e-12
        assert abs(out.kappa - kappa_before) <= LIMITS.max_kappa_rate * DT + 1e-12
        # a stop is a stop: nothing missing or low lets the speed rise
        if out.stopping:
            assert out.v <= v_before + 1e-12
