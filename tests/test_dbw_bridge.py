"""The drive-by-wire bridge's decision core against Fig. 17 of the DBW paper and §4.5's 1 s
setpoint timeout: every (mode, event) pair by hand, then random event sequences."""

import itertools
import json
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, initialize, invariant, rule

from ares.core import config
from ares.core.config import ConfigError, VehicleProfile
from control.dbw_bridge import (
    DRIVER_ACTIONS,
    TRANSITIONS,
    Command,
    DbwCore,
    DbwLimits,
    Event,
    EventKind,
    Mode,
    command_gate,
    setpoint_problem,
)

# A Techs4AgeCar-like profile (the shuttle's with the car's geometry and top speed): max
# curvature tan(0.349)/2.36 = 0.15419 1/m.
PROFILE = config.load_vehicle(
    "ares_shuttle",
    {
        "wheelbase_m": 2.36,
        "track_m": 1.315,
        "wheel_radius_m": 0.28,
        "steering_ratio": 40,
        "max_wheel_angle_rad": 0.349,
        "max_speed_mps": 6.9,
    },
)
LIMITS = DbwLimits.from_profile(PROFILE)
MAX_KAPPA = math.tan(0.349) / 2.36
TIMEOUT = 1.0

M, R, A = Mode.MANUAL, Mode.READY, Mode.AUTOMATIC
K = EventKind

# Fig. 17, written out again independently of the module's table.
#                 BUTTON SET_AUTO THROTTLE BRAKE STEERING SETPOINT TICK
FIG17 = {
    M: dict(zip(K, [R, M, M, M, M, M, M])),
    R: dict(zip(K, [M, A, M, M, M, R, R])),
    A: dict(zip(K, [M, A, M, M, M, A, A])),
}
assert list(K) == [K.BUTTON, K.SET_AUTOMATIC, K.THROTTLE_PEDAL, K.BRAKE_PEDAL, K.STEERING_WHEEL, K.SETPOINT, K.TICK]

# In the scenario below the AUTOMATIC core last got (2.0, -0.05) at t = 10.0, the event comes
# at t = 10.5, and a SETPOINT event carries (1.5, 0.05). Expected output (engaged, v, kappa).
OLD_SETPOINT, NEW_SETPOINT = (2.0, -0.05), (1.5, 0.05)
MANUAL_OUT, NULL_ENGAGED = (False, 0.0, 0.0), (True, 0.0, 0.0)
EXPECTED_OUTPUT = {
    (M, K.BUTTON): NULL_ENGAGED,
    (R, K.SET_AUTOMATIC): NULL_ENGAGED,  # just switched: wait for a newer setpoint
    (A, K.SET_AUTOMATIC): (True, *OLD_SETPOINT),
    (A, K.SETPOINT): (True, *NEW_SETPOINT),
    (A, K.TICK): (True, *OLD_SETPOINT),
    (R, K.SETPOINT): NULL_ENGAGED,
    (R, K.TICK): NULL_ENGAGED,
}


def make_event(kind: EventKind, t: float) -> Event:
    if kind is K.SETPOINT:
        return Event.setpoint(*NEW_SETPOINT, t)
    return Event(kind, t)


def core_in(mode: Mode) -> DbwCore:
    """A core brought into `mode` by the paper's own path, with a setpoint at t = 10.0."""
    core = DbwCore(LIMITS, TIMEOUT)
    if mode is not M:
        core.handle(Event.button(9.0))
    if mode is A:
        core.handle(Event.set_automatic(9.5))
    core.handle(Event.setpoint(*OLD_SETPOINT, 10.0))
    assert core.mode is mode
    return core


def test_table_lists_every_mode_and_event_exactly_once():
    assert set(TRANSITIONS) == set(itertools.product(Mode, EventKind))
    assert len(TRANSITIONS) == len(Mode) * len(EventKind) == 21


def test_table_is_fig17():
    assert {(mode, kind): FIG17[mode][kind] for mode in Mode for kind in EventKind} == TRANSITIONS


@pytest.mark.parametrize("mode, kind", list(itertools.product(Mode, EventKind)), ids=lambda x: x.value)
def test_every_mode_and_event(mode, kind):
    core = core_in(mode)
    records_before = len(core.history)
    outcome = core.handle(make_event(kind, 10.5))
    expected_mode = FIG17[mode][kind]

    assert core.mode is expected_mode
    assert outcome.command.mode is expected_mode

    # A record exactly when the mode changes, carrying from, to, event, t and a reason.
    if expected_mode is mode:
        assert outcome.transition is None
        assert len(core.history) == records_before
    else:
        tr = outcome.transition
        assert (tr.from_mode, tr.to_mode, tr.event, tr.t) == (mode, expected_mode, kind, 10.5)
        assert tr.reason and core.history[-1] == tr
        assert tr.as_dict()["from"] == mode.value and tr.as_dict()["to"] == expected_mode.value

    # Only the service request in MANUAL is refused.
    assert outcome.accepted is not (mode is M and kind is K.SET_AUTOMATIC)

    command = outcome.command
    engaged, v, kappa = EXPECTED_OUTPUT.get((mode, kind), MANUAL_OUT)
    assert (command.engaged, command.v, command.kappa) == (engaged, pytest.approx(v), pytest.approx(kappa))
    assert not command.watchdog_tripped
    assert command == core.command(10.5)


@pytest.mark.parametrize("mode", list(Mode), ids=lambda m: m.value)
@pytest.mark.parametrize("kind", sorted(DRIVER_ACTIONS), ids=lambda k: k.value)
def test_driver_action_always_gives_manual(mode, kind):
    core = core_in(mode)
    outcome = core.handle(Event(kind, 10.2))
    assert core.mode is M and not outcome.command.engaged
    if mode is not M:
        assert "driver takes over" in outcome.transition.reason
        assert kind.value.lower().replace("_", " ") in outcome.transition.reason


# --- activation --------------------------------------------------------------------------------


def test_starts_in_manual_not_engaged():
    core = DbwCore(LIMITS)
    command = core.command(0.0)
    assert core.mode is M
    assert (command.engaged, command.v, command.kappa, command.watchdog_tripped) == (False, 0.0, 0.0, False)
    assert command.setpoint_age_s is None


def test_set_automatic_in_manual_is_refused_with_a_reason():
    core = DbwCore(LIMITS)
    outcome = core.handle(Event.set_automatic(1.0))
    assert not outcome.accepted
    assert "button" in outcome.reason and "MANUAL" in outcome.reason
    assert outcome.transition is None and core.mode is M and not core.history


def test_set_automatic_when_already_automatic_is_accepted_and_keeps_driving():
    core = core_in(A)
    outcome = core.handle(Event.set_automatic(10.2))
    assert outcome.accepted and outcome.transition is None
    assert "already" in outcome.reason
    assert (outcome.command.v, outcome.command.kappa) == OLD_SETPOINT


def test_full_activation_path_and_history():
    core = DbwCore(LIMITS)
    core.handle(Event.button(1.0))
    core.handle(Event.set_automatic(2.0))
    core.handle(Event.brake_pedal(3.0))
    assert [(tr.from_mode, tr.to_mode, tr.event, tr.t) for tr in core.history] == [
        (M, R, K.BUTTON, 1.0),
        (R, A, K.SET_AUTOMATIC, 2.0),
        (A, M, K.BRAKE_PEDAL, 3.0),
    ]


def test_history_is_bounded():
    core = DbwCore(LIMITS)
    for i in range(3 * DbwCore.HISTORY_LENGTH):
        core.handle(Event.button(float(i)))
    assert len(core.history) == DbwCore.HISTORY_LENGTH
    assert core.history[-1].t == 3 * DbwCore.HISTORY_LENGTH - 1


# --- setpoints and the watchdog ----------------------------------------------------------------


def automatic_core(t_switch: float = 0.0, timeout: float = TIMEOUT) -> DbwCore:
    core = DbwCore(LIMITS, timeout)
    core.handle(Event.button(t_switch))
    core.handle(Event.set_automatic(t_switch))
    return core


def test_stale_setpoint_from_ready_is_not_used_after_the_switch():
    core = DbwCore(LIMITS)
    core.handle(Event.button(0.0))
    core.handle(Event.setpoint(3.0, 0.1, 0.9))  # seen in READY
    core.handle(Event.set_automatic(1.0))
    waiting = core.command(1.05)
    assert waiting.is_null and waiting.engaged and not waiting.watchdog_tripped
    assert "waiting" in waiting.reason
    # Still nothing newer 1 s after the READY setpoint: the watchdog speaks.
    assert core.command(1.95).watchdog_tripped and core.command(1.95).is_null
    core.handle(Event.setpoint(1.0, 0.02, 1.1))
    assert (core.command(1.2).v, core.command(1.2).kappa) == (1.0, 0.02)


def test_reentering_automatic_forgets_the_previous_setpoint():
    core = automatic_core()
    core.handle(Event.setpoint(2.0, 0.0, 0.1))
    core.handle(Event.button(0.2))
    core.handle(Event.button(0.3))
    core.handle(Event.set_automatic(0.4))
    assert core.command(0.5).is_null
    assert not core.command(0.5).watchdog_tripped


def test_automatic_without_any_setpoint_is_null_and_tripped():
    command = automatic_core().command(0.0)
    assert command.is_null and command.engaged and command.watchdog_tripped
    assert "no setpoint received" in command.reason


def test_watchdog_trips_after_the_timeout_and_recovers_on_fresh_setpoints():
    core = automatic_core()
    first = core.handle(Event.setpoint(2.0, 0.1, 0.1))
    assert first.watchdog_changed  # recovered from "nothing yet"
    assert (first.command.v, first.command.kappa) == (2.0, 0.1)
    assert core.command(1.1).v == 2.0  # exactly 1 s old: still used
    tripped = core.handle(Event.tick(1.1001))
    assert tripped.command.is_null and tripped.command.watchdog_tripped and tripped.watchdog_changed
    assert "no setpoint for 1.000 s" in tripped.command.reason
    again = core.handle(Event.tick(1.5))
    assert again.command.watchdog_tripped and not again.watchdog_changed
    fresh = core.handle(Event.setpoint(1.0, -0.1, 2.0))
    assert fresh.watchdog_changed and not fresh.command.watchdog_tripped
    assert (fresh.command.v, fresh.command.kappa) == (1.0, -0.1)


def test_watchdog_timeout_is_a_parameter():
    core = automatic_core(timeout=0.3)
    core.handle(Event.setpoint(2.0, 0.0, 0.0))
    assert not core.command(0.3).watchdog_tripped
    assert core.command(0.31).watchdog_tripped
    with pytest.raises(ValueError):
        DbwCore(LIMITS, setpoint_timeout_s=0.0)


def test_watchdog_only_flags_in_automatic():
    for mode in (M, R):
        command = core_in(mode).command(100.0)
        assert command.is_null and not command.watchdog_tripped
        assert command.setpoint_age_s == pytest.approx(90.0)


def test_clock_going_backwards_stops_the_vehicle():
    core = automatic_core()
    core.handle(Event.setpoint(2.0, 0.0, 5.0))
    command = core.command(4.0)
    assert command.is_null and command.watchdog_tripped and "clock" in command.reason


@pytest.mark.parametrize(
    "v, kappa",
    [
        (math.nan, 0.0),
        (0.0, math.nan),
        (math.inf, 0.0),
        (1.0, -math.inf),
        (None, 0.0),
        ("1.0", 0.0),
        (True, 0.0),
        (1.0, [0.1]),
    ],
)
def test_invalid_setpoints_are_rejected_counted_and_do_not_feed_the_watchdog(v, kappa):
    core = automatic_core()
    core.handle(Event.setpoint(2.0, 0.05, 0.0))
    outcome = core.handle(Event.setpoint(v, kappa, 0.9))
    assert not outcome.accepted
    assert outcome.reason.startswith("setpoint rejected")
    assert core.rejected_setpoints == 1 and core.last_rejection == outcome.reason
    assert (outcome.command.v, outcome.command.kappa) == (2.0, 0.05)  # the last good one
    assert core.command(1.2).watchdog_tripped  # not refreshed at 0.9


def test_setpoint_outside_automatic_is_noted_but_not_used():
    core = DbwCore(LIMITS)
    outcome = core.handle(Event.setpoint(2.0, 0.0, 0.0))
    assert outcome.accepted and "not used in MANUAL" in outcome.reason
    assert core.last_setpoint.v == 2.0 and outcome.command.is_null


def test_setpoint_problem():
    assert setpoint_problem(1.0, 0.0) is None
    assert setpoint_problem(1, -0) is None
    assert "v is not finite" in setpoint_problem(math.nan, 0.0)
    assert "kappa is not a number" in setpoint_problem(1.0, None)


def test_event_time_must_be_finite():
    for bad in (math.nan, math.inf, None):
        with pytest.raises(ValueError, match="event time"):
            Event.tick(bad)


# --- the command gate ------------------------------------------------------------------------


@pytest.mark.parametrize(
    "v, kappa, expected",
    [
        (2.0, 0.1, (2.0, 0.1, False)),
        (10.0, 0.1, (6.9, 0.1, True)),
        (-1.0, 0.1, (0.0, 0.1, True)),
        (2.0, 0.5, (2.0, MAX_KAPPA, True)),
        (2.0, -0.5, (2.0, -MAX_KAPPA, True)),
        (math.nan, 0.1, (0.0, 0.0, True)),
        (1.0, math.inf, (0.0, 0.0, True)),
        (-0.0, -0.0, (0.0, 0.0, False)),
    ],
)
def test_command_gate(v, kappa, expected):
    out = command_gate(v, kappa, LIMITS)
    assert out == pytest.approx(expected)
    assert math.copysign(1, out[0]) == 1  # never a negative zero speed


def test_automatic_command_is_limited_to_the_vehicle():
    core = automatic_core()
    command = core.handle(Event.setpoint(50.0, -3.0, 0.1)).command
    assert (command.v, command.kappa) == (6.9, pytest.approx(-MAX_KAPPA))
    assert command.limited and "limited" in command.reason


def test_limits_from_the_shipped_shuttle_profile():
    shuttle = DbwLimits.from_profile(config.load_vehicle("ares_shuttle"))
    assert shuttle.max_speed_mps == 4.0
    assert shuttle.max_curvature == pytest.approx(math.tan(0.31) / 2.8)  # 0.11440 1/m


def test_limits_from_the_shipped_techs4agecar_profile():
    core = DbwCore.from_profile(config.load_vehicle("techs4agecar"), TIMEOUT)
    assert core.limits.max_curvature == pytest.approx(MAX_KAPPA)
    assert core.limits.max_speed_mps == 6.94  # 25 km/h


def test_core_from_profile_takes_the_watchdog_timeout():
    core = DbwCore.from_profile(PROFILE, 0.4)
    assert core.setpoint_timeout_s == 0.4 and core.limits == LIMITS


def test_a_profile_without_a_limit_is_refused_naming_the_key():
    data = {k: v for k, v in PROFILE.model_dump().items() if k != "max_speed_mps"}
    with pytest.raises(ConfigError, match="max_speed_mps: required, missing"):
        config.validated(VehicleProfile, data, "test profile")


@pytest.mark.parametrize(
    "key, bad",
    [("max_speed_mps", 0.0), ("max_speed_mps", math.inf), ("wheelbase_m", -2.36), ("max_wheel_angle_rad", math.nan)],
)
def test_a_profile_with_a_bad_limit_is_refused_naming_the_key(key, bad):
    # DbwLimits never sees such a profile: the typed model stops it where it is read
    with pytest.raises(ConfigError, match=f"{key}: Input should be"):
        config.validated(VehicleProfile, {**PROFILE.model_dump(), key: bad}, "test profile")


@pytest.mark.parametrize("speed, kappa", [(0.0, 0.1), (1.0, -0.1), (math.nan, 0.1), (1.0, math.inf)])
def test_limits_must_be_positive_and_finite(speed, kappa):
    with pytest.raises(ValueError):
        DbwLimits(speed, kappa)


# --- serialisation -----------------------------------------------------------------------------


def test_modes_and_records_serialise_as_plain_strings():
    assert json.dumps(Mode.AUTOMATIC) == '"AUTOMATIC"'
    core = core_in(A)
    outcome = core.handle(Event.steering_wheel(10.2))
    assert json.loads(json.dumps(outcome.transition.as_dict())) == {
        "from": "AUTOMATIC",
        "to": "MANUAL",
        "event": "STEERING_WHEEL",
        "t": 10.2,
        "reason": outcome.transition.reason,
    }
    as_dict = json.loads(json.dumps(outcome.command.as_dict()))
    assert as_dict["mode"] == "MANUAL" and as_dict["engaged"] is False
    assert set(as_dict) == {f for f in Command.__dataclass_fields__}


# --- random event sequences ------------------------------------------------------------------

# Mostly the bridge's 10 Hz rhythm, sometimes pauses around and beyond the 1 s timeout.
gaps = st.one_of(
    st.sampled_from([0.0, 0.1, 0.1, 0.1, 0.2, 0.5, 0.9, 1.0]),
    st.floats(min_value=0.0, max_value=1.5),
)
finite_or_not = st.one_of(
    st.floats(min_value=-20.0, max_value=20.0),
    st.sampled_from([math.nan, math.inf, -math.inf]),
)


class DbwSequences(RuleBasedStateMachine):
    """Random events at random times; a hand-written model of Fig. 17 and the watchdog
    alongside the core, and the safety properties checked after every step."""

    @initialize()
    def start(self):
        self.core = DbwCore(LIMITS, TIMEOUT)
        self.t = 0.0
        self.mode = M  # the model's own idea of the mode
        self.licensed = False  # SET_AUTOMATIC accepted in READY, no BUTTON/driver since
        self.last_valid_t = None  # time of the last valid setpoint, any mode
        self.since_switch = None  # (v, kappa) received since entering AUTOMATIC

    def advance(self, dt):
        self.t += dt

    def set_mode(self, mode):
        if mode is not self.mode:
            self.since_switch = None
        self.mode = mode

    @rule(dt=gaps)
    def button(self, dt):
        self.advance(dt)
        self.core.handle(Event.button(self.t))
        self.licensed = False
        self.set_mode(R if self.mode is M else M)

    @rule(dt=gaps)
    def set_automatic(self, dt):
        self.advance(dt)
        outcome = self.core.handle(Event.set_automatic(self.t))
        assert outcome.accepted == (self.mode is not M)
        if self.mode is R:
            self.licensed = True
            self.set_mode(A)

    @rule(dt=gaps)
    def operator_rearms(self, dt):
        # The usual way back to AUTOMATIC (button until READY, then the service) as one rule,
        # so that sequences leaving and re-entering AUTOMATIC are common.
        while self.mode is not R:
            self.button(dt)
        self.set_automatic(dt)

    @rule(dt=gaps, kind=st.sampled_from(sorted(DRIVER_ACTIONS)))
    def driver_action(self, dt, kind):
        self.advance(dt)
        outcome = self.core.handle(Event(kind, self.t))
        # The driver takes over at once, whatever the mode.
        assert self.core.mode is M and not outcome.command.engaged
        self.licensed = False
        self.set_mode(M)

    @rule(dt=gaps, v=finite_or_not, kappa=finite_or_not)
    def setpoint(self, dt, v, kappa):
        self.advance(dt)
        rejected_before = self.core.rejected_setpoints
        outcome = self.core.handle(Event.setpoint(v, kappa, self.t))
        valid = math.isfinite(v) and math.isfinite(kappa)
        assert outcome.accepted == valid
        assert self.core.rejected_setpoints == rejected_before + (not valid)
        if valid:
            self.last_valid_t = self.t
            if self.mode is A:
                self.since_switch = (v, kappa)

    @rule(dt=gaps)
    def tick(self, dt):
        self.advance(dt)
        self.core.handle(Event.tick(self.t))

    @invariant()
    def mode_follows_fig17(self):
        assert self.core.mode is self.mode

    @invariant()
    def automatic_only_with_both_activations(self):
        if self.core.mode is A:
            assert self.licensed

    @invariant()
    def output_is_safe(self):
        for t in (self.t, self.t + 0.5, self.t + 1.2):
            command = self.core.command(t)
            assert command.mode is self.core.mode
            assert math.isfinite(command.v) and math.isfinite(command.kappa)
            assert 0.0 <= command.v <= LIMITS.max_speed_mps
            assert abs(command.kappa) <= LIMITS.max_curvature
            if command.mode is M:
                assert not command.engaged and command.is_null
            else:
                assert command.engaged
            if command.mode is R:
                assert command.is_null and not command.watchdog_tripped
            if command.mode is A:
                self.check_automatic(command, t)

    def check_automatic(self, command, t):
        stale = self.last_valid_t is None or t - self.last_valid_t > TIMEOUT
        assert command.watchdog_tripped == stale
        if stale or self.since_switch is None:
            assert command.is_null
        else:
            expected_v, expected_kappa, _ = command_gate(*self.since_switch, LIMITS)
            assert (command.v, command.kappa) == (expected_v, expected_kappa)


DbwSequences.TestCase.settings = settings(max_examples=300, stateful_step_count=50, deadline=None)
TestDbwSequences = DbwSequences.TestCase


@given(st.lists(st.tuples(st.sampled_from(list(EventKind)), st.floats(0.0, 2.0)), max_size=30))
def test_any_sequence_ending_in_a_driver_action_is_manual(steps):
    core, t = DbwCore(LIMITS), 0.0
    for kind, dt in steps:
        t += dt
        core.handle(make_event(kind, t))
    core.handle(Event.throttle_pedal(t))
    assert core.mode is M and not core.command(t).engaged
