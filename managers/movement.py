"""The movement gate: the last word on every command before the drive-by-wire bridge (ARES §3.7).

Nothing moves unless every manager allows it. Each cycle the gate takes the control manager's
(v, κ), the speed limits of the managers that set one (speed, obstacle, mission) and the awareness
level, and gives the one command the bridge accepts:

1. **Level 1** (critical) latches an emergency stop: speed 0 at once, the bridge brakes fully. It
   stays latched, whatever happens next, until a person re-arms it (`rearm`), and a re-arm is
   refused while level 1 lasts.
2. **Level 2** (low), or an input gone missing or stale (its safe value), is a controlled stop: a
   limit falling from the speed now at `stop_decel_mps2` to 0, held while the cause lasts; when
   it clears, the shuttle goes on by itself.
3. The **lowest limit** applies at once: the command is never above an active limit.
4. Below the limits, the speed follows the control manager's within the vehicle's acceleration,
   deceleration and jerk, and the curvature within the steering motor's rate (a final limit:
   Autoware's vehicle command gate).

The order of trust is fixed: emergency stop, then controlled stop, then limits, then comfort.
Plain code without a bus, so that every state × event can be tested (tests/test_movement.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import IntEnum


class Level(IntEnum):
    """Awareness levels (ARES §3.7): 1 critical, 2 low; 0 nominal."""

    NOMINAL = 0
    CRITICAL = 1
    LOW = 2


@dataclass(frozen=True)
class GateLimits:
    """The vehicle's figures the gate enforces."""

    max_accel_mps2: float
    max_decel_mps2: float  # the largest deceleration a command may ask for (not the emergency brake)
    max_jerk_mps3: float
    max_kappa: float  # 1/m: tan(largest wheel angle) / wheelbase
    max_kappa_rate: float  # 1/m/s: the steering motor's rate
    stop_decel_mps2: float  # a controlled stop


@dataclass(frozen=True)
class GateInputs:
    """One cycle's inputs; None is an input missing or stale."""

    command: tuple[float, float] | None  # (v, κ) from the control manager
    limits: dict[str, float | None] = field(default_factory=dict)  # manager -> its speed limit, m/s
    level: Level | None = Level.NOMINAL  # the awareness level
    level_cause: str = ""


@dataclass(frozen=True)
class GateOutput:
    v: float
    kappa: float
    emergency: bool  # the bridge brakes fully
    stopping: bool  # a controlled stop is under way (level 2, or something missing)
    limit_mps: float  # the lowest active limit (inf: none)
    limited_by: str  # which: a manager's name, "stop", "emergency", or "" (none active)
    reason: str


class MovementGate:
    def __init__(self, limits: GateLimits):
        self.limits = limits
        self.latched = False
        self.latch_cause = ""
        self.v = 0.0  # the last command given
        self.accel = 0.0  # ... and its rate of change
        self.kappa = 0.0
        self._stop_limit: float | None = None  # the controlled stop's falling limit, while one runs

    def latch(self, cause: str) -> None:
        """An emergency stop from outside the levels (one already in force at start-up)."""
        self.latched, self.latch_cause = True, cause

    def rearm(self, level: Level | None) -> tuple[bool, str]:
        """A person's re-arm: clears a latched emergency stop unless its cause is still there."""
        if not self.latched:
            return False, "nothing to re-arm: no emergency stop is latched"
        if level == Level.CRITICAL:
            return False, f"refused: level 1 persists ({self.latch_cause})"
        cause, self.latched, self.latch_cause = self.latch_cause, False, ""
        return True, f"re-armed after: {cause}"

    def step(self, dt: float, inputs: GateInputs) -> GateOutput:
        lim = self.limits
        if inputs.level == Level.CRITICAL and not self.latched:
            self.latch(inputs.level_cause or "level 1")
        if self.latched:
            self.v, self.accel, self._stop_limit = 0.0, 0.0, None
            return GateOutput(
                0.0,
                self.kappa,
                True,
                False,
                0.0,
                "emergency",
                f"emergency stop latched ({self.latch_cause}): waiting for a re-arm",
            )

        # what calls for a controlled stop: level 2 and every missing input (their safe value)
        causes = []
        if inputs.level is None:
            causes.append("awareness level missing")
        elif inputs.level == Level.LOW:
            causes.append(f"level 2: {inputs.level_cause}" if inputs.level_cause else "level 2")
        if inputs.command is None:
            causes.append("no command from the control manager")
        causes += [f"{name} limit missing" for name, value in inputs.limits.items() if value is None]
        if causes:
            start = self.v if self._stop_limit is None else self._stop_limit
            self._stop_limit = max(0.0, start - lim.stop_decel_mps2 * dt)
        else:
            self._stop_limit = None

        active = {name: max(0.0, value) for name, value in inputs.limits.items() if value is not None}
        if self._stop_limit is not None:
            active["stop"] = self._stop_limit
        limited_by, limit = min(active.items(), key=lambda item: item[1], default=("", math.inf))

        v_wanted, kappa_wanted = inputs.command if inputs.command is not None else (0.0, self.kappa)
        v_wanted = min(max(v_wanted, 0.0), limit)
        # comfort below the limits: an acceleration (or deceleration) builds up within the jerk and
        # is let go at once; the speed never goes past what is wanted
        accel_wanted = (v_wanted - self.v) / dt if dt > 0 else 0.0
        lowest = max(-lim.max_decel_mps2, min(self.accel, 0.0) - lim.max_jerk_mps3 * dt)
        highest = min(lim.max_accel_mps2, max(self.accel, 0.0) + lim.max_jerk_mps3 * dt)
        v = max(0.0, self.v + min(max(accel_wanted, lowest), highest) * dt)
        v = min(v, limit)  # a limit applies at once
        self.accel = (v - self.v) / dt if dt > 0 else 0.0
        self.v = v
        kappa_wanted = min(max(kappa_wanted, -lim.max_kappa), lim.max_kappa)
        step = lim.max_kappa_rate * dt
        self.kappa = min(max(kappa_wanted, self.kappa - step), self.kappa + step)

        if causes:
            reason = "stopping: " + "; ".join(causes)
        elif limited_by and v_wanted >= limit:
            reason = f"limited by {limited_by} ({limit:.2f} m/s)"
        else:
            reason = "following the control manager"
        return GateOutput(v, self.kappa, False, bool(causes), limit, limited_by if math.isfinite(limit) else "", reason)
