"""Movement manager: nothing moves unless every manager allows it (ARES §3.7).

The only process whose command reaches the drive-by-wire bridge (movement/command, a
single-publisher topic the bridge alone reads), and so the only one besides the bridge that can
command an emergency stop. Each cycle managers/movement.py turns the control manager's
(v, κ), the speed limits and the awareness level into that command:

| input              | safe value when missing or stale            |
|--------------------|---------------------------------------------|
| control/setpoint   | a controlled stop, the wheels held          |
| speed/limits       | a controlled stop                           |
| obstacle/state     | a controlled stop (with the LiDARs on)      |
| awareness/state    | a controlled stop (as level 2)              |
| mission/status     | a controlled stop (nothing moves without a mission) |
| body/state         | a controlled stop (doors and ramp unknown)  |

Doors not closed or the ramp not stowed is a limit of 0 (`body`), whatever the mission says: the
gate keeps that rule itself, so no fault of the mission manager can move the shuttle with a door
open.

Level 1 latches an emergency stop until an operator re-arms it (`movement/rearm`, which the REST
API offers to the operator role only; refused while level 1 lasts). The latch survives a restart
of this process: the bridge keeps braking and says so in its car state, and a movement manager
that starts sends nothing until it has read the bridge's state, latching again if the bridge is in
an emergency stop (an operator must still re-arm). Every latch, re-arm and
controlled stop is an event, so the black box keeps them with their causes and the operator's name.
"""

from __future__ import annotations

import math

from ares.core.config import Params, param
from ares.core.messages import (
    AwarenessState,
    BodyState,
    EventLevel,
    MissionStatus,
    MovementCommand,
    MovementStatus,
    RearmReply,
    RearmRequest,
    Setpoint,
    SpeedLimits,
)
from ares.core.node import Input, Node, Output, service
from ares.core.signed_command import CommandVerifier, load_command_key
from managers.movement import GateInputs, GateLimits, Level, MovementGate


class MovementParams(Params):
    rate_hz: float = param(
        50.0, "commands per second to the bridge (the control manager's rate: no waiting here)", unit="Hz", gt=0
    )
    command_timeout_s: float = param(0.3, "an older control manager's command counts as missing", unit="s", gt=0)
    limit_timeout_s: float = param(1.0, "an older speed limit counts as missing", unit="s", gt=0)
    obstacle_timeout_s: float = param(
        0.5, "an older obstacle verdict counts as missing (it comes at 10 Hz)", unit="s", gt=0
    )
    mission_timeout_s: float = param(
        0.5, "an older mission status counts as missing (it comes at 10 Hz)", unit="s", gt=0
    )
    body_timeout_s: float = param(0.5, "an older body state counts as missing (it comes at 10 Hz)", unit="s", gt=0)
    awareness_timeout_s: float = param(
        0.5, "an older awareness level counts as missing (it comes at 10 Hz)", unit="s", gt=0
    )
    stop_decel_mps2: float = param(1.0, "a controlled stop's deceleration", unit="m/s^2", gt=0)
    max_jerk_mps3: float = param(
        2.0,
        "how fast an acceleration or deceleration may build up (comfort: 0.9-2 m/s^3 for standing passengers)",
        unit="m/s^3",
        gt=0,
    )
    kappa_rate_factor: float = param(
        5.0,
        "the curvature may change this many times faster than the steering motor "
        "turns: a bound against a runaway command that leaves the controllers "
        "alone (the MPC's steps come at 10 Hz, this gate's at 50)",
        ge=1,
    )


class MovementManager(Node):
    """The command gate: the control manager's (v, kappa) under every limit, or a stop."""

    name = "movement_manager"
    Params = MovementParams
    setpoint = Input("control/setpoint", max_age="command_timeout_s", doc="the control manager's (v, kappa)")
    speed = Input("speed/limits", max_age="limit_timeout_s", doc="the speed manager's limit where the vehicle is")
    obstacle = Input("obstacle/state", max_age="obstacle_timeout_s", doc="the obstacle manager's limit (with LiDARs)")
    mission = Input("mission/status", max_age="mission_timeout_s", doc="the mission manager's limit")
    body = Input("body/state", max_age="body_timeout_s", doc="doors closed and ramp stowed, or a limit of 0")
    awareness = Input("awareness/state", max_age="awareness_timeout_s", doc="level 0, 1 (critical) or 2 (low)")
    car = Input("dbw/car_state", max_age="command_timeout_s", doc="at start: is the bridge in an emergency stop?")
    command = Output("movement/command", rate="rate_hz", doc="(v, kappa, emergency) to the drive-by-wire bridge")
    status = Output("movement/status", rate="rate_hz", doc="the active limit, a latched stop, why")

    def setup(self) -> None:
        p, vehicle = self.params, self.vehicle
        self.gate = MovementGate(
            GateLimits(
                max_accel_mps2=vehicle.max_accel_mps2,
                max_decel_mps2=vehicle.max_decel_mps2,
                max_jerk_mps3=p.max_jerk_mps3,
                max_kappa=vehicle.max_curvature,
                max_kappa_rate=vehicle.max_curvature_rate * p.kappa_rate_factor,
                stop_decel_mps2=p.stop_decel_mps2,
            )
        )
        self._last_step: float | None = None
        self._was_stopping = False
        self._level: Level | None = Level.NOMINAL
        # without LiDARs (simulation runs about something else) there is no grid and no obstacle manager
        self.obstacle_required = bool(self.core.lidars)
        self._synced = False  # the bridge's emergency state read (at start)
        self._started = self.clock.now()
        self.commands = CommandVerifier(load_command_key(self.core.commands), self.core.commands.max_age_s)

    @staticmethod
    def _level_of(state: AwarenessState | None) -> tuple[Level | None, str]:
        if state is None:
            return None, ""
        return Level(state.level), "; ".join(state.causes)

    @service("movement/rearm")
    def _rearm(self, request: RearmRequest) -> RearmReply:
        # who re-arms is the name signed by the vehicle's API or CLI, never the one in the request
        operator, refusal = self.commands.check("movement/rearm", request)
        if operator is None:
            self.event(
                "command_refused",
                f"movement/rearm claimed by {request.operator!r}: {refusal}",
                EventLevel.WARNING,
                service="movement/rearm",
                claimed=request.operator,
            )
            return RearmReply(t=self.clock.now(), accepted=False, reason=refusal)
        accepted, reason = self.gate.rearm(self._level)
        self.event(
            "rearm",
            f"re-arm by {operator}: {reason}",
            EventLevel.INFO if accepted else EventLevel.WARNING,
            operator=operator,
            accepted=accepted,
        )
        return RearmReply(t=self.clock.now(), accepted=accepted, reason=reason)

    def _sync_with_the_bridge(self, now: float) -> bool:
        """Whether commands may go out: not before the bridge's state is known (a restarted
        movement manager must not clear the emergency stop its predecessor latched), unless the
        bridge stays silent for a second (it is not there to brake anyway)."""
        if self._synced:
            return True
        car = self.car.fresh(now)
        if car is None and now - self._started < 1.0:
            return False
        self._synced = True
        if car is not None and car.emergency:
            self.gate.latch("emergency stop in force when the movement manager started")
            self.event(
                "emergency_stop",
                f"emergency stop: {self.gate.latch_cause}",
                EventLevel.FAULT,
                cause=self.gate.latch_cause,
            )
        return True

    def step(self, now: float) -> None:
        dt = 1.0 / self.params.rate_hz if self._last_step is None else max(now - self._last_step, 0.0)
        self._last_step = now
        if not self._sync_with_the_bridge(now):
            return
        sp: Setpoint | None = self.setpoint.fresh(now)
        speed: SpeedLimits | None = self.speed.fresh(now)
        self._level, cause = self._level_of(self.awareness.fresh(now))
        mission: MissionStatus | None = self.mission.fresh(now)
        body: BodyState | None = self.body.fresh(now)
        limits = {
            "speed": None if speed is None else speed.limit_mps,
            "mission": None if mission is None else (math.inf if mission.limit_mps is None else mission.limit_mps),
            "body": None if body is None else (math.inf if body.doors == "closed" and body.ramp == "stowed" else 0.0),
        }
        if self.obstacle_required:
            obstacle = self.obstacle.fresh(now)
            limits["obstacle"] = None if obstacle is None else obstacle.limit_mps
        was_latched = self.gate.latched
        out = self.gate.step(
            dt,
            GateInputs(
                command=None if sp is None else (sp.v, sp.kappa), limits=limits, level=self._level, level_cause=cause
            ),
        )
        if self.gate.latched and not was_latched:
            self.event(
                "emergency_stop",
                f"emergency stop: {self.gate.latch_cause}",
                EventLevel.FAULT,
                cause=self.gate.latch_cause,
            )
        if out.stopping != self._was_stopping:
            self._was_stopping = out.stopping
            if out.stopping:
                self.event("controlled_stop", out.reason, EventLevel.WARNING)
            else:
                self.event("controlled_stop", "cleared: moving on", EventLevel.INFO)
        source = "emergency" if out.emergency else ("stop" if out.stopping or sp is None else sp.source)
        self.command.put(MovementCommand(t=now, v=out.v, kappa=out.kappa, emergency=out.emergency, source=source))
        self.status.put(
            MovementStatus(
                t=now,
                level=None if self._level is None else int(self._level),
                latched=self.gate.latched,
                latch_cause=self.gate.latch_cause,
                stopping=out.stopping,
                limit_mps=out.limit_mps if math.isfinite(out.limit_mps) else None,
                limited_by=out.limited_by,
                limits={k: v for k, v in limits.items() if v is None or math.isfinite(v)},
                v=out.v,
                kappa=out.kappa,
                reason=out.reason,
            )
        )
