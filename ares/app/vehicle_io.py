"""The vehicle's devices for a run: the simulator's own wires (`--wire`), a user's file
(`--vehicle-io FILE`), and the refusal of a vehicle run whose nodes would wait for inputs no
driver publishes.

A driver publishes only what its configured devices give: the GNSS driver `sensors/gnss` once
`vehicle_io.gnss` names a receiver, the CAN driver the vehicle's frames once `vehicle_io.can` names
a bus, the LiDAR driver `lidar/<name>/points` for each LiDAR in `vehicle_io.lidars`. A run on the
vehicle (`simulate: false`) starts only when every input a running node reads has a publisher.
"""

from __future__ import annotations

import random
import socket
from pathlib import Path
from typing import Any

from ares.app import contracts, processes
from ares.core import config, topics
from ares.core.config import VehicleIo
from ares.core.localhost import free_port

MODEL_OF_MOUNT = {"vlp16": "VLP-16", "hdl64e": "HDL-64E"}
# the inputs each driver can publish, and the key of vehicle_io that enables them
DRIVER_DEVICES = {"gnss_driver": "gnss", "can_driver": "can", "lidar_driver": "lidars", "ntrip_client": "ntrip"}


def load(path: str | Path) -> dict[str, Any]:
    """A `--vehicle-io` file: the `vehicle_io` section alone (gnss, lidars, can), validated."""
    data = config.load_yaml(path)
    if set(data) == {"vehicle_io"}:  # a run configuration's section pasted whole
        data = data["vehicle_io"] or {}
    return config.validated(VehicleIo, data, str(path)).model_dump()


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def simulator_wires(cfg: dict[str, Any], wire_dir: Path) -> dict[str, Any]:
    """`--wire`: devices where the simulator writes, private to this run: a pseudo-terminal linked
    in the run directory, a CAN group and port of its own, a loopback UDP port per LiDAR, and the
    NTRIP caster behind the simulated 4G link (a port, a mount point and a password of its own)."""
    profile = config.core(cfg).vehicle_profile
    rng = random.SystemRandom()
    return {
        "ntrip": {
            "host": "127.0.0.1",
            "port": free_port(),
            "mountpoint": "ARES_BASE",
            "user": "shuttle",
            "password": f"{rng.getrandbits(64):016x}",
            "version": 2,
            # the link's silence is judged on the wall clock: a simulation slower than real time
            # sends its base station's second less often than a second of the wall
            "silent_after_s": 10.0,
        },
        "gnss": {"source": "serial", "device": str((wire_dir / "gnss.tty").resolve()), "baud": 115200},
        "can": {
            "interface": "udp_multicast",
            # a group and port of its own: two runs on one machine do not hear each other
            "channel": f"239.{rng.randint(0, 255)}.{rng.randint(0, 255)}.{rng.randint(1, 254)}",
            "port": _free_udp_port(),
        },
        "lidars": {
            name: {"model": MODEL_OF_MOUNT[mount.model], "address": "127.0.0.1", "port": _free_udp_port()}
            for name, mount in profile.lidars.items()
            if cfg["lidars"]
        },
    }


def driver_topics(cfg: dict[str, Any]) -> dict[str, tuple[str, bool]]:
    """topic -> (the vehicle_io key of the device that gives it, whether that device is configured),
    for every topic the run's drivers can publish."""
    io = config.core(cfg).vehicle_io
    found: dict[str, tuple[str, bool]] = {}
    for spec in processes.for_config(cfg):
        key = DRIVER_DEVICES.get(spec.name)
        for out in spec.node_class().outputs() if key else ():
            if out.topic == "drivers/status":
                continue
            if key == "lidars":
                name = out.topic.split("/")[1]
                found[out.topic] = (f"vehicle_io.lidars.{name}", name in io.lidars)
            else:
                found[out.topic] = (f"vehicle_io.{key}", getattr(io, key) is not None)
    return found


def missing_inputs(cfg: dict[str, Any]) -> list[str]:
    """Inputs of the vehicle's running nodes that nobody would publish, each with the device that
    would give it: "sensors/gnss (read by gnss; needs vehicle_io.gnss)"."""
    devices = driver_topics(cfg)
    graph = contracts.graph(contracts.all_contracts(cfg, processes.for_config(cfg)))
    missing = []
    for topic, ends in graph.items():
        entry = topics.find(topic)
        if entry is not None and entry.optional:  # an optional device's: its readers do without it
            continue
        device, configured = devices.get(topic, ("", True))
        readers = sorted(set(ends["subscribers"]))
        if not configured and readers:
            missing.append(f"{topic} (read by {', '.join(readers)}; needs {device})")
    return missing
