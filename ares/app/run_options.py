"""One run of the whole stack as values: what it may choose (`RunOptions`, everything the `ares run`
command line can say), what a headless drive is given while it runs (`RunningStack`) and what it
gives back (`RunResult`). ares.app.stack.run takes the options and returns the result; the command
line, the benches, the soak and `ares compare` build the options themselves."""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from ares.core import affinity, config

if TYPE_CHECKING:
    from ares.app.supervisor import Supervisor
    from ares.core.bus import Bus
    from ares.core.clock import Clock
    from ares.core.route import Route

# the clock: a factor (simulated seconds per wall second, each process on its own timers), `max`
# (the simulator drives the clock, as fast as every process keeps up) or `paced` (the same, never
# faster than real time)
Speed = Annotated[float, Field(gt=0, allow_inf_nan=False)] | Literal["max", "paced"]
LOCKSTEP_SPEEDS = ("max", "paced")


class RunOptions(BaseModel):
    """What a run chooses over its configuration files: the `ares run` command line's options,
    typed. None leaves the choice to the configuration (or to the run, for `speed`: see
    ares.app.stack.resolved_speed)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    config_files: tuple[str, ...] = ()  # YAML overrides, later files win
    settings: dict[str, Any] = Field(default_factory=dict)  # keys no option names, as a config file gives them
    headless: bool = False  # unattended: engage, drive `laps` or `seconds`, measure
    manual: bool = False  # interactive, not engaged: the sim/driver service drives
    laps: Annotated[int, Field(gt=0)] | None = None
    seconds: Annotated[float, Field(gt=0, allow_inf_nan=False)] | None = None
    speed: Speed | None = None
    route: str | None = None  # a built-in tour's name, a tour's YAML or a route CSV
    scenario: str | None = None  # a built-in scenario's name or a scenario file
    mission: Literal["tour", "drive", "none"] | None = None
    controller: Literal["auto", "mpc", "rrc", "pure_pursuit", "stanley"] | None = None
    wire: bool = False  # the simulator behind the devices' wire formats
    vehicle_io: str | None = None  # the vehicle's devices: a YAML file of the vehicle_io section
    vehicle: str | None = None
    passengers: Annotated[int, Field(ge=0)] | None = None
    vehicle_id: str | None = None
    router: str | None = None  # an external router to join (no embedded one)
    listen: str | None = None  # where the embedded router listens
    vehicle_cpus: tuple[int, ...] | None = None  # the vehicle's processes here, the rest on the others
    run_dir: Path | None = None  # default: runs/<time> (ARES_RUNS_DIR)
    api_port: int | None = None
    store: str | None = None  # the black box store's URI or file
    fleet: Annotated[int, Field(gt=0)] = 1  # shuttles on one router (interactive)
    record: str | None = None  # the bus to MCAP: "" is bus.mcap in the run folder
    foxglove: str | None = None  # [HOST:]PORT to serve the live bus to Foxglove; "" its default

    def overrides(self) -> dict:
        """The configuration the options set, over the files: `settings`, then each option given."""
        over: dict = {"sim": {}, "bus": {}, "blackbox_store": {}}
        if self.vehicle:
            over["vehicle"] = self.vehicle
        if self.vehicle_id:
            over["vehicle_id"] = self.vehicle_id
        if self.passengers is not None:
            over["sim"]["passengers"] = self.passengers
        if self.route:
            over.update(route_overrides(self.route))
        if self.scenario:
            over["scenario"] = self.scenario
        if self.wire:
            over["wire"] = True
        if self.vehicle_io:
            from ares.app import vehicle_io  # reads the file: only a run that names one

            over["vehicle_io"] = vehicle_io.load(self.vehicle_io)
        if self.mission:
            over["mission_manager"] = {"autostart": self.mission}
        if self.controller:
            over["control_manager"] = {"pinned": None if self.controller == "auto" else self.controller}
        if self.listen:
            over["bus"]["router"] = self.listen
        if self.router:
            over["bus"]["router"] = self.router
            over["bus"]["embedded_router"] = False
        if self.store:
            over["blackbox_store"]["uri"] = self.store
        if self.vehicle_cpus:
            rest = sorted(affinity.available() - set(self.vehicle_cpus)) or None  # one CPU: all share it
            over["cpus"] = {"vehicle": list(self.vehicle_cpus), "simulator": rest, "host": rest}
        if self.api_port:
            over["api"] = {"port": self.api_port}
        return config.deep_merge(self.settings, over)


def route_overrides(route: str) -> dict:
    """A built-in tour by name (`campus`) or a tour's YAML is the `tour`; anything else a route CSV."""
    builtin = config.packaged_file("tours", route).exists() and not Path(route).exists()
    if builtin:
        return {"tour": route}
    if Path(route).suffix in (".yaml", ".yml"):
        return {"tour": str(Path(route).resolve())}
    return {"route_file": str(Path(route).resolve())}


@dataclass(frozen=True)
class RunResult:
    """How a run ended. `refused`: it never started (the configuration, the command line or a tap
    such as --record said no), `error` says why; otherwise `ok` unless the drive failed or was
    interrupted. A headless run's `figures` are the drive's (up to the failure, for a failed one);
    `blackbox_records` and `recording` are counted once the stack has stopped."""

    ok: bool
    run_dir: Path
    error: str | None = None
    refused: bool = False
    interrupted: bool = False  # stopped by SIGINT or SIGTERM
    logs: Path | None = None  # where the run's processes logged
    figures: dict[str, Any] = field(default_factory=dict)
    blackbox_records: int | None = None  # records the store holds for the run (None: it could not say)
    # the recorder's last status (blackbox/status, after its final flush) and `in_store`, the count above
    blackbox: dict[str, Any] | None = None
    recording: dict[str, Any] | None = None  # the MCAP file's figures (--record)

    @property
    def exit_code(self) -> int:
        """`ares run`'s: 0 done, 1 failed, 2 refused."""
        return 0 if self.ok else 2 if self.refused else 1

    def summary(self) -> dict[str, Any]:
        """The JSON object a headless `ares run` prints as its last line (other tools and the docs
        read it): ok, the error of a failed run, the run folder and the figures; a finished run's
        black box count and recording."""
        head: dict[str, Any] = {"ok": self.ok, **({"error": self.error} if self.error is not None else {})}
        line = {**head, "run_dir": str(self.run_dir), **self.figures}
        if self.ok:
            line["blackbox_records"] = self.blackbox_records
            if self.blackbox is not None:
                line["blackbox"] = self.blackbox
            if self.recording:
                line["recording"] = self.recording
        return line


@dataclass(frozen=True)
class RunningStack:
    """What a headless drive is given: the run's options and validated configuration, its route,
    the supervisor (its bus; `inject` for process faults; its children), the stack's clock, the
    run's stop (Ctrl-C sets it) and folder."""

    options: RunOptions
    cfg: dict[str, Any]
    route: Route
    supervisor: Supervisor
    clock: Clock
    stop: threading.Event
    run_dir: Path

    @property
    def bus(self) -> Bus:
        return self.supervisor.bus


# a headless drive: the running stack -> its figures (RunFailed, with the figures so far, if it fails)
HeadlessDrive = Callable[[RunningStack], dict[str, Any]]
