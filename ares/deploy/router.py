"""A router from a deployment's JSON5 file, run by eclipse-zenoh in router mode: the tests and the
rehearsal run the files zenohd would (zenohd itself cannot be installed on these machines).

`localize` points a file's secrets at a folder (instead of compose's /run/secrets) and, when
asked, its endpoints at other addresses; nothing else of the file changes.
"""

from __future__ import annotations

import copy
import json
import signal
import sys
import threading
import time
from pathlib import Path
from typing import Any

from ares.deploy.refusals import Refusal, RefusalReader
from ares.deploy.router_config import SECRETS


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


def serve(cfg: dict[str, Any], stop: threading.Event | None = None, report_refusals_as: str | None = None) -> None:
    """Run a router until SIGTERM/SIGINT (or `stop`): `ares deploy router`. `report_refusals_as`:
    the fleet's id, under which access-control refusals are published as events (refusals.py)."""
    stop = stop or threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    say = print
    session: Any = None
    if report_refusals_as is not None:
        reader = RefusalReader(lambda refusal: _publish_refusal(session, report_refusals_as, refusal))
        reader.install()
        say = reader.print
    else:
        import zenoh

        zenoh.init_log_from_env_or("warn")  # as zenohd: RUST_LOG says more
    session = open_router(cfg)
    try:
        say(json.dumps({"router": str(session.info.zid()), "listen": cfg.get("listen", {}).get("endpoints")}))
        sys.stdout.flush()
        stop.wait()
    finally:
        session.close()


def _publish_refusal(session: Any, fleet_id: str, refusal: Refusal) -> None:
    import zenoh

    from ares.core.bus import encoding_name
    from ares.core.messages import Event, EventLevel
    from ares.core.schema import encode

    if session is None:
        return
    event = Event(
        t=time.time(),
        source="fleet_router",
        kind="acl_refused",
        level=EventLevel.WARNING,
        message=refusal.message(),
        data={"vehicle": refusal.who, "under": refusal.under, "action": refusal.action, "key": refusal.key},
    )
    session.put(f"ares/{fleet_id}/events", bytes(encode(event)), encoding=zenoh.Encoding(encoding_name(Event)))
