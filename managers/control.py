"""Which controller reaches the wheels (ARES paper §3.6, §4: the control manager).

Every controller computes all the time; this decides whose candidate is forwarded, in a fixed
order of trust:

  1. ODOMETRY (the MPC, or pure pursuit if so configured) where the path manager forces it: at
     intersections and road openings there is no road to follow, whatever the odometry score;
  2. ODOMETRY while the odometry score deserves it;
  3. RRC (road reactive control) when the score does not, but road detection is confident;
  4. STOP: nothing deserves trust, a controlled stop is asked for;
  5. CREEP: after standing `creep_after_s` in a stop with nothing trusted, the odometry controller
     at `creep_speed_mps` for at most `creep_distance_m`, while the pose is good enough for the
     road it is on; then a stop again. The odometry score is nearly binary: it says whether RTK
     corrections come, not how far off the pose is. Under the trees, having lost the corrections,
     the fused pose stays good to centimetres for a minute or two while its σ grows past 0.25 m
     (~1e-3 m²/s standing, ~3.4e-3 driving: docs/control.md, "The creep"), while road detection
     on grass verges can fail for good from one standing spot: it sees the same scene every
     frame. A few metres at walking pace give it another view; the obstacle manager
     and the movement gate still stand between the creep and anything in the way.
     *Good enough* is, first, a pose that a GNSS fix (RTK or not) has anchored within
     `creep_fix_age_s`: a dead-reckoned pose can be off by far more than its σ says (an
     unmodelled gyro bias and wheel scale put it 3.6 m off in `dead_reckoning_drift` where σ says
     0.7 m), so it never creeps. Then, the road's room: (road width - vehicle width) / 2 - |xte|
     lies between the shuttle's side and the road's edge, the width the narrowest over the path
     ahead (a creep must not carry a wide road's bound into a narrow lane); less
     `creep_clearance_m`, that room must hold `creep_sigmas_enter` of the pose's standard deviation (the
     localization's own, sqrt of eq. 6's cov) to begin a creep and `creep_sigmas_exit` to go on
     with one. On the tour's 6 m roads that is σ within 0.57 / 0.68 m, in its 3.2 m lane 0.10 /
     0.12 m. Past it (a GNSS outage, a narrow road) the stop is final until the road or the pose
     is trusted again.

A mode is *acceptable* while its candidate is fresh (and, for the MPC, not asking for a hand-over)
and its trust holds. Trust has hysteresis: a mode is entered at `enter` and kept down to `exit`,
so a score hovering at one threshold does not toggle. The mode in charge keeps charge for at least
`min_dwell_s`, unless it stops being acceptable: a better mode waits out the dwell, a failing one
is left at once (a stale candidate is never forwarded). ODOMETRY forced by the path manager
counts as a failing RRC: the road's model ends at the crossing.

A switch between candidates that disagree is a ramp, not a jump (bumpless transfer): from the
curvature forwarded so far to the new candidate's, no faster than the steering can follow
(`max_kappa_rate`, from the steering motor's rate). Once caught up, the candidate passes through
unchanged: the controller in charge already commands no faster than the steering turns (the
MPC's model has the rate), and a ramp on top would only delay it (at 25 km/h, by enough to make
the MPC weave). In STOP the speed ramps down at `stop_decel_mps2`, and the curvature goes, at the
steering's rate, to the odometry controller's while creeping is on and the pose's σ is within
the creep's exit bound, the pose dead-reckoned for at most `stop_steer_fix_age_s` (a pose good
enough to creep by is good enough to steer a stop by, and so is one a fix anchored half a minute
ago, for the few metres of a stop: the RRC's remembered road can be the wrong one), else to the
RRC's while it has a candidate (the road seen, however faintly, or remembered for a few metres
after it was lost: `stop_only`), else it is held. A held curvature rolls the shuttle off a
bend's line (0.5 m over the 6 m of a stop from 2.5 m/s, measured on grass).
A `stop_only` candidate never drives.

`pinned` (for comparisons, `ares run --controller`) takes the order of trust away: the pinned
mode drives whenever its candidate is fresh, whatever the score or the road, and STOP otherwise
(holding the curvature: a comparison shows the pinned controller alone).

Each decision carries a short `cause` beside its sentence (score_low, road_ok, forced, ...): the
lap figures count switches by cause, the sentence is for people.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum


class Mode(str, Enum):
    ODOMETRY = "odometry"
    RRC = "rrc"
    STOP = "stop"
    CREEP = "creep"


@dataclass(frozen=True)
class SelectionParams:
    score_enter: float  # odometry score to hand control to odometry
    score_exit: float  # ... and below which odometry loses it
    road_enter: float  # road-detection confidence to hand control to the RRC
    road_exit: float
    min_dwell_s: float  # least time in charge before a better mode may take over
    max_kappa_rate: float  # 1/m per s: the steering's speed, as curvature
    stop_decel_mps2: float  # a controlled stop's deceleration
    pinned: Mode | None = None  # only this mode drives (comparisons); STOP when its candidate is missing
    creep_after_s: float = 2.0  # standing this long in a stop before creeping
    creep_speed_mps: float = 0.8
    creep_distance_m: float = 0.0  # per creep, before standing again (0: never creep)
    creep_fix_age_s: float = 2.0  # a creep drives by a pose that a GNSS fix anchored this recently
    stop_steer_fix_age_s: float = 30.0  # ... and a stop steers by one anchored this recently
    creep_clearance_m: float = 0.3  # kept between the shuttle's side and the road's edge in a creep
    creep_sigmas_enter: float = 3.0  # the pose's σ the road's room must hold to begin a creep ...
    creep_sigmas_exit: float = 2.5  # ... and to go on with one

    def __post_init__(self):
        if not (0 <= self.score_exit <= self.score_enter and 0 <= self.road_exit <= self.road_enter):
            raise ValueError("each exit threshold must lie at or below its enter threshold")
        if not 0 <= self.creep_fix_age_s <= self.stop_steer_fix_age_s:
            raise ValueError("a stop steers by any pose a creep may drive by: creep_fix_age_s <= stop_steer_fix_age_s")
        if not 0 < self.creep_sigmas_exit <= self.creep_sigmas_enter:
            raise ValueError("creep_sigmas_exit must be positive and lie at or below creep_sigmas_enter")

    def creep_std_limit(self, road_room_m: float, holding: bool) -> float:
        """The largest pose σ to creep by with `road_room_m` beside the shuttle (holding: to go on)."""
        room = road_room_m - self.creep_clearance_m
        return room / (self.creep_sigmas_exit if holding else self.creep_sigmas_enter)


@dataclass(frozen=True)
class Candidate:
    v: float
    kappa: float
    stop_only: bool = False  # only to steer a controlled stop by


@dataclass(frozen=True)
class Inputs:
    """One cycle's view; None where the input is missing or stale."""

    odometry_score: float | None
    road_confidence: float | None
    force_odometry: bool
    odometry: Candidate | None  # the odometry controller's candidate (None: stale, or it hands over)
    rrc: Candidate | None
    pose_std_m: float | None = None  # the fused pose's standard deviation (None: no fresh pose)
    road_room_m: float | None = None  # (road width ahead - vehicle width) / 2 - |xte| (None: unknown)
    fix_age_s: float | None = None  # since a GNSS fix was last fused into the pose (None: none, or unknown)


@dataclass(frozen=True)
class Decision:
    mode: Mode
    v: float
    kappa: float
    switched: bool
    reason: str
    cause: str  # short code of the reason (a switch's: why the mode in charge failed, or
    # why a better one took over)


class ControlSelector:
    def __init__(self, params: SelectionParams, start: Mode = Mode.STOP):
        self.p = params
        self.mode = start
        self.since: float | None = None  # when the mode in charge took it
        self.v = 0.0
        self.kappa = 0.0
        self.catching_up = False  # after a switch, until the curvature has caught up
        self.last_t: float | None = None
        self.standing_since: float | None = None  # when a stop came to a standstill
        self.crept_m = 0.0  # in the creep in charge

    # ---- trust ----------------------------------------------------------------------------------
    def _odometry_trusted(self, inputs: Inputs, holding: bool) -> bool:
        score = inputs.odometry_score
        return score is not None and score >= (self.p.score_exit if holding else self.p.score_enter)

    def _road_trusted(self, inputs: Inputs, holding: bool) -> bool:
        conf = inputs.road_confidence
        return conf is not None and conf >= (self.p.road_exit if holding else self.p.road_enter)

    def acceptable(self, mode: Mode, inputs: Inputs, holding: bool) -> tuple[bool, str, str]:
        """Whether `mode` may drive (holding: it is in charge now, so the exit thresholds apply), the
        cause's short code and the sentence."""
        candidate = {Mode.ODOMETRY: inputs.odometry, Mode.RRC: inputs.rrc}.get(mode)
        stop_only = candidate is not None and candidate.stop_only
        if stop_only:
            candidate = None
        if self.p.pinned is not None and mode is not Mode.STOP:
            if mode is not self.p.pinned:
                return False, "pinned", f"pinned to {self.p.pinned.value}"
            if stop_only:
                return False, "stop_only", f"the pinned {mode.value} controller's candidate only steers a stop"
            if candidate is None:
                return False, "no_candidate", f"the pinned {mode.value} controller has no fresh candidate"
            return True, "pinned", f"pinned to {mode.value}"
        if mode is Mode.ODOMETRY:
            if candidate is None:
                return False, "no_candidate", "the odometry controller has no fresh candidate"
            if inputs.force_odometry:
                return True, "forced", "the path manager forces odometry control (intersection or road opening)"
            if self._odometry_trusted(inputs, holding):
                return True, "score_ok", f"odometry score {inputs.odometry_score:.2f}"
            if inputs.odometry_score is None:
                return False, "no_score", "no odometry score"
            return False, "score_low", f"odometry score {inputs.odometry_score:.2f} too low"
        if mode is Mode.RRC:
            if inputs.force_odometry and inputs.odometry is not None:
                return False, "forced", "the path manager forces odometry control"
            if stop_only:
                return False, "stop_only", "the RRC's candidate only steers a stop (its road lost or in doubt)"
            if candidate is None:
                return False, "no_candidate", "the RRC has no fresh candidate to drive by"
            if self._road_trusted(inputs, holding):
                return True, "road_ok", f"road confidence {inputs.road_confidence:.2f}"
            if inputs.road_confidence is None:
                return False, "no_road", "no road detection"
            return False, "road_low", f"road confidence {inputs.road_confidence:.2f} too low"
        if mode is Mode.CREEP:
            return self._creep_acceptable(inputs, holding)
        return True, "stop", "in a controlled stop"

    def _creep_refusal(
        self, inputs: Inputs, holding: bool, max_fix_age_s: float | None = None
    ) -> tuple[str, str] | None:
        """Why the odometry controller may not creep (or steer a stop) by the pose now, as a cause
        and a sentence; None when it may (holding: the exit threshold applies; max_fix_age_s: the
        longest dead reckoning allowed, by default the creep's)."""
        p = self.p
        max_fix_age_s = p.creep_fix_age_s if max_fix_age_s is None else max_fix_age_s
        if p.creep_distance_m <= 0:
            return "creep_off", "creeping is off"
        if inputs.odometry is None:
            return "no_candidate", "no odometry candidate to creep by"
        std = inputs.pose_std_m
        if std is None:
            return "no_pose", "no fresh pose to creep by"
        if inputs.fix_age_s is None or inputs.fix_age_s > max_fix_age_s:
            since = "no GNSS fix known" if inputs.fix_age_s is None else f"no GNSS fix for {inputs.fix_age_s:.1f} s"
            return "dead_reckoning", f"the pose is dead-reckoned ({since})"
        if inputs.road_room_m is None:
            return "no_road_width", "the road's width here is unknown"
        limit = p.creep_std_limit(inputs.road_room_m, holding)
        if limit <= 0:
            return "road_narrow", "the road leaves no room to creep by"
        if std > limit:
            return "pose_std_high", f"the pose's σ {std:.2f} m is too large to creep by here (at most {limit:.2f} m)"
        return None

    def _creep_acceptable(self, inputs: Inputs, holding: bool) -> tuple[bool, str, str]:
        p = self.p
        refusal = self._creep_refusal(inputs, holding)
        if refusal is not None:
            return False, *refusal
        if holding:
            if self.crept_m >= p.creep_distance_m:
                return False, "crept", f"crept {p.creep_distance_m:g} m: standing again"
        elif self.standing_since is None or self.last_t is None or self.last_t - self.standing_since < p.creep_after_s:
            return False, "not_standing", f"a creep waits for {p.creep_after_s:g} s of standing still"
        return (
            True,
            "creep",
            f"creeping on the odometry at {p.creep_speed_mps:g} m/s (pose σ {inputs.pose_std_m:.2f} m)",
        )

    def wanted(self, inputs: Inputs) -> tuple[Mode, str, str]:
        """The most trusted acceptable mode, in the fixed order, with its cause and sentence."""
        reasons = []
        for mode in (Mode.ODOMETRY, Mode.RRC, Mode.CREEP):
            ok, cause, why = self.acceptable(mode, inputs, holding=mode is self.mode)
            if ok:
                return mode, cause, why
            reasons.append(why if mode is not Mode.CREEP else f"no creep: {why}")
        return Mode.STOP, "nothing_trusted", "nothing deserves trust: " + "; ".join(reasons)

    # ---- each cycle -----------------------------------------------------------------------------
    def step(self, t: float, inputs: Inputs) -> Decision:
        first = self.last_t is None
        dt = 0.0 if first else max(0.0, t - self.last_t)
        self.last_t = t
        if self.since is None:
            self.since = t
        want, cause, reason = self.wanted(inputs)
        switched = False
        if want is not self.mode:
            current_ok, current_cause, current_why = self.acceptable(self.mode, inputs, holding=True)
            if not current_ok or t - self.since >= self.p.min_dwell_s:
                if not current_ok:
                    reason, cause = f"{current_why}; {reason}", current_cause  # why it was left
                self.mode, self.since, switched = want, t, True
                self.crept_m = 0.0
            else:
                cause = current_cause
                reason = f"{current_why}; {want.value} is wanted once {self.p.min_dwell_s:g} s in charge have passed"
        target = {Mode.ODOMETRY: inputs.odometry, Mode.RRC: inputs.rrc, Mode.CREEP: inputs.odometry}.get(self.mode)
        if target is None:  # STOP: slow down, steer along the path or the road, or hold
            self.v = max(0.0, self.v - self.p.stop_decel_mps2 * dt)
            steer_by = self._stop_steering(inputs)
            kappa_target = self.kappa if steer_by is None else steer_by.kappa
            self.catching_up = True  # a stop's curvature always moves at the steering's rate
        elif self.mode is Mode.CREEP:
            self.crept_m += self.v * dt  # as commanded: a creep held back by the gate ends no later
            self.v, kappa_target = min(target.v, self.p.creep_speed_mps), target.kappa
        else:
            self.v, kappa_target = target.v, target.kappa
        if self.mode is Mode.STOP and self.v == 0.0:
            self.standing_since = t if self.standing_since is None else self.standing_since
        else:
            self.standing_since = None
        if switched:
            self.catching_up = True
        if first or not self.catching_up:
            self.kappa = kappa_target
        elif abs(kappa_target - self.kappa) <= self.p.max_kappa_rate * dt:
            self.kappa, self.catching_up = kappa_target, False
        else:
            self.kappa += _clip(kappa_target - self.kappa, self.p.max_kappa_rate * dt)
        return Decision(self.mode, self.v, self.kappa, switched, reason, cause)

    def _stop_steering(self, inputs: Inputs) -> Candidate | None:
        """Whose curvature a controlled stop follows: the odometry controller's while creeping is on
        and the pose is good enough to creep by, or dead-reckoned for no longer than
        `stop_steer_fix_age_s` (a pose good to centimetres follows the path; the RRC's remembered
        road can be the wrong one, as it was before a crossing in a soak during a GNSS outage,
        where it steered a stop 0.55 m aside), else the RRC's road, seen or remembered; none when
        pinned."""
        if self.p.pinned is not None:
            return None
        refusal = self._creep_refusal(inputs, holding=True, max_fix_age_s=self.p.stop_steer_fix_age_s)
        return inputs.odometry if refusal is None else inputs.rrc


def _clip(value: float, limit: float) -> float:
    return max(-limit, min(limit, value))
