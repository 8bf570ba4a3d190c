"""`ares sim serve`: the simulated shuttle alone, behind its wires, for a stack run as on a vehicle.

A bench test of the vehicle's own configuration: the simulator (and its LiDARs) write NMEA to a
pseudo-terminal, Velodyne packets to UDP ports and CAN frames to a udp_multicast group, on the wall
clock, and nothing else runs. Beside it, `ares run --config vehicle.yaml` with `simulate: false`
and `--vehicle-io DIR/vehicle_io.yaml` reads them through its drivers, exactly as it would read a
shuttle's devices. Two files go into the wires' folder:

- `vehicle_io.yaml`: the devices, for `ares run --vehicle-io`;
- `clock.env`: the simulator's wall clock (its epoch), for the vehicle's run to share
  (`env $(cat DIR/clock.env) ares run ...`), so that the simulator's truth and the stack's
  messages are on one timeline and a headless run's figures compare them.

The simulator's supervisor runs its processes but does not publish supervisor/state: on the
vehicle's bus (the same router and vehicle id, so that sim/truth and the simulated driver's
service reach the vehicle's run) only the vehicle's supervisor speaks for the vehicle's processes.
"""

from __future__ import annotations

import threading
from pathlib import Path

import yaml

from ares.app import processes
from ares.app.stack import prepare
from ares.app.supervisor import Supervisor, serve_until_stopped
from ares.core import config
from ares.core.clock import SPEED_ENV, WallClock


def sim_config(files: tuple[str, ...], overrides: dict, wire_dir: Path) -> dict:
    """As `ares run --wire` prepares its run (the route file's origin, the scenario, the wires)."""
    return prepare(files, config.deep_merge(overrides, {"simulate": True, "wire": True}), 1.0, wire_dir=wire_dir)


def serve(cfg: dict, wire_dir: Path, run_dir: Path, stop: threading.Event | None = None) -> int:
    wire_dir.mkdir(parents=True, exist_ok=True)
    clock = WallClock()
    devices = {k: v for k, v in cfg["vehicle_io"].items() if v}
    (wire_dir / "vehicle_io.yaml").write_text(
        "# the simulator's wires (ares sim serve): ares run --vehicle-io this file\n" + yaml.safe_dump(devices)
    )
    (wire_dir / "clock.env").write_text("".join(f"{k}={v}\n" for k, v in clock.env().items() if k != SPEED_ENV))
    simulators = [p for p in processes.for_run(True, cfg["lidars"], wire=True) if p.sim_only]
    return serve_until_stopped(
        Supervisor(cfg, simulators, run_dir, clock, publishes_state=False),
        f"simulated shuttle {cfg['vehicle_id']} behind its wires on {cfg['bus']['router']}: "
        f"{', '.join(p.name for p in simulators)}; devices in {wire_dir / 'vehicle_io.yaml'}, "
        f"its clock in {wire_dir / 'clock.env'} (logs in {run_dir / 'logs'})",
        stop,
    )
