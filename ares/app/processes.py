"""Every process of the stack, in one declarative table (started in this order).

Each entry names the node class it runs (`module:Class`, imported when first needed: `ares run`
reads the classes' contracts and parameters to validate the configuration, and each child process
imports its own class through `python -m ares.core.launch`); the class holds the process's
contract: its inputs, outputs with their rates, services and parameters (`ares describe`).
`safety_relevant` processes are the ones whose loss must bring the vehicle to a safe state;
`sim_only` ones run only in simulation; `lidars` ones only with the LiDARs (the core setting
`lidars`); `nice` lowers the CPU priority of those that must yield to the driving ones.
`wire` picks the simulator's variant: the plain one publishes its sensors on the bus, the wire one
(`ares run --wire`) writes them in the devices' formats (NMEA, Velodyne packets, CAN frames) for the
`driver` processes, which run on a vehicle (`simulate: false`) and in wire simulation.
The embedded Zenoh router is not listed: the supervisor hosts it in its own session.

Adding a manager is one file (its node class) and one line here.
"""

from __future__ import annotations

from dataclasses import dataclass

from ares.core.launch import load
from ares.core.node import Node


@dataclass(frozen=True)
class Process:
    name: str
    node: str  # "module:Class" of its ares.core.node.Node subclass
    safety_relevant: bool
    sim_only: bool = False
    lidars: bool = False  # runs only with the LiDARs (core `lidars`)
    nice: int = 0
    wire: bool | None = None  # the simulator's variants: True only with --wire, False only without
    driver: bool = False  # reads a device: on a vehicle and with --wire, never in plain simulation
    device: str | None = None  # runs only when this vehicle_io device is set (an optional one: ntrip)
    when_chosen: bool = False  # a controller that runs only when the control manager's configuration names it

    def node_class(self) -> type[Node]:
        return load(self.node)


PROCESSES: list[Process] = [
    Process("sim", "simulator.simulator_node:Simulator", safety_relevant=True, sim_only=True, wire=False),
    Process("sim", "simulator.wire_simulator_node:WireSimulator", safety_relevant=True, sim_only=True, wire=True),
    # the simulated LiDARs stand for hardware, whose work is not the vehicle computer's: they yield
    Process(
        "lidar_sim",
        "simulator.lidar_node:LidarSimulator",
        safety_relevant=True,
        sim_only=True,
        lidars=True,
        nice=5,
        wire=False,
    ),
    Process(
        "lidar_sim",
        "simulator.wire_lidar_node:WireLidarSimulator",
        safety_relevant=True,
        sim_only=True,
        lidars=True,
        nice=5,
        wire=True,
    ),
    # the devices' drivers publish what the simulator publishes in plain simulation
    Process("gnss_driver", "drivers.gnss_node:GnssDriver", safety_relevant=True, driver=True),
    Process("can_driver", "drivers.can_node:CanDriver", safety_relevant=True, driver=True),
    Process("lidar_driver", "drivers.velodyne_node:VelodyneDriver", safety_relevant=True, driver=True, lidars=True),
    # RTK corrections to the receiver: without them the shuttle drives on road reactive control, not unsafely
    Process("ntrip_client", "drivers.ntrip_node:NtripClientNode", safety_relevant=False, driver=True, device="ntrip"),
    Process("gnss", "perception.gnss_node:GnssNode", safety_relevant=True),
    Process("localization", "perception.localization_node:LocalizationNode", safety_relevant=True),
    Process("odometry_manager", "managers.odometry_node:OdometryManager", safety_relevant=True),
    Process("path_manager", "managers.path_node:PathManager", safety_relevant=True),
    Process("speed_manager", "managers.speed_node:SpeedManager", safety_relevant=True),
    Process("lidar_perception", "perception.lidar_perception_node:LidarPerception", safety_relevant=True, lidars=True),
    Process("dbw_bridge", "control.dbw_bridge_node:DbwBridge", safety_relevant=True),
    # every controller computes all the time; the control manager forwards one candidate to the bridge
    Process("mpc", "control.mpc_node:MpcNode", safety_relevant=True),
    Process("rrc", "control.rrc_node:RrcNode", safety_relevant=True, lidars=True),
    Process("pure_pursuit", "control.pure_pursuit_node:PurePursuitNode", safety_relevant=True),
    Process("stanley", "control.stanley_node:StanleyNode", safety_relevant=True, when_chosen=True),
    Process("control_manager", "managers.control_node:ControlManager", safety_relevant=True),
    # nothing moves unless every manager allows it: the gate is the bridge's only source of commands
    Process("obstacle_manager", "managers.obstacle_node:ObstacleManager", safety_relevant=True, lidars=True),
    Process("mission_manager", "managers.mission_node:MissionManager", safety_relevant=True),
    Process("awareness_manager", "managers.awareness_node:AwarenessManager", safety_relevant=True),
    Process("movement_manager", "managers.movement_node:MovementManager", safety_relevant=True),
    # the black box: losing it never stops the vehicle (the recorder spools; see blackbox/register/recorder.py)
    Process("blackbox", "blackbox.register.recorder_node:Recorder", safety_relevant=False, nice=5),
    Process("api", "blackbox.api.api_node:ApiServer", safety_relevant=False, nice=5),
]


# The fleet server's processes (deploy/fleet): every vehicle's black box into the fleet's store,
# and the API over it with the fleet's live view. Nothing here is safety relevant: a vehicle never
# waits on the fleet.
FLEET_SERVER: list[Process] = [
    Process("fleet_sync", "blackbox.fleet.sync_node:FleetSync", safety_relevant=False),
    Process("fleet_api", "blackbox.api.api_node:FleetApiServer", safety_relevant=False),
]


def by_name(name: str, wire: bool = False) -> Process:
    for spec in [*PROCESSES, *FLEET_SERVER]:
        if spec.name == name and spec.wire in (None, wire):
            return spec
    raise KeyError(f"unknown process {name!r}; known: {', '.join(p.name for p in [*PROCESSES, *FLEET_SERVER])}")


def for_run(
    simulate: bool,
    lidars: bool = True,
    wire: bool = False,
    devices: frozenset[str] | None = None,
    chosen: frozenset[str] | None = None,
) -> list[Process]:
    """The processes of a run: the simulator's plain or wire variant, and the drivers wherever
    devices are read (on a vehicle, or behind the simulator's wires); `devices`: the vehicle_io
    devices set, for the drivers of optional ones; `chosen`: the controllers the control manager's
    configuration names, for those that run only when chosen (None: as if all were)."""
    wire = wire and simulate
    return [
        p
        for p in PROCESSES
        if (simulate or not p.sim_only)
        and (lidars or not p.lidars)
        and p.wire in (None, wire)
        and (not p.driver or wire or not simulate)
        and (p.device is None or devices is None or p.device in devices)
        and (not p.when_chosen or chosen is None or p.name in chosen)
    ]


def for_config(cfg) -> list[Process]:  # type: ignore[no-untyped-def]
    io = cfg.get("vehicle_io") or {}
    devices = frozenset(key for key, value in io.items() if value)
    control = cfg.get("control_manager") or {}
    chosen = frozenset(str(c) for c in (control.get("odometry_controller"), control.get("pinned")) if c)
    return for_run(cfg["simulate"], cfg["lidars"], cfg["wire"], devices, chosen)
