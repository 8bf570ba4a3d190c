"""The mission's state machine (ARES §3.3, §4), without a bus: a goal of points of interest, each
run through its actions, doors and ramp driven and watched, and the speed limit the mission sets.

A goal is an ordered list of POIs, each with the actions the tour gives it, among the paper's:

| action        | what the mission does                                  | done when                          |
|---------------|--------------------------------------------------------|------------------------------------|
| STOP          | limit 0 at the POI (the approach limit brought it)     | standing (speed <= stopped_mps)    |
| FULL_STOP     | holds (at a tour's marked intersections, while         | standing for full_stop_s           |
|               | driving: managers/intersection_stop.py)                |                                    |
| OPENING_DOORS | opens the doors                                        | the doors' sensor says open        |
| TAKEOFF_RAMP  | deploys the ramp (doors open)                          | the ramp's sensor says deployed    |
| PICKUP_RAMP   | stows the ramp once nobody is on it                    | the ramp's sensor says stowed      |
| CLOSING_DOORS | closes the doors once the entrance is clear; re-opens  | the doors' sensor says closed      |
|               | them if someone steps in while they close              |                                    |
| START_MEDIA   | starts the on-board media                              | at once                            |
| NEXT_POI      | sets off for the next POI (the POI's last action)      | at once                            |

The doors and the ramp move only once the shuttle has stood `settle_s` (0.5 s): the speed read at
the standing threshold may still be the end of a roll (the whole-stack mission test once saw the doors opening at
0.05 m/s of true speed).

A goal may also be a *drive*: no POI, round the route without stopping (runs about something
else than passengers: comparisons, tests); its limit is none while the body is ready to move.

Mission states: IDLE (no goal), DRIVING (to the next POI), AT_POI (running its actions), PAUSED
(holding where it is; resume goes back), SUCCEEDED (the last POI done), CANCELED. A new goal while
one runs pre-empts it (the old one ends CANCELED with that reason), but never while the doors are
open or the ramp is out: the shuttle must be ready to move before anything else is asked of it.

The mission's speed limit, which the movement gate applies:
- DRIVING: sqrt(2 · approach_decel · d), with d the distance to the POI's stop point. Anything
  further away is no limit (inf).
- Every other state: 0. Nothing moves without a mission, and never with a door open or the ramp
  out (`ready_to_move`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import Enum

from ares.core.config import POI_ACTIONS, Params, param


class MissionState(str, Enum):
    IDLE = "IDLE"
    DRIVING = "DRIVING"
    AT_POI = "AT_POI"
    PAUSED = "PAUSED"
    SUCCEEDED = "SUCCEEDED"
    CANCELED = "CANCELED"


ACTIVE = (MissionState.DRIVING, MissionState.AT_POI, MissionState.PAUSED)


class MissionParams(Params):
    reach_m: float = param(0.5, "a POI is reached this close to its stop point", unit="m", gt=0)
    stopped_mps: float = param(0.05, "standing", unit="m/s", gt=0)
    settle_s: float = param(
        0.5,
        "doors and ramp move only after standing this long: a speed read at the standing "
        "threshold may still be the last of a roll (the parking brake holds it after)",
        unit="s",
        ge=0,
    )
    full_stop_s: float = param(2.0, "FULL_STOP: standing this long", unit="s", ge=0)
    approach_decel_mps2: float = param(0.5, "the approach to a POI's stop point", unit="m/s^2", gt=0)


@dataclass(frozen=True)
class PoiGoal:
    name: str
    s: float  # along the route, where to stop
    actions: tuple[str, ...]


@dataclass(frozen=True)
class Body:
    """What the body's sensors say now."""

    doors: str = "closed"  # closed, opening, open, closing
    ramp: str = "stowed"  # stowed, deploying, deployed, stowing
    entrance_clear: bool = True  # nobody in the doorway or on the ramp


@dataclass(frozen=True)
class Commands:
    """What the mission asks of the body this step (None: leave it as it is)."""

    doors: str | None = None  # "open" or "close"
    ramp: str | None = None  # "deploy" or "stow"
    media: bool = False  # start the media now


@dataclass
class Mission:
    params: MissionParams = field(default_factory=MissionParams)
    state: MissionState = MissionState.IDLE
    pois: list[PoiGoal] = field(default_factory=list)
    index: int = 0  # the POI driven to or at
    action: int = 0  # its action running (AT_POI)
    result: str = ""  # why the last goal ended
    done: list[tuple[str, str]] = field(default_factory=list)  # (POI, action) done, in order
    drive: bool = False  # a drive goal: no POI, no stop
    _paused_from: MissionState | None = None
    _standing_since: float | None = None

    # ---- the action interface: goal, cancel, pause, resume ------------------------------------
    def goal(self, pois: list[PoiGoal], body: Body, drive: bool = False) -> tuple[bool, str]:
        if not pois and not drive:
            return False, "refused: a goal needs at least one POI (or to be a drive)"
        if pois and drive:
            return False, "refused: a drive goal has no POIs"
        bad = [a for poi in pois for a in poi.actions if a not in POI_ACTIONS]
        if bad:
            return False, f"refused: unknown actions {sorted(set(bad))} (known: {', '.join(POI_ACTIONS)})"
        if not ready_to_move(body):
            return False, "refused: the doors must be closed and the ramp stowed first"
        if self.state in ACTIVE:
            self.result = f"pre-empted by a new goal at {self.current_name()}"
        self.pois, self.index, self.action, self.done, self.drive = list(pois), 0, 0, [], drive
        self.state, self._paused_from, self._standing_since = MissionState.DRIVING, None, None
        return True, "accepted: a drive, no stops" if drive else f"accepted: {len(pois)} POIs, first {pois[0].name}"

    def cancel(self, body: Body) -> tuple[bool, str]:
        if self.state not in ACTIVE:
            return False, f"nothing to cancel ({self.state.value})"
        if not ready_to_move(body):
            return False, "refused: the doors must be closed and the ramp stowed first"
        self.state, self.result = MissionState.CANCELED, f"canceled at {self.current_name()}"
        return True, self.result

    def pause(self) -> tuple[bool, str]:
        if self.state not in (MissionState.DRIVING, MissionState.AT_POI):
            return False, f"nothing to pause ({self.state.value})"
        self._paused_from, self.state = self.state, MissionState.PAUSED
        return True, f"paused at {self.current_name()}"

    @property
    def paused_from(self) -> MissionState | None:
        return self._paused_from

    def resume(self, body: Body | None = None) -> tuple[bool, str]:
        if self.state is not MissionState.PAUSED or self._paused_from is None:
            return False, f"nothing to resume ({self.state.value})"
        if self._paused_from is MissionState.DRIVING and (body is None or not ready_to_move(body)):
            # (a POI's actions close what they opened themselves; a drive does not)
            return (
                False,
                "refused: close the doors and stow the ramp first"
                if body is not None
                else "refused: the doors' state is not known",
            )
        self.state, self._paused_from = self._paused_from, None
        return True, f"resumed: {self.state.value}"

    # ---- each step ------------------------------------------------------------------------------
    def step(self, now: float, distance_m: float | None, speed_mps: float, body: Body) -> Commands:
        """Advance with the distance to the current POI's stop point (None: unknown), the speed and
        the body's sensors; returns what the body must do."""
        standing = speed_mps <= self.params.stopped_mps
        self._standing_since = (self._standing_since if self._standing_since is not None else now) if standing else None
        if self.drive:
            return Commands()
        if self.state is MissionState.DRIVING and distance_m is not None and distance_m <= self.params.reach_m:
            self.state, self.action = MissionState.AT_POI, 0
        if self.state is not MissionState.AT_POI:
            return Commands()
        poi = self.pois[self.index]
        commands = Commands()
        while self.action < len(poi.actions):
            name = poi.actions[self.action]
            finished, asked = self._run(name, now, standing, body)
            # actions finished in one step add up (START_MEDIA then NEXT_POI: the media still start)
            commands = Commands(
                asked.doors or commands.doors, asked.ramp or commands.ramp, asked.media or commands.media
            )
            if not finished:
                return commands
            self.done.append((poi.name, name))
            self.action += 1
            if name == "NEXT_POI":
                break
        # every action of this POI done: the next one, or the goal reached
        self.index += 1
        self.action = 0
        if self.index >= len(self.pois):
            self.state, self.result = MissionState.SUCCEEDED, f"every POI done, last {poi.name}"
        else:
            self.state = MissionState.DRIVING
        return commands

    def _run(self, name: str, now: float, standing: bool, body: Body) -> tuple[bool, Commands]:
        """(finished, commands) of one action."""
        if name == "STOP":
            return standing, Commands()
        if name == "FULL_STOP":
            return (
                standing and self._standing_since is not None and now - self._standing_since >= self.params.full_stop_s,
                Commands(),
            )
        settled = standing and self._standing_since is not None and now - self._standing_since >= self.params.settle_s
        if name in ("OPENING_DOORS", "TAKEOFF_RAMP", "PICKUP_RAMP", "CLOSING_DOORS") and not settled:
            return False, Commands()  # doors and ramp move only with the shuttle standing, settled
        if name == "OPENING_DOORS":
            return body.doors == "open", Commands(doors=None if body.doors == "open" else "open")
        if name == "TAKEOFF_RAMP":
            if body.doors != "open":
                return False, Commands(doors="open")
            return body.ramp == "deployed", Commands(ramp=None if body.ramp == "deployed" else "deploy")
        if name == "PICKUP_RAMP":
            if body.ramp == "stowed":
                return True, Commands()
            if not body.entrance_clear:
                return False, Commands(ramp="deploy" if body.ramp == "stowing" else None)  # someone on it
            return False, Commands(ramp="stow")
        if name == "CLOSING_DOORS":
            if body.ramp != "stowed":
                return False, Commands(ramp="stow" if body.entrance_clear else None)
            if not body.entrance_clear:
                # passengers boarding: wait, and re-open doors that were closing on them
                return False, Commands(doors="open" if body.doors == "closing" else None)
            return body.doors == "closed", Commands(doors=None if body.doors == "closed" else "close")
        if name == "START_MEDIA":
            return True, Commands(media=True)
        return True, Commands()  # NEXT_POI

    # ---- what the mission says --------------------------------------------------------------------
    def limit_mps(self, distance_m: float | None, body: Body) -> float:
        if not ready_to_move(body) or self.state is not MissionState.DRIVING:
            return 0.0
        if self.drive:
            return math.inf
        if distance_m is None:
            return 0.0  # where the POI is is unknown: do not run past it
        return math.sqrt(2.0 * self.params.approach_decel_mps2 * max(distance_m - self.params.reach_m / 2, 0.0))

    # ---- a restarted mission manager goes on where its predecessor was -------------------------
    def snapshot(self) -> dict:
        return {
            "state": self.state.value,
            "pois": [[p.name, p.s, list(p.actions)] for p in self.pois],
            "index": self.index,
            "action": self.action,
            "result": self.result,
            "done": [list(d) for d in self.done],
            "drive": self.drive,
            "paused_from": self._paused_from.value if self._paused_from else None,
        }

    @classmethod
    def restore(cls, snap: dict, params: MissionParams) -> Mission:
        m = cls(
            params=params,
            state=MissionState(snap["state"]),
            pois=[PoiGoal(name, float(s), tuple(actions)) for name, s, actions in snap["pois"]],
            index=int(snap["index"]),
            action=int(snap["action"]),
            result=str(snap["result"]),
            done=[(a, b) for a, b in snap["done"]],
            drive=bool(snap["drive"]),
        )
        m._paused_from = MissionState(snap["paused_from"]) if snap["paused_from"] else None
        return m

    def current_name(self) -> str:
        return self.pois[self.index].name if self.pois and self.index < len(self.pois) else "-"

    def current_action(self) -> str | None:
        if self.state is not MissionState.AT_POI and not (
            self.state is MissionState.PAUSED and self._paused_from is MissionState.AT_POI
        ):
            return None
        poi = self.pois[self.index]
        return poi.actions[self.action] if self.action < len(poi.actions) else None


def ready_to_move(body: Body) -> bool:
    return body.doors == "closed" and body.ramp == "stowed"


def body_request_refusal(
    state: MissionState, standing: bool, body: Body, doors: str | None, ramp: str | None
) -> str | None:
    """Why an operator's demand to the doors or the ramp is refused, or None to pass it on.
    `state`: the mission's, or while paused the state it was paused from. Only standing, and
    never while the mission drives or is amid a POI's actions (they would undo it, or drive off
    with the doors open); and by the body's interlocks: the ramp under open doors and stowed only
    with nobody on it, the doors closed over a stowed ramp and an empty entrance."""
    if doors is None and ramp is None:
        return "refused: nothing asked of the doors or the ramp"
    if not standing:
        return "refused: the shuttle is moving"
    if state is MissionState.DRIVING:
        return "refused: the mission is DRIVING (pause it first)"
    if state is MissionState.AT_POI:  # running, or paused amid, a POI's actions: they own the body
        return "refused: a POI's actions run the doors and the ramp (cancel the mission first)"
    if ramp == "deploy" and (body.doors != "open" or doors == "close"):
        return "refused: the ramp deploys only under open doors"
    if ramp == "stow" and not body.entrance_clear:
        return "refused: someone is on the ramp or in the doorway"
    if doors == "close" and (body.ramp != "stowed" or ramp == "deploy" or not body.entrance_clear):
        return "refused: the doors close only over a stowed ramp and an empty entrance"
    return None
