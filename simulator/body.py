"""The shuttle's body, simulated: doors and ramp with travel times and end-position sensors, and
passengers who board and alight at the points of interest.

Doors and ramp are each a position p in [0, 1] (0 closed / stowed, 1 open / deployed) moved at
1 / travel_s towards the end asked for; a new demand turns them round mid-travel. Their sensors
report only the ends (closed, open) and the direction between them (opening, closing), as end
switches do. The ramp moves only with the doors fully open (an interlock in the body itself).

Passengers: at a POI where the scenario puts people, once the doors are open those alighting
and then those boarding pass through the entrance one at a time, `per_person_s` each; anyone
who needs the ramp waits until it is deployed. While someone passes, the entrance is not clear.
A late passenger steps into the doorway as the doors begin to close, which the mission must
answer by opening them again.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from simulator.scenario import ScenarioPassengers


@dataclass
class Travel:
    """A door or ramp: its position and where it is going."""

    travel_s: float
    position: float = 0.0  # 0 closed / stowed, 1 open / deployed
    target: float = 0.0

    def step(self, dt: float) -> None:
        rate = dt / self.travel_s
        if self.position < self.target:
            self.position = min(self.target, self.position + rate)
        elif self.position > self.target:
            self.position = max(self.target, self.position - rate)

    def sensed(self, names: tuple[str, str, str, str]) -> str:
        """(closed, moving out, out, moving in) as its end switches tell it."""
        closed, opening, opened, closing = names
        if self.position <= 0.0:
            return opening if self.target > 0 else closed
        if self.position >= 1.0:
            return closing if self.target < 1 else opened
        return opening if self.target > self.position else closing


DOOR_NAMES = ("closed", "opening", "open", "closing")
RAMP_NAMES = ("stowed", "deploying", "deployed", "stowing")


@dataclass(frozen=True)
class Person:
    alighting: bool  # leaving the shuttle (else boarding)
    needs_ramp: bool = False


@dataclass
class Visit:
    """The people at one POI for this stop, in the order they pass the entrance."""

    queue: list[Person]
    late: int  # boarding as the doors begin to close
    passing_left_s: float = 0.0  # the one in the entrance now


@dataclass
class BodySim:
    door_travel_s: float
    ramp_travel_s: float
    per_person_s: float
    passengers: int
    stops: dict[str, ScenarioPassengers] = field(default_factory=dict)  # POI name -> who is waiting there
    media: bool = False

    def __post_init__(self) -> None:
        self.doors = Travel(self.door_travel_s)
        self.ramp = Travel(self.ramp_travel_s)
        self.visit: Visit | None = None
        self.served: set[str] = set()  # POIs whose people have been served (once each)
        self._was_closing = False

    # ---- the actuators --------------------------------------------------------------------------
    def command(self, doors: str | None, ramp: str | None, media: bool) -> None:
        if doors == "open":
            self.doors.target = 1.0
        elif doors == "close" and self.ramp.position <= 0.0:  # never close on the ramp
            self.doors.target = 0.0
        if ramp == "deploy" and self.doors.position >= 1.0:
            self.ramp.target = 1.0
        elif ramp == "stow":
            self.ramp.target = 0.0
        self.media = self.media or media

    # ---- what the sensors say ---------------------------------------------------------------------
    @property
    def door_state(self) -> str:
        return self.doors.sensed(DOOR_NAMES)

    @property
    def ramp_state(self) -> str:
        return self.ramp.sensed(RAMP_NAMES)

    @property
    def entrance_clear(self) -> bool:
        return self.visit is None or self.visit.passing_left_s <= 0.0

    # ---- time ---------------------------------------------------------------------------------------
    def step(self, dt: float, poi_here: str | None) -> None:
        """One step, with the POI the shuttle stands at (None: none, or moving)."""
        if self.doors.target < self.doors.position and self.ramp.position > 0.0:
            self.doors.target = 1.0  # the interlock: doors stay open over a ramp
        if self.ramp.target > 0 and self.doors.position < 1.0:
            self.ramp.target = 0.0
        self.doors.step(dt)
        self.ramp.step(dt)
        if poi_here is not None and self.visit is None and poi_here in self.stops and poi_here not in self.served:
            who = self.stops[poi_here]
            self.served.add(poi_here)
            self.visit = Visit(
                queue=[Person(alighting=True) for _ in range(who.alighting)]
                + [Person(alighting=False, needs_ramp=i < who.on_ramp) for i in range(who.boarding)],
                late=who.late,
            )
        visit = self.visit
        if visit is None:
            return
        closing = self.door_state == "closing"
        if closing and not self._was_closing and visit.late > 0:
            visit.late -= 1  # someone runs for it: into the closing doorway
            self._pass(Person(alighting=False))
        self._was_closing = closing
        if visit.passing_left_s > 0.0:
            visit.passing_left_s = max(0.0, visit.passing_left_s - dt)
            return
        if not visit.queue:
            if visit.late == 0 and self.door_state == "closed":
                self.visit = None  # everyone served and the doors shut: the stop is over
            return
        if self.door_state != "open" or (visit.queue[0].needs_ramp and self.ramp_state != "deployed"):
            return
        self._pass(visit.queue.pop(0))

    def _pass(self, person: Person) -> None:
        self.visit.passing_left_s = self.per_person_s
        self.passengers = max(0, self.passengers + (-1 if person.alighting else 1))
