"""Scenarios (scenarios/*.yaml): what happens around the simulated shuttle: obstacles and their
motion, sensor and process faults, passengers at the POIs, the operator's actions, and what the
human at the wheel does (steer, throttle, brake, the Auto/Manual button) at a time or a place."""

from __future__ import annotations

from pathlib import Path
from typing import Literal, Self

from pydantic import model_validator

from ares.core.config.base import Params, load_yaml, named_file, param, validated


class ScenarioPlace(Params):
    """A place beside the route: arc length and lateral offset (left +)."""

    s: float = param(doc="distance along the route", unit="m")
    offset_m: float = param(0.0, "left (+) or right (−) of the route's centre line", unit="m")
    wait_s: float = param(0.0, "a moving obstacle stands here this long before it goes on", unit="s", ge=0)


OBSTACLE_SIZES: dict[str, tuple[float, float, float]] = {  # length, width, height (m)
    "box": (0.4, 0.4, 0.3),
    "crate": (0.8, 0.6, 0.6),
    "pedestrian": (0.5, 0.5, 1.75),
    "cart": (1.8, 1.2, 1.5),
    "vehicle": (4.2, 1.8, 1.5),
}


class ScenarioObstacle(Params):
    """A static obstacle (one place) or a moving one (a path walked at `speed_mps`)."""

    name: str
    kind: Literal["box", "crate", "pedestrian", "cart", "vehicle"]
    size_m: tuple[float, float, float] | None = param(None, "length, width, height (default: the kind's)", unit="m")
    path: list[ScenarioPlace] = param(doc="where it stands, or the path it follows", min_length=1)
    speed_mps: float = param(0.0, "walking or driving speed along the path", unit="m/s", ge=0)
    start_t_s: float | None = param(None, "starts moving at this stack time ...", unit="s", ge=0)
    start_when_vehicle_at_s: float | None = param(
        None, "... or when the vehicle reaches this distance along the route (its first lap)", unit="m", ge=0
    )
    appear_ahead_m: float | None = param(
        None,
        "absent until start_t_s, then it appears this far ahead of the vehicle: the path's places (s) are "
        "counted from there (a soak's pedestrian or parked object in the path)",
        unit="m",
        ge=0,
    )
    gone_after_s: float | None = param(None, "it leaves the world this long after it appeared", unit="s", gt=0)

    @model_validator(mode="after")
    def _appears_at_a_time(self) -> Self:
        if self.appear_ahead_m is not None and self.start_t_s is None:
            raise ValueError(f"obstacle {self.name}: appear_ahead_m needs start_t_s (when it appears)")
        if self.gone_after_s is not None and self.appear_ahead_m is None:
            raise ValueError(f"obstacle {self.name}: gone_after_s is for an obstacle that appears (appear_ahead_m)")
        return self

    def size(self) -> tuple[float, float, float]:
        return self.size_m or OBSTACLE_SIZES[self.kind]


class ScenarioAlongTour(Params):
    """Obstacles of several sizes placed along the tour, beside the path the shuttle drives."""

    every_m: float = param(40.0, "one obstacle every ...", unit="m", gt=0)
    kinds: list[Literal["box", "crate", "pedestrian", "cart", "vehicle"]] = param(
        factory=lambda: ["box", "crate", "pedestrian", "cart", "vehicle"], doc="in turn"
    )
    clearance_m: float = param(1.5, "gap between the route's centre line and the obstacle's near side", unit="m", ge=0)
    skip_narrower_than_m: float = param(5.0, "no obstacle where the road is narrower", unit="m", gt=0)


class ScenarioPassengers(Params):
    """People at a point of interest: they alight, then board, one at a time, when the doors open."""

    poi: str = param(doc="the POI's name (in the tour)")
    boarding: int = param(0, "people getting on", ge=0)
    alighting: int = param(0, "people getting off", ge=0)
    on_ramp: int = param(0, "of those boarding, how many need the ramp (a wheelchair, a pram): they wait for it", ge=0)
    late: int = param(0, "of those boarding, how many more step into the doorway as the doors begin to close", ge=0)

    @model_validator(mode="after")
    def _ramp_users_board(self) -> Self:
        if self.on_ramp > self.boarding:
            raise ValueError(f"on_ramp ({self.on_ramp}) is more than boarding ({self.boarding})")
        return self


FAULT_FIELDS: dict[str, tuple[set[str], set[str]]] = {  # kind -> (fields it needs, fields it may have)
    "block_lidar": ({"sensor", "at_t_s"}, {"duration_s"}),
    "gnss_outage": (set(), {"at_t_s", "duration_s", "s_start_m", "s_end_m"}),
    "gnss_no_corrections": (set(), {"at_t_s", "duration_s", "s_start_m", "s_end_m"}),
    "wheel_speed_scale": ({"scale"}, {"at_t_s", "duration_s"}),
    "gyro_bias": ({"bias_deg_s"}, {"at_t_s", "duration_s"}),
    "freeze_imu": ({"at_t_s"}, {"duration_s"}),
    "kill_process": ({"process", "at_t_s"}, set()),
    "stop_process": ({"process", "at_t_s"}, set()),
    "hang_process": ({"process", "at_t_s"}, set()),
}
PROCESS_FAULTS = ("kill_process", "stop_process", "hang_process")


class ScenarioFault(Params):
    """A fault, from `at_t_s` (stack time) for `duration_s`, or over a stretch of the route
    (`s_start_m`..`s_end_m`, every lap); without either, for the whole run."""

    kind: Literal[
        "block_lidar",
        "gnss_outage",
        "gnss_no_corrections",
        "wheel_speed_scale",
        "gyro_bias",
        "freeze_imu",
        "kill_process",
        "stop_process",
        "hang_process",
    ] = param(
        doc="block_lidar: an opaque cover over a LiDAR; gnss_outage: no fix at all; gnss_no_corrections: no RTK "
        "corrections (a float fix, as in a tour's rtk_loss zone); wheel_speed_scale: the CAN wheel speed reads "
        "(1 + scale) x the truth; gyro_bias: the IMU's yaw rate reads bias_deg_s too much; freeze_imu: the IMU "
        "repeats its last reading; kill_process: SIGKILL; stop_process: SIGTERM (it exits); hang_process: "
        "SIGSTOP (alive but its loop stands still, until the supervisor kills it)"
    )
    process: str | None = param(None, "process faults: which process (a name of the process table)")
    sensor: Literal["roof", "front_left", "front_right"] | None = param(None, "block_lidar: which LiDAR")
    at_t_s: float | None = param(None, "stack time it begins", unit="s", ge=0)
    duration_s: float | None = param(None, "how long it lasts (for ever if not given)", unit="s", gt=0)
    s_start_m: float | None = param(None, "GNSS faults: the stretch of the route where it holds ...", unit="m", ge=0)
    s_end_m: float | None = param(None, "... and where it ends", unit="m", ge=0)
    scale: float | None = param(None, "wheel_speed_scale: 0.02 reads 2 % fast", gt=-0.5, lt=0.5)
    bias_deg_s: float | None = param(None, "gyro_bias: added to the yaw rate", unit="deg/s")

    @model_validator(mode="after")
    def _fields_of_its_kind(self) -> Self:
        needs, may = FAULT_FIELDS[self.kind]
        given = {
            name
            for name in ("sensor", "at_t_s", "duration_s", "s_start_m", "s_end_m", "scale", "bias_deg_s", "process")
            if getattr(self, name) is not None
        }
        if needs - given:
            raise ValueError(f"a {self.kind} fault needs {', '.join(sorted(needs - given))}")
        if given - needs - may:
            raise ValueError(f"a {self.kind} fault has no {', '.join(sorted(given - needs - may))}")
        if (self.s_start_m is None) != (self.s_end_m is None):
            raise ValueError("a stretch needs both s_start_m and s_end_m")
        if (
            self.s_start_m is not None
            and self.s_end_m is not None  # given with s_start_m: checked above
            and (self.at_t_s is not None or self.s_end_m <= self.s_start_m)
        ):
            raise ValueError("a fault holds over a stretch (s_start_m < s_end_m) or from a time, not both")
        return self

    def active(self, t: float, s: float | None = None) -> bool:
        """Whether it holds at stack time t with the vehicle at s along the route."""
        if self.s_start_m is not None and self.s_end_m is not None:  # a stretch has both (validated)
            return s is not None and self.s_start_m <= s <= self.s_end_m
        begins = self.at_t_s or 0.0
        return t >= begins and (self.duration_s is None or t < begins + self.duration_s)


class ScenarioOperatorAction(Params):
    """An operator's action through the vehicle's services, at a stack time (engage: the software
    half of the Auto/Manual switch, `set_automatic_mode`, after the driver's button)."""

    at_t_s: float = param(doc="stack time", unit="s", ge=0)
    action: Literal["rearm", "pause", "resume", "cancel", "engage"]


class ScenarioDriverAction(Params):
    """What the person at the wheel does, at a stack time or where the shuttle first reaches a
    point of the route: the simulator plays it as the `sim/driver` service does (the drive-by-wire
    bridge sees the pedal, the wheel's torque or the button, and any of them takes it to Manual)."""

    action: Literal["steer", "throttle", "brake", "button", "release"] = param(
        doc="steer: hold the steering wheel at `value` degrees; throttle, brake: the pedal at `value` (0..1); "
        "button: press Auto/Manual; release: let go of everything"
    )
    at_t_s: float | None = param(None, "stack time it happens ...", unit="s", ge=0)
    at_s_m: float | None = param(None, "... or the route's arc length where the shuttle first reaches", unit="m", ge=0)
    value: float = param(0.0, "steering-wheel angle (deg, + left) or pedal position (0..1)")
    duration_s: float = param(1.0, "how long the hand or foot stays", unit="s", ge=0, le=600)

    @model_validator(mode="after")
    def _one_moment_and_a_pedal_within_its_travel(self) -> Self:
        if (self.at_t_s is None) == (self.at_s_m is None):
            raise ValueError(f"a driver's {self.action} happens at a time (at_t_s) or a place (at_s_m): one of them")
        if self.action in ("throttle", "brake") and not 0.0 <= self.value <= 1.0:
            raise ValueError(f"a pedal's position is within 0..1, got {self.value}")
        return self


class Scenario(Params):
    """What happens around the simulated shuttle: obstacles and their motion, faults and their times."""

    name: str
    description: str = ""
    obstacles: list[ScenarioObstacle] = param(factory=list)
    along_tour: ScenarioAlongTour | None = param(None, "also place obstacles along the tour")
    faults: list[ScenarioFault] = param(factory=list)
    passengers: list[ScenarioPassengers] = param(factory=list, doc="people waiting at the POIs")
    operator: list[ScenarioOperatorAction] = param(factory=list, doc="what the operator does, and when")
    driver: list[ScenarioDriverAction] = param(factory=list, doc="what the person at the wheel does, when or where")
    start_s_m: float | None = param(
        None, "where along the route the shuttle stands at start (default: sim.start_s_m)", unit="m", ge=0
    )
    mission: Literal["tour", "drive"] | None = param(
        None, "the goal the run starts: every POI of the tour, or round without stopping (default: the configuration's)"
    )

    @model_validator(mode="after")
    def _one_visit_per_poi(self) -> Self:
        pois = [p.poi for p in self.passengers]
        if len(set(pois)) != len(pois):
            raise ValueError(f"passengers: one entry per POI ({pois})")
        return self


def scenario_file(name: str) -> Path:
    """A built-in scenario (simulator/scenarios/NAME.yaml) by name, or a YAML file by path."""
    return named_file("scenarios", name, folder=Path(__file__).parent)


def load_scenario(name: str) -> Scenario:
    path = scenario_file(name)
    return validated(Scenario, load_yaml(path), str(path))
