"""A router from a deployment's JSON5 file, run by eclipse-zenoh in router mode: the tests and the
rehearsal run the files zenohd would (zenohd itself cannot be installed on these machines).

`localize` points a file's secrets at a folder (instead of compose's /run/secrets) and, when
asked, its endpoints at other addresses; nothing else of the file changes.
"""

from __future__ import annotations

import copy
import json
import signal
import threading
from pathlib import Path
from typing import Any

from ares.tools.deploy.router_config import SECRETS


def localize(
    cfg: dict[str, Any],
    secrets_dir: Path | None = None,
    listen: list[str] | None = None,
    connect: list[str] | None = None,
) -> dict[str, Any]:
    out = copy.deepcopy(cfg)

    def walk(node: Any) -> Any:
        if isinstance(node, dict):
            return {k: walk(v) for k, v in node.items()}
        if isinstance(node, list):
            return [walk(v) for v in node]
        if secrets_dir is not None and isinstance(node, str) and node.startswith(SECRETS + "/"):
            return str(Path(secrets_dir) / node[len(SECRETS) + 1 :])
        return node

    out = walk(out)
    if listen is not None:
        out["listen"] = {**out.get("listen", {}), "endpoints": listen}
    if connect is not None:
        out["connect"] = {**out.get("connect", {}), "endpoints": connect}
    return out


def zenoh_config(cfg: dict[str, Any]) -> Any:
    import zenoh

    return zenoh.Config.from_json5(json.dumps(cfg))


def open_router(cfg: dict[str, Any]) -> Any:
    import zenoh

    return zenoh.open(zenoh_config(cfg))


def serve(cfg: dict[str, Any], stop: threading.Event | None = None) -> None:
    """Run a router until SIGTERM/SIGINT (or `stop`): `ares deploy router`."""
    stop = stop or threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    session = open_router(cfg)
    try:
        print(
            json.dumps({"router": str(session.info.zid()), "listen": cfg.get("listen", {}).get("endpoints")}),
            flush=True,
        )
        stop.wait()
    finally:
        session.close()
