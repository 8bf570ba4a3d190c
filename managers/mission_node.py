"""Mission manager: the passenger tour as an action over Zenoh (ARES §3.3).

| action part | how                                                                             |
|-------------|---------------------------------------------------------------------------------|
| goal        | service `mission/goal`: POI names in order, every POI of the route ahead, or a   |
|             | drive (round without stopping); accepted with a goal id, or refused with why;    |
|             | a new goal pre-empts the one that runs                                           |
| feedback    | `mission/status`: state, POI, action, distance, expected arrival, limit          |
| result      | `mission/status.result` and a `mission_result` event when a goal ends            |
| control     | services `mission/pause`, `mission/resume`, `mission/cancel`                     |
| body        | service `mission/body`: an operator's doors and ramp, standing, no POI running   |

Each step the state machine (managers/mission.py) gets the distance to the POI's stop
point along the route, the speed and the body's sensors, and gives the body's demands
(`body/command`) and the mission's speed limit, which the movement gate applies. The limit falls
no faster than `pause_decel_mps2` from the speed the shuttle has (a pause is a stop, not a brake).

A restarted mission manager goes on where its predecessor was: the mission is written to
`mission_manager.json` beside the run's configuration at every change, and read back on a restart.
At a first start it sets itself the goal `autostart` names (the tour, a drive, or none); so does a
restart that finds nothing kept (its predecessor died before it set that goal).
"""

from __future__ import annotations

import json
import math
from typing import Literal

from ares.core.config import param
from ares.core.messages import (
    BodyCommand,
    BodyRequest,
    BodyState,
    CarState,
    EventLevel,
    MissionGoal,
    MissionReply,
    MissionRequest,
    MissionStatus,
    PathMatch,
    PoiProgress,
    SpeedLimits,
)
from ares.core.node import Input, Node, Output, service
from ares.core.route import load_route
from ares.core.signed_command import CommandVerifier, load_command_key
from managers.intersection_stop import IntersectionStops, LineState
from managers.mission import Body, Mission, MissionParams, MissionState, PoiGoal, body_request_refusal, ready_to_move


class MissionManagerParams(MissionParams):
    rate_hz: float = param(10.0, "steps per second", unit="Hz", gt=0)
    autostart: Literal["tour", "drive", "none"] = param(
        "tour",
        "the goal set at a first start: tour (every POI of the route), drive (round without stopping) or "
        "none (wait for `ares mission start`)",
    )
    pause_decel_mps2: float = param(
        3.0,
        "the mission's limit falls no faster than this from the speed the shuttle "
        "has: a pause stands the shuttle within 2 s of the operator's click (from "
        "3.5 m/s: 1.2 s braking after ~0.6 s for the request to reach the wheels "
        "and the brake to bite; docs/pages.md); firm, at the bridge's brake-assist "
        "limit",
        unit="m/s^2",
        gt=0,
    )
    path_timeout_s: float = param(
        1.0, "an older path match counts as missing (where the POIs are is unknown)", unit="s", gt=0
    )
    body_timeout_s: float = param(
        1.0, "an older body state counts as missing (doors and ramp unknown: limit 0)", unit="s", gt=0
    )
    save_period_s: float = param(
        2.0,
        "the mission (and where along the route the shuttle is) is kept for a restart "
        "at every change and at least this often",
        unit="s",
        gt=0,
    )
    eta_min_speed_mps: float = param(1.0, "the expected arrival counts on at least this speed", unit="m/s", gt=0)


class MissionManager(Node):
    """Goals of points of interest, each POI's actions, the doors and ramp, and the mission's limit."""

    name = "mission_manager"
    Params = MissionManagerParams
    match = Input("path/match", max_age="path_timeout_s", doc="where the shuttle is on its route")
    car = Input("dbw/car_state", max_age="path_timeout_s", doc="the measured speed")
    speed = Input("speed/limits", max_age="path_timeout_s", doc="the speed limit: for the expected arrival")
    body = Input("body/state", max_age="body_timeout_s", doc="doors, ramp and the entrance")
    status = Output("mission/status", rate="rate_hz", doc="feedback; the mission's speed limit for the movement gate")
    body_command = Output("body/command", doc="doors, ramp, media: sent while an action asks for them")

    def setup(self) -> None:
        self.route = load_route(self.core)
        self.mission = Mission(params=self.params)
        p = self.params
        self.stop_lines = IntersectionStops(self.route, p.full_stop_s, p.reach_m, p.approach_decel_mps2)
        self.goal_id = 0
        self.kind = "none"
        self.targets: list[float] = []  # each POI's stop point as progress along the route (laps unwrapped)
        self.repeat = False  # a tour of a closed route goes round again after its last POI
        self._limit = 0.0
        self._last_step: float | None = None
        self._ended_reported = True
        # the mission's own odometer along the route (laps unwrapped): the path manager's lap count
        # starts again when it restarts, which would move every POI a lap away
        self.progress: float | None = None
        self._last_s: float | None = None
        self._saved_at = -math.inf
        self.state_path = self.kept_state_path()
        self.commands = CommandVerifier(load_command_key(self.core.commands), self.core.commands.max_age_s)
        # a restart before the first start set its goal finds nothing kept: that goal is still to set
        never_set = self.state_path is not None and not self.state_path.exists()
        if self.restarted and self._restore():
            self.event(
                "mission",
                f"restarted: going on with goal {self.goal_id} ({self.mission.state.value} "
                f"at {self.mission.current_name()})",
            )
        self._autostart_pending = self.params.autostart != "none" and (not self.restarted or never_set)

    # ---- where things are ------------------------------------------------------------------------
    def _follow(self, match: PathMatch | None) -> None:
        """Move the odometer on to the match (the short way round a closed route)."""
        if match is None:
            return
        if not self.route.closed or self.progress is None:
            self.progress = match.s
        elif self._last_s is not None:
            self.progress += self.route.step_between(self._last_s, match.s)
        self._last_s = match.s

    def _progress(self, match: PathMatch) -> float:
        return self.progress if self.progress is not None else match.s

    def _body(self, now: float) -> Body | None:
        b: BodyState | None = self.body.fresh(now)
        return None if b is None else Body(doors=b.doors, ramp=b.ramp, entrance_clear=b.entrance_clear)

    def _plan(self, names: list[str] | None, progress: float) -> tuple[list[PoiGoal], list[float]] | str:
        """The goal's POIs and where each stop point lies ahead, or why not."""
        known = {p.name: p for p in self.route.pois}
        if names is None:
            ordered = (
                sorted(self.route.pois, key=lambda p: (p.s - progress) % self.route.length)
                if self.route.closed
                else [p for p in self.route.pois if p.s >= progress - self.params.reach_m]
            )
            if not ordered:
                return f"refused: '{self.route.name}' has no POI ahead"
        else:
            unknown = [n for n in names if n not in known]
            if unknown:
                return f"refused: unknown POIs {unknown} (on '{self.route.name}': {', '.join(known) or 'none'})"
            ordered = [known[n] for n in names]
        pois, targets, last = [], [], progress - self.params.reach_m
        for poi in ordered:
            if self.route.closed:
                target = poi.s + math.ceil((last - poi.s) / self.route.length) * self.route.length
                if target <= last and targets:
                    target += self.route.length
            else:
                target = poi.s
                if target < last:
                    return f"refused: {poi.name} is behind the shuttle on an open route"
            pois.append(PoiGoal(poi.name, target, tuple(poi.actions)))
            targets.append(target)
            last = target
        return pois, targets

    # ---- the action's services ------------------------------------------------------------------
    def _signed(self, service: str, request: MissionGoal | MissionRequest | BodyRequest) -> str | MissionReply:
        """Who gave the command, as the vehicle's API or CLI signed it (never the request's own
        `operator`), or the refusal of a command unsigned, forged, stale or replayed."""
        operator, refusal = self.commands.check(service, request)
        if operator is not None:
            return operator
        self.event(
            "command_refused",
            f"{service} claimed by {request.operator!r}: {refusal}",
            EventLevel.WARNING,
            service=service,
            claimed=request.operator,
        )
        return self._reply(False, refusal)

    @service("mission/goal")
    def _goal(self, request: MissionGoal) -> MissionReply:
        operator = self._signed("mission/goal", request)
        if isinstance(operator, MissionReply):
            return operator
        return self._set_goal(request.pois, request.drive, operator, repeat=request.repeat)

    def _set_goal(self, names: list[str] | None, drive: bool, operator: str, repeat: bool = False) -> MissionReply:
        now = self.clock.now()
        match, body = self.match.fresh(now), self._body(now)
        if match is None or body is None:
            return self._reply(False, "refused: where the shuttle is or its doors' state is not known yet")
        if drive:
            pois, targets = [], []
        else:
            planned = self._plan(names, self._progress(match))
            if isinstance(planned, str):
                return self._reply(False, planned, operator)
            pois, targets = planned
        previous = self.mission.state
        accepted, reason = self.mission.goal(pois, body, drive=drive)
        if accepted:
            if previous in (MissionState.DRIVING, MissionState.AT_POI, MissionState.PAUSED):
                self._report_end(f"goal {self.goal_id} pre-empted by goal {self.goal_id + 1}")
            self.goal_id += 1
            self.kind = "drive" if drive else "tour"
            self.targets = targets
            self.repeat = repeat and self.route.closed and not drive
            self._ended_reported = False
            self._save()
        return self._reply(accepted, reason, operator)

    @service("mission/pause")
    def _pause(self, request: MissionRequest) -> MissionReply:
        operator = self._signed("mission/pause", request)
        if isinstance(operator, MissionReply):
            return operator
        return self._reply(*self.mission.pause(), operator)

    @service("mission/resume")
    def _resume(self, request: MissionRequest) -> MissionReply:
        operator = self._signed("mission/resume", request)
        if isinstance(operator, MissionReply):
            return operator
        return self._reply(*self.mission.resume(self._body(self.clock.now())), operator)

    @service("mission/cancel")
    def _cancel(self, request: MissionRequest) -> MissionReply:
        operator = self._signed("mission/cancel", request)
        if isinstance(operator, MissionReply):
            return operator
        body = self._body(self.clock.now())
        if body is None:
            return self._reply(False, "refused: the doors' state is not known", operator)
        return self._reply(*self.mission.cancel(body), operator)

    @service("mission/body")
    def _body_request(self, request: BodyRequest) -> MissionReply:
        """The operator's doors and ramp (managers/mission.body_request_refusal decides)."""
        operator = self._signed("mission/body", request)
        if isinstance(operator, MissionReply):
            return operator
        now = self.clock.now()
        body, car = self._body(now), self.car.fresh(now)
        if body is None or car is None:
            refusal = "refused: the body's or the speed's state is not known"
        else:
            m = self.mission
            # paused amid a POI's actions counts as at the POI: its actions own the doors and the ramp
            state = (
                MissionState.AT_POI
                if m.state is MissionState.PAUSED and m.paused_from is MissionState.AT_POI
                else m.state
            )
            refusal = body_request_refusal(
                state, abs(car.speed_mps) <= self.params.stopped_mps, body, request.doors, request.ramp
            )
        if refusal is not None:
            return self._reply(False, refusal, operator)
        self.body_command.put(BodyCommand(t=now, doors=request.doors, ramp=request.ramp))
        asked = " and ".join(f"{what} {how}" for what, how in (("doors", request.doors), ("ramp", request.ramp)) if how)
        return self._reply(True, f"{asked}: asked of the body", operator)

    def _reply(self, accepted: bool, reason: str, operator: str = "") -> MissionReply:
        if operator:
            self.event(
                "mission_command",
                f"{operator}: {reason}",
                EventLevel.INFO if accepted else EventLevel.WARNING,
                operator=operator,
                accepted=accepted,
                goal_id=self.goal_id,
            )
        if accepted:
            self._save()
        return MissionReply(
            t=self.clock.now(), accepted=accepted, reason=reason, goal_id=self.goal_id, state=self.mission.state.value
        )

    # ---- each step ------------------------------------------------------------------------------
    def step(self, now: float) -> None:
        dt = 0.0 if self._last_step is None else max(now - self._last_step, 0.0)
        self._last_step = now
        match: PathMatch | None = self.match.fresh(now)
        self._follow(match)
        car: CarState | None = self.car.fresh(now)
        body = self._body(now)
        if self._autostart_pending and match is not None and body is not None:
            self._autostart_pending = False
            # the tour: every POI, round and round (a route without POIs is driven without stopping)
            drive = self.params.autostart == "drive" or not self.route.pois
            reply = self._set_goal(None, drive, operator="", repeat=True)
            self.event(
                "mission",
                f"autostart ({self.params.autostart}): {reply.reason}",
                EventLevel.INFO if reply.accepted else EventLevel.WARNING,
            )
        m = self.mission
        distance = None
        if match is not None and m.index < len(self.targets):
            distance = self.targets[m.index] - self._progress(match)
        speed = car.speed_mps if car is not None else None
        before = (m.state, m.index, m.action, len(m.done))
        if body is not None and speed is not None:
            asked = m.step(now, distance, speed, body)
            if asked.doors or asked.ramp or asked.media:
                self.body_command.put(BodyCommand(t=now, doors=asked.doors, ramp=asked.ramp, media=asked.media))
        for poi, action in m.done[before[3] :]:
            self.event("poi_action", f"{poi}: {action}", poi=poi, action=action, goal_id=self.goal_id)
        if (m.state, m.index, m.action, len(m.done)) != before or now - self._saved_at >= self.params.save_period_s:
            self._save()
            self._saved_at = now
        if m.state is MissionState.SUCCEEDED and self.repeat and match is not None and body is not None:
            self._next_round(match, body)
        if m.state in (MissionState.SUCCEEDED, MissionState.CANCELED) and not self._ended_reported:
            self._report_end(m.result)
        # the limit: nothing moves without the body's state or where the POI is; it falls gently
        wanted = 0.0 if body is None else m.limit_mps(distance, body)
        if m.state is MissionState.DRIVING:  # FULL_STOP at the marked intersections, through the same gate
            wanted = min(wanted, self._stop_lines(now, match, speed))
        if wanted >= self._limit:
            self._limit = wanted
        else:
            from_speed = min(self._limit, speed if speed is not None else 0.0)
            self._limit = max(wanted, from_speed - self.params.pause_decel_mps2 * dt)
        self._publish(now, distance, body, speed)

    def _stop_lines(self, now: float, match: PathMatch | None, speed: float | None) -> float:
        standing = speed is not None and abs(speed) <= self.params.stopped_mps
        limit, changes = self.stop_lines.step(now, None if match is None else match.s, standing)
        for change in changes:
            if change.state is LineState.STANDING:
                self.event(
                    "full_stop",
                    f"FULL_STOP at the intersection's line (s={change.line:.0f} m): standing "
                    f"{self.params.full_stop_s:g} s before crossing",
                    line_s=change.line,
                )
            elif change.state is LineState.CLEARED:
                self.event(
                    "full_stop_cleared", f"the intersection at s={change.line:.0f} m: crossing", line_s=change.line
                )
        return limit

    def _next_round(self, match: PathMatch, body: Body) -> None:
        """A repeating tour: the route's POIs again, from the one after the last served."""
        planned = self._plan(None, max(self._progress(match), self.targets[-1] + self.params.reach_m))
        if isinstance(planned, str):
            return
        accepted, reason = self.mission.goal(planned[0], body)
        if accepted:
            self.targets = planned[1]
            self.event("mission", f"goal {self.goal_id}: round again: {reason}", goal_id=self.goal_id)
            self._save()

    def _report_end(self, result: str) -> None:
        self._ended_reported = True
        self.event(
            "mission_result",
            f"goal {self.goal_id}: {self.mission.state.value}: {result}",
            goal_id=self.goal_id,
            state=self.mission.state.value,
            result=result,
        )
        self._save()

    def _publish(self, now: float, distance: float | None, body: Body | None, speed: float | None) -> None:
        m = self.mission
        eta = None
        if distance is not None and m.state is MissionState.DRIVING and not m.drive:
            limits: SpeedLimits | None = self.speed.fresh(now)
            cruise = max(limits.limit_mps if limits is not None else 0.0, speed or 0.0, self.params.eta_min_speed_mps)
            eta = now + max(distance, 0.0) / cruise
        progress = [PoiProgress(name=p.name) for p in m.pois]
        i = 0
        for name, action in m.done:  # in order, POI by POI (a POI may come twice in a goal)
            while i < len(m.pois) and (m.pois[i].name != name or len(progress[i].done) >= len(m.pois[i].actions)):
                i += 1
            if i < len(m.pois):
                progress[i].done.append(action)
        self.status.put(
            MissionStatus(
                t=now,
                goal_id=self.goal_id,
                state=m.state.value,
                kind=self.kind,
                poi=m.current_name() if m.pois and m.index < len(m.pois) else None,
                action=m.current_action(),
                distance_m=None if distance is None or m.drive else round(distance, 2),
                eta_s=eta,
                limit_mps=self._limit if math.isfinite(self._limit) else None,
                ready_to_move=body is not None and ready_to_move(body),
                pois=progress,
                result=m.result,
            )
        )

    # ---- a restart goes on ----------------------------------------------------------------------
    def _save(self) -> None:
        if self.state_path is None:
            return
        snap = {
            "goal_id": self.goal_id,
            "kind": self.kind,
            "targets": self.targets,
            "repeat": self.repeat,
            "progress": self.progress,
            "last_s": self._last_s,
            "ended_reported": self._ended_reported,
            "mission": self.mission.snapshot(),
        }
        tmp = self.state_path.with_suffix(".tmp")
        tmp.write_text(json.dumps(snap))
        tmp.replace(self.state_path)  # atomic: a kill mid-write leaves the previous one

    def _restore(self) -> bool:
        if self.state_path is None or not self.state_path.exists():
            return False
        try:
            snap = json.loads(self.state_path.read_text())
            self.mission = Mission.restore(snap["mission"], self.mission.params)
            self.goal_id, self.kind, self.targets = int(snap["goal_id"]), snap["kind"], list(snap["targets"])
            self.repeat = bool(snap["repeat"])
            self.progress, self._last_s = snap["progress"], snap["last_s"]
            self._ended_reported = bool(snap["ended_reported"])
            return True
        except (OSError, ValueError, KeyError, TypeError) as exc:
            self.event(
                "mission",
                f"could not read the mission left by the last run of this process ({exc}): starting without a goal",
                EventLevel.WARNING,
            )
            return False
