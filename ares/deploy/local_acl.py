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
after its first samples (2 of 40 delivered; all 40 with it), and a declaration whose key is wider
than the rule's (the supervisor's `heartbeat/*` against `heartbeat/api`) does not pass it: a whole
stack's heartbeats stopped after their first. So every subscriber's declaration flows toward every
process (SUBSCRIBERS_DECLARED: nothing to read, no right to put), beside the samples of its
inputs, the queries of its services and the replies of its calls. The supervisor watches every process's
liveliness token (`alive/*`: its liveliness subscriber and query in, the tokens out).

router_config.vehicle_router makes the vehicle router's access control from these rules, one
subject per user; pki.issue_vehicle gives each user its password (`zenoh_local_users`, which the
stack reads as bus.credentials_file), and `ares deploy rehearse` shows a process refused a key
outside its contract (`local_acl_refused`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from ares.app import contracts, supervisor
from ares.app.processes import PROCESSES
from ares.core.node import IMPLICIT_OUTPUTS
from ares.deploy.pki import OBSERVER  # `ares topics` / `ares echo` on the vehicle's computer: it reads only

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
    sup["call"] |= set(SUPERVISOR_DRIVE_CALLS)
    sup["alive"].add(contracts.SUPERVISOR)
    return allowed


def fleet_inputs(cfg: Mapping[str, Any]) -> dict[str, set[str]]:
    """process -> the topics it reads from every vehicle (`ares/*/<topic>` either way on a vehicle)."""
    out: dict[str, set[str]] = {}
    for c in contracts.all_contracts(cfg, PROCESSES):
        out.setdefault(c["process"], set()).update(c["fleet_inputs"])
    return out


# what flows toward a process, by kind of its rights: samples of what it subscribes to, the
# queries of its services, the replies of its calls
EGRESS = {
    "subscribe": ["put", "delete"],
    "serve": ["query"],
    "call": ["reply"],
}
SUBSCRIBERS_DECLARED = "subscribers_declared"
# `ares run`'s drive, in the supervisor's session: it starts the simulated driver and automatic mode
SUPERVISOR_DRIVE_CALLS = ("sim/driver", "set_automatic_mode")
# ...and its taps: `--record` and `--foxglove` subscribe to every key, its report reads sim/truth,
# dbw/car_state, mission/status and blackbox/status. The supervisor may read everything: it starts
# and stops every process, so reading their data gives it nothing it does not already hold, and a
# tap's list of keys would change with every contract; what it may put and call stays exact
SUPERVISOR_READS = "**"
WATCH_ALIVE = "alive/*"  # the supervisor's liveliness subscriber and query (bus.watch_alive, alive())


def _rule(rule_id: str, messages: list[str], flow: str, keys: list[str]) -> dict[str, Any]:
    return {"id": rule_id, "permission": "allow", "messages": messages, "flows": [flow], "key_exprs": keys}


def rules(cfg: Mapping[str, Any]) -> list[dict[str, Any]]:
    """One ingress rule per process and kind of message, with the keys its contract allows, and
    one egress rule per process and kind for what flows back to it (EGRESS)."""
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
            out.append(_rule(f"{process}_{kind}", messages[kind], "ingress", keys))
            if kind in EGRESS:
                out.append(_rule(f"{process}_{kind}_back", EGRESS[kind], "egress", keys))
    watch = [_key(WATCH_ALIVE)]
    sup = contracts.SUPERVISOR
    out.append(_rule(f"{sup}_watch", ["declare_liveliness_subscriber", "liveliness_query"], "ingress", watch))
    out.append(_rule(f"{sup}_watch_back", ["liveliness_token"], "egress", watch))
    taps = [_key(SUPERVISOR_READS)]
    out.append(_rule(f"{sup}_tap", ["declare_subscriber"], "ingress", taps))
    out.append(_rule(f"{sup}_tap_back", ["put", "delete"], "egress", taps))
    out.append(_rule(f"{OBSERVER}_tap", ["declare_subscriber"], "ingress", taps))
    out.append(_rule(f"{OBSERVER}_tap_back", ["put", "delete"], "egress", taps))
    # `ares topics` lists the processes alive beside the keys: it may watch the tokens too
    out.append(_rule(f"{OBSERVER}_watch", ["declare_liveliness_subscriber", "liveliness_query"], "ingress", watch))
    out.append(_rule(f"{OBSERVER}_watch_back", ["liveliness_token"], "egress", watch))
    # toward every process, the subscribers' declarations of every key: a client publisher not told
    # of its subscribers stops sending, and a subscriber's key may be wider than any process's
    # output (the supervisor's heartbeat/*, a tap's **: the router checks a declaration against the
    # rule's key as a whole, so `heartbeat/api` would not pass heartbeat/*). A declaration gives a
    # process nothing to read and no right to put
    out.append(_rule(SUBSCRIBERS_DECLARED, ["declare_subscriber"], "egress", [_key("**")]))
    return out


def rule_ids(cfg: Mapping[str, Any]) -> dict[str, list[str]]:
    """process -> the ids of its rules, for its policy (its subject: its user name)."""
    suffixes = [*KINDS, *(f"{kind}_back" for kind in EGRESS), "watch", "watch_back", "tap", "tap_back"]
    every = {r["id"] for r in rules(cfg)}
    users = [*allowed_topics(cfg), OBSERVER]
    return {p: [*(f"{p}_{s}" for s in suffixes if f"{p}_{s}" in every), SUBSCRIBERS_DECLARED] for p in users}
