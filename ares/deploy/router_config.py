"""The Zenoh routers' configurations: the fleet's and each vehicle's (docs/deploy.md).

The vehicle's router (mode router) listens on plain TCP for the vehicle's own processes, inside
the vehicle, and connects to the fleet router over TLS. The link between them is secured three
ways, each checked by the fleet router and the vehicle's router alike:

- mutual TLS: both present a certificate of the fleet's CA (ares/deploy/pki.py);
- Zenoh user/password: the vehicle's user is its id, checked against the fleet's dictionary;
- access control, default deny: a vehicle may publish, answer and declare liveliness only under
  `ares/<its id>/**` (its certificate's common name and its user must both be that id); the fleet
  may subscribe to every vehicle and call only the services of FLEET_SERVICES, which read and
  command nothing: no goal, pause, resume or cancel of a mission (docs/security.md).

The fleet's own services (API, recorder) reach the fleet router over plain TCP on the fleet
server's private network, with the user `fleet`; that router publishes its TLS port only. A
vehicle's processes reach its router the same way, each with its own user (its process name) and
password; the vehicle router's access control allows each exactly the keys its contract declares
(ares/deploy/local_acl.py: the rules are made from the contracts, so a new output is allowed by
declaring it, and a key no contract declares is allowed to no one).

Files are plain JSON (valid JSON5) written by `render`; `deploy/fleet/zenoh-router.json5` and
`deploy/vehicle/zenoh-router.json5` are this module's output (a test keeps them so). zenohd reads
a connecting router's password only from its configuration, so a vehicle's router config with
its credentials is made per vehicle by `ares deploy certs` and handed over as a secret.
"""

from __future__ import annotations

import copy
import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from ares.deploy import pki

SECRETS = "/run/secrets"  # where compose mounts secrets in a container
ROUTER_PORT = 7447  # TLS: vehicles to the fleet
LOCAL_PORT = 7448  # TCP: a host's own processes to its router
LEASE_MS = 2000  # as the stack's bus.lease_ms: a cut link is noticed within it

# the services the fleet may call on a vehicle: its state, the black-box seconds a lost link kept
# from the fleet's store and the incident snapshots it copies. No command: every process holding
# the fleet's Zenoh password (the network-facing fleet API among them) would otherwise send any
# shuttle driving; a mission's goal, pause, resume and cancel, the re-arm, the doors, automatic mode
# and the simulator are the vehicle's own API's, for an operator it has authenticated
FLEET_SERVICES = (
    "supervisor/status",
    "blackbox/records",
    "blackbox/acknowledge",
    "blackbox/snapshots",
    "blackbox/snapshot_part",
)

PUBLISH = ["put", "delete", "liveliness_token", "declare_queryable", "reply"]
SUBSCRIBE = ["declare_subscriber", "declare_liveliness_subscriber", "liveliness_query"]
ALL_MESSAGES = [*PUBLISH, *SUBSCRIBE, "query"]


def _rule(rule_id: str, messages: list[str], flows: list[str], key_exprs: list[str]) -> dict[str, Any]:
    return {"id": rule_id, "permission": "allow", "messages": messages, "flows": flows, "key_exprs": key_exprs}


def _tls() -> dict[str, Any]:
    return {
        "root_ca_certificate": f"{SECRETS}/zenoh_ca",
        "listen_certificate": f"{SECRETS}/zenoh_router_cert",
        "listen_private_key": f"{SECRETS}/zenoh_router_key",
        "connect_certificate": f"{SECRETS}/zenoh_router_cert",
        "connect_private_key": f"{SECRETS}/zenoh_router_key",
        "enable_mtls": True,
        "verify_name_on_connect": True,
        "close_link_on_expiration": True,
    }


def _common(name: str) -> dict[str, Any]:
    return {
        "mode": "router",
        "metadata": {"name": name},
        # routers meet only where configured: no multicast, and no gossip either (a vehicle router
        # would pass on its local listener, tcp/127.0.0.1:7448, which on the fleet host is the
        # fleet router's own port)
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
        "timestamping": {"enabled": {"router": True}},
    }


def fleet_router(vehicles: list[str]) -> dict[str, Any]:
    """The fleet router: TLS from the vehicles, TCP from the fleet's own services."""
    for vehicle_id in vehicles:
        pki.check_vehicle_id(vehicle_id)
    services = [f"ares/*/srv/{s}" for s in FLEET_SERVICES]
    rules = [
        _rule("fleet_services", ALL_MESSAGES, ["ingress", "egress"], ["**"]),
        # toward every vehicle: the fleet's subscriptions and its allowed calls
        _rule("to_vehicles_subscribe", SUBSCRIBE, ["egress"], ["ares/**"]),
        _rule("to_vehicles_call", ["query"], ["egress"], services),
    ]
    subjects: list[dict[str, Any]] = [{"id": "fleet_services", "link_protocols": ["tcp"], "usernames": ["fleet"]}]
    policies: list[dict[str, Any]] = [
        {"id": "fleet_services", "rules": ["fleet_services"], "subjects": ["fleet_services"]}
    ]
    for vehicle_id in sorted(set(vehicles)):
        own = [f"ares/{vehicle_id}/**"]
        rules.append(_rule(f"{vehicle_id}_publish", PUBLISH, ["ingress"], own))
        rules.append(_rule(f"{vehicle_id}_subscribed", ["put", "delete", "liveliness_token", "reply"], ["egress"], own))
        subjects.append(
            {"id": vehicle_id, "link_protocols": ["tls"], "cert_common_names": [vehicle_id], "usernames": [vehicle_id]}
        )
        policies.append(
            {
                "id": vehicle_id,
                "rules": [
                    f"{vehicle_id}_publish",
                    f"{vehicle_id}_subscribed",
                    "to_vehicles_subscribe",
                    "to_vehicles_call",
                ],
                "subjects": [vehicle_id],
            }
        )
    cfg = _common("fleet-router")
    cfg["listen"] = {"endpoints": [f"tls/0.0.0.0:{ROUTER_PORT}", f"tcp/0.0.0.0:{LOCAL_PORT}"]}
    cfg["transport"] = {
        "link": {"tx": {"lease": LEASE_MS}, "tls": _tls()},
        "auth": {"usrpwd": {"dictionary_file": f"{SECRETS}/zenoh_users"}},
    }
    cfg["access_control"] = {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }
    return cfg


def vehicle_router(
    fleet_endpoint: str = f"tls/fleet-router:{ROUTER_PORT}", cfg: Mapping[str, Any] | None = None
) -> dict[str, Any]:
    """A vehicle's router, without its credentials (`with_credentials` adds them); its processes'
    rights from the contracts of the process table under the configuration `cfg` (the defaults
    when None: a vehicle whose configuration changes its topics, other LiDARs for one, makes its
    own with `ares deploy router-config vehicle --config ...`)."""
    from ares.core import config
    from ares.deploy import local_acl

    cfg = config.core_defaults() if cfg is None else cfg
    ids = local_acl.rule_ids(cfg)
    services = [f"ares/*/srv/{s}" for s in FLEET_SERVICES]
    rules = [
        *local_acl.rules(cfg),
        # from the fleet: its subscriptions and its allowed calls; to the fleet: the vehicle's data
        _rule("fleet_subscribes", SUBSCRIBE, ["ingress"], ["ares/**"]),
        _rule("fleet_calls", ["query"], ["ingress"], services),
        _rule("to_fleet", ["put", "delete", "liveliness_token", "reply", "declare_queryable"], ["egress"], ["ares/**"]),
    ]
    cfg = _common("vehicle-router")
    cfg["listen"] = {"endpoints": [f"tcp/0.0.0.0:{LOCAL_PORT}"]}
    cfg["connect"] = {"endpoints": [fleet_endpoint], "timeout_ms": -1, "exit_on_failure": False}
    cfg["transport"] = {
        "link": {"tx": {"lease": LEASE_MS}, "tls": _tls()},
        # the vehicle's own processes log in too, each as its name: a router with credentials asks every link
        "auth": {"usrpwd": {"dictionary_file": f"{SECRETS}/zenoh_local_users"}},
    }
    cfg["access_control"] = {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": [
            *({"id": user, "link_protocols": ["tcp"], "usernames": [user]} for user in sorted(ids)),
            {"id": "fleet", "link_protocols": ["tls"], "cert_common_names": ["fleet"]},
        ],
        "policies": [
            *({"id": user, "rules": ids[user], "subjects": [user]} for user in sorted(ids)),
            {"id": "fleet", "rules": ["fleet_subscribes", "fleet_calls", "to_fleet"], "subjects": ["fleet"]},
        ],
    }
    return cfg


def with_credentials(cfg: dict[str, Any], user: str, password: str) -> dict[str, Any]:
    out = copy.deepcopy(cfg)
    usrpwd = out.setdefault("transport", {}).setdefault("auth", {}).setdefault("usrpwd", {})
    usrpwd.update({"user": user, "password": password})
    return out


def vehicles_of(cfg: dict[str, Any]) -> list[str]:
    """The vehicle ids a fleet router's access control admits."""
    subjects = cfg.get("access_control", {}).get("subjects", [])
    return sorted(s["id"] for s in subjects if "tls" in s.get("link_protocols", []))


HEADER = {
    "fleet": "// The fleet router (zenohd, or eclipse-zenoh in router mode for the tests).\n"
    "// Written by `ares deploy router-config fleet` / `ares deploy certs --fleet-config`; see docs/deploy.md.\n",
    "vehicle": "// A vehicle's router, without its credentials: `ares deploy certs` adds them and hands the\n"
    "// result to the vehicle as a secret. Written by `ares deploy router-config vehicle`; see docs/deploy.md.\n",
}


def render(cfg: dict[str, Any], kind: str) -> str:
    return HEADER[kind] + json.dumps(cfg, indent=2) + "\n"


def load(path: Path) -> dict[str, Any]:
    import json5

    data = json5.loads(Path(path).read_text())
    if not isinstance(data, dict):
        raise ValueError(f"{path}: a router config must be an object")
    return data


def write_for_vehicle(ca_dir: Path, vehicle_id: str, fleet_endpoint: str) -> tuple[Path, Path]:
    """After `pki.issue_vehicle`: the vehicle's router config with its credentials (a secret), and
    the fleet router's config admitting every vehicle of the fleet's dictionary."""
    ca_dir = Path(ca_dir)
    vehicle_dir = ca_dir / "vehicles" / vehicle_id
    user = (vehicle_dir / "zenoh_user").read_text().strip()
    password = (vehicle_dir / "zenoh_password").read_text().strip()
    vehicle_path = vehicle_dir / "zenoh_router.json5"
    pki.write_private(vehicle_path, render(with_credentials(vehicle_router(fleet_endpoint), user, password), "vehicle"))
    vehicles = [u for u in pki.read_users(ca_dir / "fleet" / "zenoh_users") if u != pki.FLEET_USER]
    fleet_path = ca_dir / "fleet" / "zenoh-router.json5"
    fleet_path.write_text(render(fleet_router(vehicles), "fleet"))
    return vehicle_path, fleet_path
