"""A run's configuration: the core sections every process reads, and the whole run's, built.

Every section of a run's configuration is a pydantic model (`Params`) whose fields carry their
default, unit, range and meaning (`param(...)`). Core sections (vehicle id, bus, heartbeat,
clock, the local frame's origin, the vehicle profile) are defined here; each node defines its
own section next to its code (`Node.Params`), and the composition layer (ares.app.run_config)
assembles the whole model from the process table. Nothing else holds defaults: no YAML file of
defaults, no `dict.get(key, default)` in code.

Files: vehicle profiles and tours are data (ares/core/config/vehicles/*.yaml, tours/*.yaml), typed
by VehicleProfile and TourDescription. A user's run configuration is a YAML file of overrides
(`ares run --config FILE`). Each file is validated on its own, so an error names the file, the
key and what is allowed; `ConfigError` carries that sentence.

A run's effective configuration (validated, every default filled in) is written once by
`ares run` to a JSON file whose path reaches every child process through ARES_RUN_CONFIG, so
all processes of a run agree on it; a node validates its own section again on start.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal, TypeVar

from pydantic import BaseModel, ValidationError, model_validator

from ares.core.config.base import (
    ConfigError,
    Params,
    deep_merge,
    error_line,
    load_yaml,
    named_file,
    param,
    sentence,
    validated,
)
from ares.core.config.vehicle import VehicleProfile, load_vehicle
from ares.core.config.vehicle_io import VehicleIo

RUN_CONFIG_ENV = "ARES_RUN_CONFIG"
VEHICLE_ID_PATTERN = r"^[A-Za-z0-9_.-]{1,64}$"  # one key segment of ares/<vehicle_id>/...

Section = TypeVar("Section", bound=Params)


OBSERVER_USER = "observer"  # the read-only tools' user on a deployed vehicle's router (bus.credentials_file)


class BusSettings(Params):
    mode: Literal["peer", "client"] = param(
        "peer",
        "how processes join the bus: peer (a direct link between "
        "processes, lowest latency) or client (everything through the router)",
    )
    router: str = param(
        "tcp/127.0.0.1:7447",
        "the router's endpoint; the embedded router listens here",
        pattern=r"^[a-z][a-z0-9+-]*/\S+$",
    )
    embedded_router: bool = param(True, "the supervisor hosts the router in its own session (no zenohd needed)")
    listen: list[str] = param(
        doc="where a peer accepts direct links from other peers (loopback by default)",
        factory=lambda: ["tcp/127.0.0.1:0"],
    )
    lease_ms: int = param(
        2000, "liveliness lease: a frozen process's token disappears after ~3/4 of it", unit="ms", ge=200
    )
    service_timeout_s: float = param(2.0, "longest a service call waits for its reply", unit="s", gt=0)
    user: str | None = param(
        None, "Zenoh user name for a router that asks for credentials (a deployment's router); null: none"
    )
    password_file: str | None = param(
        None, "file holding that user's password (a compose secret); never the password itself in a config"
    )
    credentials_file: str | None = param(
        None,
        "a `user:password` dictionary (a compose secret): each process logs in as its own name, the "
        "supervisor as `supervisor`, `ares topics` and `ares echo` as `observer` (read only); instead of "
        "user and password_file",
    )

    @model_validator(mode="after")
    def _user_and_password(self) -> BusSettings:
        if (self.user is None) != (self.password_file is None):
            raise ValueError("bus: give both user and password_file, or neither")
        if self.credentials_file is not None and self.user is not None:
            raise ValueError("bus: give credentials_file, or user and password_file, not both")
        if (self.user is not None or self.credentials_file is not None) and self.mode == "peer":
            # peers link to each other directly, past the router that checks the credentials, and
            # such links are refused: every process must go through the router
            raise ValueError("bus: with user and password_file (a router that asks for credentials) set mode: client")
        return self


class CommandSettings(Params):
    """The key that signs an operator's commands (ares/core/signed_command.py)."""

    key_file: str | None = param(
        None,
        "the vehicle's command key (a compose secret, at least 32 characters) with which its API and "
        "CLI sign an operator's commands and its managers check them; null: `command_key` in the "
        "user's state directory ($XDG_STATE_HOME/ares or ~/.local/state/ares), made at first use",
    )
    max_age_s: float = param(
        10.0,
        "a signed command older than this (wall clock) is refused as stale; its nonce is remembered "
        "this long against a replay",
        unit="s",
        gt=0,
    )


class HeartbeatSettings(Params):
    period_s: float = param(
        0.2, "heartbeat period, wall clock: it reveals a stuck Python loop, not sim time", unit="s", gt=0
    )
    stale_after_s: float = param(
        2.0,
        "a heartbeat older than this means the process is hung (generous: a "
        "loaded 2-core machine can starve a process for ~1 s)",
        unit="s",
        gt=0,
    )


class LockstepSettings(Params):
    """`--speed max`: the simulator drives the stack clock (ares.core.lockstep)."""

    participants: list[str] = param(
        doc="processes the simulator waits for before advancing the clock; filled "
        "in by `ares run` from the topic graph (every process its outputs feed)",
        factory=list,
    )
    max_wait_s: float = param(
        2.0,
        "wall seconds a participant may hold the clock back before the simulator goes "
        "on without it (it rejoins with its next report)",
        unit="s",
        gt=0,
    )
    start_wait_s: float = param(
        60.0, "wall seconds the simulator waits at start for every participant to join", unit="s", gt=0
    )
    max_step_s: float = param(0.1, "longest clock step while no participant is due", unit="s", gt=0)
    pace: float | None = param(
        None,
        "at most this many stack seconds per wall second (`--speed paced`: 1); null: "
        "as fast as every participant keeps up (`--speed max`)",
        gt=0,
    )
    broadcast_period_s: float = param(
        0.05,
        "how often the time goes to the processes outside the lockstep "
        "(supervisor, API): each participant hears it only when it is due",
        unit="s",
        gt=0,
    )


class ReplaySettings(Params):
    record: list[str] = param(
        doc="processes that write their inputs and outputs, step by step, for process replay (ares.core.replay)",
        factory=list,
    )
    dir: str | None = param(None, "where the recordings go (default: <run dir>/replay)")


# The light log's rates (`recording.light_rates_hz`), as openpilot's qlog decimates its rlog: what an
# engineer reads after a day's driving (where it was, what it was told, how sure it was, why it
# stopped), a few per second; every event and every black-box second; no clouds, no grid.
LIGHT_RATES_HZ: dict[str, float] = {
    "events": 0,  # 0: every message
    "blackbox/record": 0,
    "blackbox/status": 0,
    "supervisor/state": 0,
    "vehicle/panel": 0,
    "body/command": 0,
    "body/state": 1,
    "mission/status": 1,
    "localization/pose": 5,
    "gnss/fix": 1,
    "gnss/corrections": 1,
    "odometry/score": 2,
    "awareness/state": 2,
    "path/match": 1,
    "speed/limits": 2,
    "obstacle/state": 2,
    "control/status": 2,
    "control/setpoint": 5,
    "movement/status": 2,
    "dbw/car_state": 5,
    "dbw/actuators": 5,
    "perception/road": 1,
    "perception/lidar_status": 1,
    "drivers/status": 0.2,
    "heartbeat/*": 0.2,
    "sim/truth": 5,
}


class SnapshotTrigger(Params):
    """An event that saves a snapshot: its kind, the values its data must have (all of them) and
    those it must not (any). A trigger within `before_s` of one under way is covered by that one."""

    kind: str = param(doc="the event's kind (`emergency_stop`, `mode_change`, ...)")
    where: dict[str, str | int | float | bool] = param(doc="data the event must carry, key: value", factory=dict)
    unless: dict[str, str | int | float | bool] = param(
        doc="data that makes it no trigger (any of them): `level_from: 1` for a level-1 event already at level 1",
        factory=dict,
    )


DEFAULT_SNAPSHOT_TRIGGERS = (
    SnapshotTrigger(kind="emergency_stop"),
    SnapshotTrigger(kind="mode_change", where={"from": "AUTOMATIC", "to": "MANUAL"}),  # a manual takeover
    SnapshotTrigger(kind="awareness", where={"level_to": 1}, unless={"level_from": 1}),  # entering level 1
    SnapshotTrigger(kind="controller_switch", where={"to": "stop"}),
    SnapshotTrigger(kind="collision"),  # the simulator's: the body touched an obstacle
)


class SnapshotSettings(Params):
    """Incident snapshots: the last seconds of the whole bus kept in memory, saved with the seconds
    after when something happens (docs/recording.md)."""

    enabled: bool = param(False, "keep the ring and save snapshots (`ares run`'s process)")
    before_s: float = param(20.0, "stack seconds kept before the event", unit="s", gt=0)
    after_s: float = param(10.0, "stack seconds saved after it", unit="s", ge=0)
    max_ring_mb: float = param(
        800.0, "the ring's bound in memory (three full LiDARs: ~24 MB a second); beyond, the oldest go", unit="MB", gt=0
    )
    dir: str | None = param(None, "where snapshots are kept (null: `snapshots/` beside the black box's store)")
    retention_days: float = param(7.0, "kept as long as the black box keeps its records", unit="d", gt=0)
    triggers: list[SnapshotTrigger] = param(
        doc="the events that save one; an operator's `ares snapshot` always does",
        factory=lambda: [t.model_copy() for t in DEFAULT_SNAPSHOT_TRIGGERS],
    )


class RecordingSettings(Params):
    """What `ares run` records of its bus (docs/recording.md)."""

    profile: Literal["full", "light"] = param(
        "full", "what `--record` keeps: full (every message) or light (decimated per topic, no clouds)"
    )
    light_always: bool = param(
        False, "every run writes the light log (bus-light.mcap in its folder), with or without `--record`"
    )
    cloud_encoding: Literal["grid", "float32"] = param(
        "grid", "clouds as integers on the sensor's grid (exact, 1.8 B a point) or as they travelled (17 B)"
    )
    driver_lidar: Literal["packets", "clouds", "both"] = param(
        "packets",
        "with the Velodyne driver: each LiDAR's packets as received (the driver publishes them; a replay "
        "rebuilds the clouds through its decoder), its clouds (on the calibration's grid), or both (to check "
        "the decoder's replay: `ares replay FILE --node lidar_driver`)",
    )
    cloud_view_every_s: float = param(
        1.0,
        "a full recording's Foxglove preview of each LiDAR (foxglove.PointCloud) this often; 0: none "
        "(every sweep stays in the raw channel, exact)",
        unit="s",
        ge=0,
    )
    cloud_view_stride: int = param(4, "... with every n-th point of the sweep", ge=1)
    views_max_hz: float = param(
        10.0,
        "the other Foxglove views (pose, frames, plan, grid) at most this often per topic; 0: one per message "
        "(the raw channels keep every message whatever this is)",
        unit="Hz",
        ge=0,
    )
    snapshots: SnapshotSettings = param(doc="incident snapshots", factory=SnapshotSettings)
    light_rates_hz: dict[str, float] = param(
        doc="the light profile's topics (patterns allowed) and the most it keeps of each per second (0: every "
        "message); a topic not named is not kept",
        factory=lambda: dict(LIGHT_RATES_HZ),
    )


class CpuSettings(Params):
    """Which CPUs (Linux's numbering) each part of a run may use; null: any. A way to give the
    vehicle's own processes one computer's share of a bigger machine, with the simulated shuttle
    beside it (`ares run --vehicle-cpus`, ares.core.affinity)."""

    vehicle: list[int] | None = param(
        None, "the vehicle's own processes: every process of the table but the simulator's (sim_only)"
    )
    simulator: list[int] | None = param(None, "the simulated shuttle and its LiDARs (the sim_only processes)")
    host: list[int] | None = param(
        None, "`ares run`'s own process: the supervisor, the embedded router, a headless run's measurements"
    )

    @model_validator(mode="after")
    def _cpu_numbers(self) -> CpuSettings:
        for part in ("vehicle", "simulator", "host"):
            cpus = getattr(self, part)
            if cpus is not None and (not cpus or min(cpus) < 0):
                raise ValueError(f"cpus.{part}: give CPU numbers (0, 1, ...), or null for any")
        return self


class UtmOrigin(Params):
    """The local frame's origin in UTM: x east, y north, z above the origin's altitude."""

    zone: int = param(30, "UTM zone", ge=1, le=60)
    hemisphere: Literal["N", "S"] = param("N", "hemisphere")
    easting: float = param(440000.0, "easting of the origin", unit="m")
    northing: float = param(4474000.0, "northing of the origin", unit="m")
    altitude_m: float = param(650.0, "altitude of the origin above mean sea level", unit="m")
    reach_km: float = param(
        100.0,
        "positions farther than this from the origin are refused (a wrong fix or a "
        "wrong configuration); nearer ones are projected in the origin's zone, even "
        "across a zone boundary",
        unit="km",
        gt=0,
    )


class CoreConfig(Params):
    vehicle_id: str = param(
        "shuttle01",
        "this shuttle's id in every bus key (ares/<vehicle_id>/...); one per "
        "vehicle so that a fleet shares one Zenoh network",
        pattern=VEHICLE_ID_PATTERN,
    )
    vehicle: str = param("ares_shuttle", "vehicle profile: a name in ares/core/config/vehicles/ or a YAML file")
    tour: str = param("default", "built-in tour: a name in ares/core/config/tours/ or a YAML file")
    route_file: str | None = param(None, "an open route (CSV of x,y[,z] metres) driven instead of the tour")
    scenario: str | None = param(None, "simulated obstacles and faults: a name in simulator/scenarios/ or a YAML file")
    simulate: bool = param(True, "run the simulated shuttle (the `sim` process) with the stack")
    wire: bool = param(
        False,
        "simulation behind the wire formats (`ares run --wire`): the simulator writes NMEA, Velodyne "
        "packets and CAN frames to `vehicle_io`'s devices and the drivers read them",
    )
    vehicle_io: VehicleIo = param(doc="the vehicle's devices, read by the drivers", factory=VehicleIo)
    lidars: bool = param(
        True,
        "run the LiDARs and LiDAR perception (off: the stack drives on GNSS and odometry "
        "alone, as the tests that are not about perception do, to save time)",
    )
    origin_utm: UtmOrigin = param(doc="origin of the local frame", factory=UtmOrigin)
    bus: BusSettings = param(doc="the Zenoh bus", factory=BusSettings)
    commands: CommandSettings = param(doc="the operator's signed commands", factory=CommandSettings)
    heartbeat: HeartbeatSettings = param(doc="process heartbeats", factory=HeartbeatSettings)
    lockstep: LockstepSettings = param(doc="the simulator-driven clock of `--speed max`", factory=LockstepSettings)
    replay: ReplaySettings = param(doc="process replay recordings", factory=ReplaySettings)
    recording: RecordingSettings = param(
        doc="the bus recorded to MCAP (`ares run --record`)", factory=RecordingSettings
    )
    cpus: CpuSettings = param(doc="which CPUs each part of a run may use", factory=CpuSettings)
    vehicle_profile: VehicleProfile | None = param(
        None, "the profile named by `vehicle`, resolved by `ares run`; its fields may be overridden here"
    )


CORE_SECTIONS = tuple(CoreConfig.model_fields)


COMMAND_LINE = "the command line"


def build(
    model: type[CoreConfig], files: tuple[str | Path, ...] = (), overrides: Mapping[str, Any] | None = None
) -> dict[str, Any]:
    """The run configuration as a JSON-ready dict: the model's defaults, each file, then `overrides`
    (the command line's choices), each layer validated on its own so that an error names it; the
    vehicle profile resolved into `vehicle_profile`, with any of its fields overridden there."""
    layers = [(str(path), load_yaml(path)) for path in files]
    if overrides:
        layers.append((COMMAND_LINE, dict(overrides)))
    data: dict[str, Any] = {}
    profile_overrides: dict[str, Any] = {}
    set_by: dict[str, str] = {}  # profile field -> the layer that last overrode it
    for source, content in layers:
        content = _empty_sections_as_mappings(model, content)
        validated(model, _without_profile(content), source)
        data = deep_merge(data, _without_profile(content))
        changes = _profile_overrides(content, source)
        profile_overrides = deep_merge(profile_overrides, changes)
        set_by.update(dict.fromkeys(changes, source))
    cfg = validated(model, data, " + ".join(source for source, _ in layers) or "the defaults")
    out = cfg.model_dump(mode="json")
    out["vehicle_profile"] = _profile(cfg.vehicle, profile_overrides, set_by).model_dump(mode="json")
    return out


def _profile(vehicle: str, overrides: dict[str, Any], set_by: dict[str, str]) -> VehicleProfile:
    """The named profile with its overrides; an error names the layer that set the field."""
    path = named_file("vehicles", vehicle)
    try:
        return VehicleProfile.model_validate(deep_merge(load_yaml(path), overrides))
    except ValidationError as exc:
        by_source: dict[str, list[str]] = {}
        for err in exc.errors(include_url=False):
            overridden = str(err["loc"][0]) in set_by if err["loc"] else False
            source = set_by[str(err["loc"][0])] if overridden else str(path)
            prefix = "vehicle_profile." if overridden else ""
            by_source.setdefault(source, []).append(error_line(VehicleProfile, err, prefix))
        raise ConfigError("\n".join(sentence(source, lines) for source, lines in by_source.items())) from None


def _profile_overrides(content: Mapping[str, Any], source: str) -> dict[str, Any]:
    overrides = content.get("vehicle_profile")
    if overrides is None:
        return {}
    if not isinstance(overrides, Mapping):
        raise ConfigError(
            f"{source}: vehicle_profile: expected a mapping of profile fields to override, "
            f"got {type(overrides).__name__}"
        )
    return dict(overrides)


def _empty_sections_as_mappings(model: type[BaseModel], content: Mapping[str, Any]) -> dict[str, Any]:
    """`section:` with nothing under it (YAML null) means the section's defaults."""

    def is_section(name: str) -> bool:
        field = model.model_fields.get(name)
        return field is not None and isinstance(field.annotation, type) and issubclass(field.annotation, BaseModel)

    return {k: ({} if v is None and is_section(k) else v) for k, v in content.items()}


def _without_profile(data: Mapping[str, Any]) -> dict[str, Any]:
    """A configuration without its vehicle_profile overrides: those are single fields, validated
    once merged into the named profile."""
    return {k: v for k, v in data.items() if k != "vehicle_profile"}


def core_defaults() -> dict[str, Any]:
    """Only the core sections, for a process started without a run configuration."""
    return build(CoreConfig)


def write_run_config(cfg: Mapping[str, Any], path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(cfg, indent=1))
    return path


def current() -> dict[str, Any]:
    """The run's configuration in a child process (ARES_RUN_CONFIG), else the core defaults."""
    path = os.environ.get(RUN_CONFIG_ENV)
    if path:
        try:
            cfg: dict[str, Any] = json.loads(Path(path).read_text())  # as write_run_config wrote it
            return cfg
        except (OSError, ValueError) as exc:
            raise ConfigError(f"{RUN_CONFIG_ENV}={path}: cannot read the run configuration: {exc}") from None
    return core_defaults()


def core(cfg: Mapping[str, Any]) -> CoreConfig:
    """The core sections of a run configuration, typed (the named vehicle's profile if it has none)."""
    typed = validated(CoreConfig, {k: cfg[k] for k in CORE_SECTIONS if k in cfg}, "the run configuration")
    if typed.vehicle_profile is None:
        typed = typed.model_copy(update={"vehicle_profile": load_vehicle(typed.vehicle)})
    return typed


def section(cfg: Mapping[str, Any], name: str, model: type[Section]) -> Section:
    """One section of a run configuration, typed (its defaults where the section is absent)."""
    return validated(model, cfg.get(name) or {}, f"the run configuration, section {name!r}")
