"""`ares fleet serve`: the fleet server's processes under one supervisor (deploy/fleet).

The fleet server joins the fleet router (its own plain-TCP port, user `fleet`: bus.router,
bus.user, bus.password_file) under its own id (`fleet`, so its heartbeats and events live under
`ares/fleet/**`), and runs the processes of processes.FLEET_SERVER: `fleet_sync` (every vehicle's
black box into the fleet's store) and `fleet_api` (the REST API and the pages over that store,
with the live view of every vehicle on the router). On the wall clock, until SIGINT/SIGTERM.
"""

from __future__ import annotations

import threading
from pathlib import Path

from ares.app import processes, run_config
from ares.app.supervisor import Supervisor, serve_until_stopped
from ares.core import config
from ares.core.clock import WallClock
from blackbox.register.recorder import store_uri
from blackbox.register.store.record_store import StoreSettings

FLEET_ID = "fleet"


def fleet_config(files: tuple[str, ...], overrides: dict) -> dict:
    """The fleet server's run configuration: the stack's format, its own id, the store absolute."""
    cfg = run_config.build(files, config.deep_merge({"vehicle_id": FLEET_ID, "simulate": False}, overrides))
    cfg["blackbox_store"]["uri"] = store_uri(config.section(cfg, "blackbox_store", StoreSettings))
    return cfg


def serve(cfg: dict, run_dir: Path, stop: threading.Event | None = None) -> int:
    """Run the fleet server's processes until `stop` (or a signal); 0 on a clean stop."""
    return serve_until_stopped(
        Supervisor(cfg, processes.FLEET_SERVER, run_dir, WallClock()),
        f"fleet server {cfg['vehicle_id']} on {cfg['bus']['router']}: "
        f"{', '.join(p.name for p in processes.FLEET_SERVER)} (logs in {run_dir / 'logs'})",
        stop,
    )
