"""The vehicle router's access control for its own processes, made from their contracts (issue 42
item 6): each process, logged in as its own user (its process name), may put exactly its declared
outputs and the outputs every node has (events, its own heartbeat, clock/done), subscribe to its
inputs (its fleet inputs under every vehicle's id), serve and answer its services, call the
services it declares, and hold its own liveliness token. Nothing else: a key no contract declares
is allowed to no one. The supervisor (not a node) gets what ares/app/supervisor.py declares.

Keys are `ares/*/<topic>`: the template serves every vehicle, and the fleet router admits a
vehicle's data only under its own id (router_config.fleet_router).

Measured with eclipse-zenoh 1.x in router mode (default deny, usernames as subjects): a client
publisher that is not sent the subscribers' declarations (egress declare_subscriber) stops sending
after its first samples (2 of 40 delivered; all 40 with it), so the egress rules still to be
written must pass declarations toward a publisher, as well as the samples toward a subscriber.

Not yet wired into router_config.vehicle_router, pki and the rehearsal (see docs/security.md).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from ares.app import contracts, supervisor
from ares.app.processes import PROCESSES
from ares.core.node import IMPLICIT_OUTPUTS

KINDS = ("put", "subscribe", "serve", "call", "alive")


def _key(topic: str) -> str:
    return f"ares/*/{topic}"


def allowed_topics(cfg: Mapping[str, Any]) -> dict[str, dict[str, set[str]]]:
    """process -> kind -> the topics (services for serve/call) its contract allows; the process
    table's variants of one name (the simulator's plain and wire ones) are one user, their union."""
    allowed: dict[str, dict[str, set[str]]] = {}
    for c in contracts.all_contracts(cfg, PROCESSES):
        own = allowed.setdefault(c["process"], {kind: set() for kind in KINDS})
        own["put"] |= {o["topic"] for o in c["outputs"]}
        own["put"] |= {t.replace("*", c["process"]) for t in IMPLICIT_OUTPUTS}
        own["subscribe"] |= {i["topic"] for i in c["inputs"]}
        own["subscribe"] |= {contracts.CLOCK_FOR_STEPPERS if c["steps"] else contracts.CLOCK_FOR_OTHERS}
        own["serve"] |= {s["name"] for s in c["services"]}
        own["call"] |= set(c["calls"])
        own["alive"].add(c["process"])
    sup = allowed.setdefault(contracts.SUPERVISOR, {kind: set() for kind in KINDS})
    sup["put"] |= set(supervisor.OUTPUTS)
    sup["subscribe"] |= set(supervisor.INPUTS)
    sup["serve"].add("supervisor/status")
    sup["alive"].add(contracts.SUPERVISOR)
    return allowed


def fleet_inputs(cfg: Mapping[str, Any]) -> dict[str, set[str]]:
    """process -> the topics it reads from every vehicle (`ares/*/<topic>` either way on a vehicle)."""
    out: dict[str, set[str]] = {}
    for c in contracts.all_contracts(cfg, PROCESSES):
        out.setdefault(c["process"], set()).update(c["fleet_inputs"])
    return out


def rules(cfg: Mapping[str, Any]) -> list[dict[str, Any]]:
    """One ingress rule per process and kind of message, with the keys its contract allows."""
    messages = {
        "put": ["put", "delete"],
        "subscribe": ["declare_subscriber"],
        "serve": ["declare_queryable", "reply"],
        "call": ["query"],
        "alive": ["liveliness_token"],
    }
    fleet = fleet_inputs(cfg)
    out: list[dict[str, Any]] = []
    for process, kinds in sorted(allowed_topics(cfg).items()):
        for kind in KINDS:
            topics = kinds[kind] | (fleet.get(process, set()) if kind == "subscribe" else set())
            if not topics:
                continue
            prefix = "srv/" if kind in ("serve", "call") else "alive/" if kind == "alive" else ""
            keys = sorted(_key(prefix + t) for t in topics)
            out.append(
                {"id": f"{process}_{kind}", "permission": "allow", "messages": messages[kind],
                 "flows": ["ingress"], "key_exprs": keys}
            )  # fmt: skip
    return out
