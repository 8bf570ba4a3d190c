"""`ares deploy rehearse --containers`: the compose stacks of deploy/ under a real Docker engine.

The engine is the one running, or one started here (ares/deploy/engine.py) and stopped at the
end; the images are built when missing (ares/deploy/images.py). A temporary copy of deploy/ gets
secrets made for the run (a fleet CA, both vehicles' certificates and credentials, the release
manifest signed inside the image, everything owned by the image's user, uid 10001), and each
stack is brought up with Docker Compose from its compose.yaml, the no-registry override (the
project's router in the ares image, the embedded store in place of MongoDB: neither eclipse/zenoh
nor mongo can be pulled here) and a small override of the run's own (ports on 127.0.0.1 that do
not collide, the link network, each vehicle's id). The vehicles' routers reach the fleet router
over a network of the engine's own (`aresr-link`), as they would over the road's cellular link.

What it checks: every healthcheck turns healthy (waited on: `healthy_s`); both vehicles on the
fleet's API; secrets mounted as uid 10001 with mode 0600 or stricter; the resource limits of
ARES §3.8.3 set on every container and in force in its cgroup; only 127.0.0.1 published; a
vehicle's router disconnected from the link for `partition_s` (unreachable on the fleet, no
black-box second lost at the fleet); the fleet router restarted (both vehicles back, no vehicle
process restarted); `docker compose restart stack` and a `docker kill` of a vehicle's stack
(every second the fleet heard from it before is still in the vehicle's own store, in its volume:
`restart_lost_s`, `kill_lost_s`). MongoDB itself is not run, and the figures say so. Everything
it made (containers, networks, volumes, the engine it started) is removed at the end, also on
failure, Ctrl-C and SIGTERM; `left_behind` lists what could not be.
"""

from __future__ import annotations

import json
import os
import secrets
import shutil
import signal
import ssl
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ares.deploy import pki, router_config
from ares.deploy.engine import Engine, EngineError, compose_binary, connect_or_start
from ares.deploy.images import ARES_IMAGE, REPO, build_images, have_image
from ares.deploy.router import localize

VEHICLES = ("shuttle01", "shuttle02")
PREFIX = "aresr"
LINK = f"{PREFIX}-link"
IMAGE_UID = 10001
FLEET_PORTS = {"api": 18443, "tls": 17447, "local": 17448}
PROBE_S = 3.0  # a refused link: not linked within this long
# certificates and the release's public half: anyone may read them; every other secret only its owner
PUBLIC_SECRETS = {"zenoh_ca", "zenoh_router_cert", "api_tls_cert", "release_key.pub", "release_manifest"}
VEHICLE_PORTS = {"shuttle01": {"api": 18444, "local": 17449}, "shuttle02": {"api": 18445, "local": 17450}}


class ContainerRehearsalError(RuntimeError):
    pass


@dataclass
class ContainerRehearsal:
    work: Path
    base: str = "debootstrap"
    partition_s: float = 60.0
    progress: Callable[[str], None] = lambda text: print(f"[containers] {text}", file=sys.stderr, flush=True)
    engine: Engine | None = None
    projects: list[str] = field(default_factory=list)
    figures: dict[str, Any] = field(default_factory=dict)

    # ---- engine, images, the deployment's copy --------------------------------------------------
    def prepare(self) -> None:
        if os.geteuid() != 0:
            raise ContainerRehearsalError("the container rehearsal starts an engine and owns files as uid 10001: root")
        self.engine = connect_or_start()
        self.figures["engine_started_here"] = self.engine.started
        self.progress(f"engine at {self.engine.host}{' (started here)' if self.engine.started else ''}")
        if not have_image(self.engine, ARES_IMAGE):
            self.progress(f"no {ARES_IMAGE}: building it on the {self.base} base")
            built = build_images(self.base, self.progress, engine=self.engine)
            if not built.ok:
                raise ContainerRehearsalError(f"the images could not be built: {built.error}")
            self.figures["images"] = {i.tag: {"size_mb": i.size_mb, "seconds": i.seconds} for i in built.images}
        self.figures["image_size_mb"] = round(
            int(self.engine.docker("image", "inspect", "--format", "{{.Size}}", ARES_IMAGE).stdout.strip()) / 1e6, 1
        )

    def make_deployment(self) -> None:
        self.deploy = self.work / "deploy"
        shutil.copytree(REPO / "deploy", self.deploy, ignore=shutil.ignore_patterns("secrets"))
        self.ca = self.work / "ca"
        for vehicle in VEHICLES:
            pki.issue_vehicle(self.ca, vehicle, ["fleet-router", "localhost"])
            router_config.write_for_vehicle(self.ca, vehicle, f"tls/fleet-router:{router_config.ROUTER_PORT}")
        pki.issue_vehicle(self.work / "other-ca", VEHICLES[1], ["fleet-router", "localhost"])  # to be refused
        self.probes = self.work / "probes"
        self.probes.mkdir()
        shutil.copy(self.ca / "fleet" / "zenoh-router.json5", self.deploy / "fleet" / "zenoh-router.json5")
        self._release_manifest()
        self.api_password = secrets.token_urlsafe(16)
        self._probe_configs()
        for folder in (self.ca, self.work / "release", self.work / "other-ca", self.probes):
            _chown_tree(folder, IMAGE_UID)
        os.chown(self.work, IMAGE_UID, IMAGE_UID)  # the probes (uid 10001) read their configs from it
        self._overrides()

    def _release_manifest(self) -> None:
        """The release the vehicles must be: the image's installed files, hashed and signed inside it."""
        release = self.work / "release"
        release.mkdir()
        os.chown(release, IMAGE_UID, IMAGE_UID)
        self.engine.docker(
            "run", "--rm", "--network", "none", "-v", f"{release}:/release", ARES_IMAGE,
            "deploy", "manifest", "--key", "/release/release_key", "--out", "/release/release_manifest",
            timeout_s=300,
        )  # fmt: skip
        for vehicle in VEHICLES:
            for name in ("release_manifest", "release_key.pub"):
                shutil.copy(release / name, self.ca / "vehicles" / vehicle / name)

    def _probe_configs(self) -> None:
        """Session and router configs of the probes, their secrets' paths as the probe container
        mounts them (/w: the run's folder)."""
        inside = Path("/w")
        fleet_link = [f"tls/fleet-router:{router_config.ROUTER_PORT}"]
        v2 = self.ca / "vehicles" / VEHICLES[1]
        user = (v2 / "zenoh_user").read_text().strip()
        for name, ca, password in (
            ("wrong-password", self.ca, "not-its-password"),
            ("other-ca", self.work / "other-ca", None),
        ):
            folder = ca / "vehicles" / VEHICLES[1]
            secret = password or (folder / "zenoh_password").read_text().strip()
            cfg = router_config.with_credentials(router_config.vehicle_router(), user, secret)
            cfg = localize(cfg, inside / folder.relative_to(self.work), [], fleet_link)
            _write_json(self.probes / f"{name}.json5", cfg)
        fleet_password = (self.ca / "fleet" / "zenoh_fleet_password").read_text().strip()
        _write_json(self.probes / "fleet.json5", _session("tcp/zenoh-router:7448", pki.FLEET_USER, fleet_password))
        passwords = pki.read_users(self.ca / "vehicles" / VEHICLES[0] / "zenoh_local_users")
        for process in ("api", "blackbox", "mission_manager", "supervisor"):
            session = _session("tcp/zenoh-router:7448", process, passwords[process])
            _write_json(self.probes / f"{VEHICLES[0]}-{process}.json5", session)

    def _probe(self, network: str, *args: str) -> subprocess.Popen:
        """A probe (ares.deploy.probe) in a container of its own on `network`, started; what it
        says on stderr goes to logs/probes.log."""
        logs = self.work / "logs"
        logs.mkdir(exist_ok=True)
        with open(logs / "probes.log", "a") as err:
            err.write(f"---- {' '.join(args[:3])}\n")
            err.flush()
            return subprocess.Popen(
                [self.engine.client, "run", "--rm", "--network", network, "-v", f"{self.work}:/w:ro",
                 "--entrypoint", "python", ARES_IMAGE, "-m", "ares.deploy.probe", *args],
                env=self.engine.env(), stdout=subprocess.PIPE, stderr=err, text=True,
            )  # fmt: skip

    def _probe_says(self, network: str, *args: str) -> dict:
        out = self._probe(network, *args).communicate(timeout=120)[0].strip().splitlines()
        if not out:
            raise ContainerRehearsalError(
                f"probe {' '.join(args[:2])} said nothing ({self.work / 'logs' / 'probes.log'})"
            )
        return json.loads(out[-1])

    def _ready(self, probe: subprocess.Popen) -> subprocess.Popen:
        assert probe.stdout is not None
        probe.stdout.readline()  # listening / serving
        return probe

    def _ended(self, probe: subprocess.Popen) -> dict:
        out = probe.communicate(timeout=120)[0].strip().splitlines()
        if not out:
            raise ContainerRehearsalError("a probe said nothing")
        return json.loads(out[-1])

    def check_refusals(self) -> None:
        """As the namespace rehearsal: a wrong password and another CA's certificate refused by the
        fleet router; shuttle01's API putting under shuttle02's id refused (the fleet hears only its
        own, and an acl_refused event reaches the fleet's black box); the fleet's credentials
        calling mission/goal on shuttle01 refused; shuttle01's API putting the car's state (outside
        its contract) heard by no one on its own router."""
        fleet_net, v1_net = f"{PREFIX}-fleet_default", f"{PREFIX}-{VEHICLES[0]}_default"
        for name in ("wrong-password", "other-ca"):
            linked = self._probe_says(LINK, "link", f"/w/probes/{name}.json5", str(PROBE_S))["linked"]
            self.figures[f"refused_{name.replace('-', '_')}"] = not linked
        self.figures["refused_wrong_ca"] = self.figures.pop("refused_other_ca")
        own, other = f"ares/{VEHICLES[0]}/events", f"ares/{VEHICLES[1]}/events"
        ear = self._ready(self._probe(fleet_net, "listen", "/w/probes/fleet.json5", "9", own, other))
        speaker = f"/w/probes/{VEHICLES[0]}-api.json5"
        for key in (other, own):
            self._probe_says(v1_net, "put", speaker, key, "10")
        heard = self._ended(ear)["received"]
        self.figures["acl_heard"] = heard
        try:
            event = self._wait("the acl_refused event", self._acl_event, 20.0, 1.0)
        except ContainerRehearsalError:
            event = None
        self.figures["refused_acl"] = heard[other] == 0 and heard[own] > 0 and bool(event)
        self.figures["acl_refusal_event"] = event
        goal, status = f"ares/{VEHICLES[0]}/srv/mission/goal", f"ares/{VEHICLES[0]}/srv/supervisor/status"
        serving = [
            self._ready(self._probe(v1_net, "serve", f"/w/probes/{VEHICLES[0]}-mission_manager.json5", "12", goal)),
            self._ready(self._probe(v1_net, "serve", f"/w/probes/{VEHICLES[0]}-supervisor.json5", "12", status)),
        ]
        time.sleep(1.0)  # the queryables' declarations reach the fleet router
        drive = json.dumps({"t": 0.0, "operator": "fleet", "drive": True})
        answered = self._probe_says(fleet_net, "call", "/w/probes/fleet.json5", drive, goal, status)["answered"]
        queried = {k: v for probe in serving for k, v in self._ended(probe)["queried"].items()}
        self.figures["fleet_command_refused"] = answered[goal] == 0 and queried[goal] == 0 and answered[status] > 0
        forged = f"ares/{VEHICLES[0]}/dbw/car_state"
        listener = self._ready(
            self._probe(v1_net, "listen", f"/w/probes/{VEHICLES[0]}-blackbox.json5", "7", forged, own)
        )
        for key in (forged, own):
            self._probe_says(v1_net, "put", speaker, key, "10")
        local = self._ended(listener)["received"]
        self.figures["local_acl_heard"] = local
        self.figures["local_acl_refused"] = local[forged] == 0 and local[own] > 0
        self.progress(
            f"refused: wrong password {self.figures['refused_wrong_password']}, another CA "
            f"{self.figures['refused_wrong_ca']}, under another's id {self.figures['refused_acl']} ({event!r}), "
            f"the fleet's mission/goal {self.figures['fleet_command_refused']}, outside the contract "
            f"{self.figures['local_acl_refused']}"
        )

    def _acl_event(self) -> str | None:
        from datetime import UTC, datetime, timedelta

        now = datetime.now(UTC)
        r = self.api.get(
            "/vehicles/fleet/events",
            params={"start": (now - timedelta(minutes=10)).isoformat(), "end": (now + timedelta(minutes=1)).isoformat(),
                    "kind": "acl_refused", "page_size": 1000},
        )  # fmt: skip
        events = r.json().get("events", []) if r.status_code == 200 else []
        said = f"under {VEHICLES[1]}'s id (ares/{VEHICLES[1]}/events)"
        found = [e["message"] for e in events if said in e["message"]]
        return found[0] if found else None

    def _overrides(self) -> None:
        """The run's own override of each stack: ports that do not collide, the link network, the id."""
        fleet = {
            "services": {
                "zenoh-router": {
                    "ports": _reset([f"127.0.0.1:{FLEET_PORTS['tls']}:7447", f"127.0.0.1:{FLEET_PORTS['local']}:7448"]),
                    "networks": {"default": {}, "link": {"aliases": ["fleet-router"]}},
                },
                "fleet": {"ports": _reset([f"127.0.0.1:{FLEET_PORTS['api']}:8443"])},
            },
            "networks": {"link": {"external": True, "name": LINK}},
        }
        _write_yaml(self.deploy / "fleet" / "compose.rehearsal.yaml", fleet)
        for k, vehicle in enumerate(VEHICLES):
            ports = VEHICLE_PORTS[vehicle]
            overlay = {
                "vehicle_id": vehicle,
                "lidars": False,
                "mission_manager": {"autostart": "drive"},
                "sim": {"start_s_m": 0.0 if k == 0 else 340.0},
            }
            _write_yaml(self.deploy / "vehicle" / f"rehearsal-{vehicle}.yaml", overlay)
            override = {
                "services": {
                    "zenoh-router": {
                        "ports": _reset([f"127.0.0.1:{ports['local']}:7448"]),
                        "networks": {"default": {}, "link": {}},
                    },
                    "stack": {
                        "command": [
                            "run",
                            "--speed",
                            "paced",
                            "--config",
                            "/etc/ares/vehicle.yaml",
                            "--config",
                            "/etc/ares/embedded-store.yaml",
                            "--config",
                            "/etc/ares/rehearsal.yaml",
                        ],  # fmt: skip
                        "configs": [{"source": "rehearsal", "target": "/etc/ares/rehearsal.yaml"}],
                        "ports": _reset([f"127.0.0.1:{ports['api']}:8443"]),
                    },
                },
                "configs": {"rehearsal": {"file": f"./rehearsal-{vehicle}.yaml"}},
                "networks": {"link": {"external": True, "name": LINK}},
            }
            _write_yaml(self.deploy / "vehicle" / f"compose.{vehicle}.yaml", override)

    # ---- compose ---------------------------------------------------------------------------------
    def _compose_files(self, project: str) -> tuple[Path, list[str], dict[str, str]]:
        if project == "fleet":
            folder, extra, secrets_dir = self.deploy / "fleet", "compose.rehearsal.yaml", self.ca / "fleet"
        else:
            folder, extra = self.deploy / "vehicle", f"compose.{project}.yaml"
            secrets_dir = self.ca / "vehicles" / project
        files = ["-f", "compose.yaml", "-f", "compose.no-registry.yaml", "-f", extra]
        return folder, files, {"ARES_SECRETS": str(secrets_dir)}

    def compose(self, project: str, *args: str, timeout_s: float = 300.0, check: bool = True) -> str:
        folder, files, env = self._compose_files(project)
        done = subprocess.run(
            [compose_binary(), "-p", f"{PREFIX}-{project}", *files, *args],
            cwd=folder,
            env={**self.engine.env(), **env},
            capture_output=True,
            text=True,
            timeout=timeout_s,
        )
        if check and done.returncode != 0:
            raise ContainerRehearsalError(
                f"docker compose {project} {' '.join(args[:2])}: {(done.stderr or done.stdout).strip()[-1200:]}"
            )
        return done.stdout

    def up(self, project: str) -> float:
        began = time.monotonic()
        self.projects.append(project)
        self.compose(project, "up", "-d", "--pull", "never", "--no-build", "--wait", "--wait-timeout", "300",
                     timeout_s=420)  # fmt: skip
        return time.monotonic() - began

    def container(self, project: str, service: str) -> str:
        return f"{PREFIX}-{project}-{service}-1"

    def start_all(self) -> None:
        self.engine.docker("network", "create", LINK)
        self.progress("fleet: router, fleet server (compose up, waiting for its healthchecks)")
        healthy = {"fleet": self.up("fleet")}
        self._add_fleet_user()
        self.api = self._wait("the fleet's API", self._api_client, 60.0, 1.0)
        self.vehicles_started = time.monotonic()
        for vehicle in VEHICLES:
            self.progress(f"{vehicle}: router, stack (compose up, waiting for its healthchecks)")
            healthy[vehicle] = self.up(vehicle)
        self.figures["healthy_s"] = {name: round(s, 1) for name, s in healthy.items()}
        self.progress(f"every healthcheck healthy: {self.figures['healthy_s']}")

    def _add_fleet_user(self) -> None:
        folder, files, env = self._compose_files("fleet")
        done = subprocess.run(
            [compose_binary(), "-p", f"{PREFIX}-fleet", *files, "exec", "-T", "fleet", "ares", "users", "add",
             "fleet1", "--role", "fleet", "--store", "/var/lib/ares/blackbox.sqlite"],
            cwd=folder, env={**self.engine.env(), **env}, input=self.api_password + "\n",
            capture_output=True, text=True, timeout=120,
        )  # fmt: skip
        if done.returncode != 0:
            raise ContainerRehearsalError(f"adding the fleet's API user: {(done.stderr or done.stdout).strip()[-600:]}")

    # ---- the fleet's API -------------------------------------------------------------------------
    def _api_client(self):
        import httpx

        context = ssl.create_default_context()
        context.check_hostname, context.verify_mode = False, ssl.CERT_NONE  # the run's own certificate
        client = httpx.Client(base_url=f"https://127.0.0.1:{FLEET_PORTS['api']}/api/v1", verify=context, timeout=5)
        try:
            r = client.post("/auth/token", data={"username": "fleet1", "password": self.api_password})
        except httpx.HTTPError:
            client.close()
            return None
        if r.status_code != 200:
            client.close()
            return None
        client.headers["Authorization"] = "Bearer " + r.json()["access_token"]
        return client

    def reachable(self) -> set[str]:
        import httpx

        try:
            r = self.api.get("/fleet")
        except httpx.HTTPError:
            return set()
        if r.status_code == 401:
            self.api = self._api_client() or self.api
            return set()
        vehicles = r.json().get("vehicles", []) if r.status_code == 200 else []
        return {v["vehicle_id"] for v in vehicles if v.get("reachable")}

    def _wait(self, what: str, cond: Callable[[], Any], timeout_s: float, step_s: float = 0.5) -> Any:
        deadline = time.monotonic() + timeout_s
        while True:
            value = cond()
            if value:
                return value
            if time.monotonic() > deadline:
                raise ContainerRehearsalError(f"timed out after {timeout_s:.0f} s waiting for {what}")
            time.sleep(step_s)

    # ---- the stores, in their volumes ------------------------------------------------------------
    def store_path(self, project: str) -> Path:
        volume = f"{PREFIX}-{project}_state"
        mountpoint = self.engine.docker("volume", "inspect", "--format", "{{.Mountpoint}}", volume).stdout.strip()
        return Path(mountpoint) / "blackbox.sqlite"

    def seconds(self, project: str, vehicle: str) -> set[int]:
        from ares.deploy.rehearse import Rehearsal, _epoch

        return {int(_epoch(r["time"])) for r in Rehearsal._store_records(self.store_path(project), vehicle)}

    # ---- the checks ------------------------------------------------------------------------------
    def check_seen(self) -> None:
        began = time.monotonic()
        self._wait("both vehicles on the fleet API", lambda: self.reachable() >= set(VEHICLES), 120.0)
        self.figures["vehicles_seen"] = len(self.reachable() & set(VEHICLES))
        self.figures["seen_within_s"] = round(time.monotonic() - self.vehicles_started, 2)  # from their compose up
        self.figures["seen_after_healthy_s"] = round(time.monotonic() - began, 2)
        self.progress(f"both vehicles on the fleet's API ({self.figures['seen_after_healthy_s']} s after healthy)")

    def check_secrets(self) -> None:
        """Every secret of every service as the image's user reads it: uid 10001, no one else's."""
        seen: dict[str, list[str]] = {}
        for project, services in (
            ("fleet", ("fleet", "zenoh-router")),
            *((v, ("stack", "zenoh-router")) for v in VEHICLES),
        ):
            for service in services:
                out = self.engine.docker(
                    "exec", self.container(project, service), "sh", "-c", "stat -L -c '%u %a %n' /run/secrets/*"
                ).stdout
                seen[f"{project}/{service}"] = out.split("\n")[:-1]
        bad = [
            f"{where}: {line}"
            for where, lines in seen.items()
            for line in lines
            if int(line.split()[0]) != IMAGE_UID
            or (Path(line.split()[2]).name not in PUBLIC_SECRETS and int(line.split()[1], 8) & 0o077)
        ]
        self.figures["secrets_checked"] = sum(len(lines) for lines in seen.values())
        self.figures["secrets_ok"] = not bad and self.figures["secrets_checked"] > 0
        self.progress(f"secrets: {self.figures['secrets_checked']} mounted, wrong owner or mode: {bad[:3] or 'none'}")

    def check_limits(self) -> None:
        """Each container's limits as compose set them, and as its cgroup enforces them."""
        limits: dict[str, dict[str, int]] = {}
        enforced = True
        for name in self._containers():
            cfg = json.loads(self.engine.docker("inspect", "--format", "{{json .HostConfig}}", name).stdout)
            limits[name] = {"nano_cpus": cfg["NanoCpus"], "memory": cfg["Memory"], "pids": cfg["PidsLimit"] or 0}
            in_cgroup = self.engine.docker(
                "exec", name, "sh", "-c",
                "cat /sys/fs/cgroup/memory.max /sys/fs/cgroup/pids.max 2>/dev/null"
                " || cat /sys/fs/cgroup/memory/memory.limit_in_bytes /sys/fs/cgroup/pids/pids.max",
            ).stdout.split()  # fmt: skip
            enforced &= all(v > 0 for v in limits[name].values())
            enforced &= in_cgroup[:2] == [str(cfg["Memory"]), str(cfg["PidsLimit"])]
        self.figures["limits"] = limits
        self.figures["limits_in_force"] = enforced and bool(limits)
        self.progress(f"resource limits set and in the cgroups of {len(limits)} containers: {enforced}")

    def check_ports(self) -> None:
        published = []
        for name in self._containers():
            ports = json.loads(
                self.engine.docker("inspect", "--format", "{{json .NetworkSettings.Ports}}", name).stdout
            )
            for bindings in (ports or {}).values():
                published += [b["HostIp"] for b in bindings or []]
        self.figures["published_ports"] = len(published)
        self.figures["only_loopback_published"] = bool(published) and all(ip == "127.0.0.1" for ip in published)
        # from another network of the engine (not the stack's): the vehicle's API is not reachable
        address = self.engine.docker(
            "inspect", "--format", "{{range .NetworkSettings.Networks}}{{.IPAddress}} {{end}}",
            self.container(VEHICLES[0], "stack"),
        ).stdout.split()[0]  # fmt: skip
        probe = self.engine.docker(
            "run", "--rm", "--network", LINK, "--entrypoint", "python", ARES_IMAGE, "-c",
            f"import socket\ntry:\n socket.create_connection(('{address}', 8443), 3); print('open')\n"
            "except OSError: print('closed')",
            check=False, timeout_s=60,
        ).stdout.strip()  # fmt: skip
        self.figures["stack_closed_to_other_networks"] = probe == "closed"
        self.progress(
            f"published: {len(published)} ports, all on 127.0.0.1: {self.figures['only_loopback_published']}; "
            f"{VEHICLES[0]}'s API from the link network: {probe}"
        )

    def check_partition(self) -> None:
        vehicle = VEHICLES[0]
        router = self.container(vehicle, "zenoh-router")
        self.progress(f"disconnecting {vehicle}'s router from the link for {self.partition_s:g} s")
        cut, cut_wall = time.monotonic(), time.time()
        self.engine.docker("network", "disconnect", LINK, router)
        self._wait(f"{vehicle} unreachable", lambda: vehicle not in self.reachable(), 60.0)
        self.figures["unreachable_after_s"] = round(time.monotonic() - cut, 2)
        time.sleep(max(self.partition_s - (time.monotonic() - cut), 0.0))
        self.engine.docker("network", "connect", LINK, router)
        healed = time.time()
        self.figures["partition_s"] = round(time.monotonic() - cut, 1)
        self._wait(f"{vehicle} back", lambda: vehicle in self.reachable(), 90.0)
        self.figures["reachable_again_after_s"] = round(time.time() - healed, 2)
        until = time.time() - 2.0

        def lost() -> set[int]:
            on_vehicle = {k for k in self.seconds(vehicle, vehicle) if k <= until}
            return on_vehicle - self.seconds("fleet", vehicle)

        try:
            self._wait("the cut's seconds at the fleet", lambda: not lost(), 90.0, 1.0)
        except ContainerRehearsalError:
            pass
        self.figures["blackbox_seconds_lost"] = len(lost())
        self.figures["blackbox_seconds_checked"] = len({k for k in self.seconds(vehicle, vehicle) if k <= until})
        records = self._records(vehicle)
        during = [speed for k, speed in records.items() if cut_wall <= k <= healed]
        self.figures["partition_vehicle_seconds"] = len(during)
        moving = [speed for speed in during if (speed or 0.0) > 0.3]
        self.figures["partition_moving_share"] = round(len(moving) / max(len(during), 1), 3)
        self.progress(
            f"after the link returned: {self.figures['blackbox_seconds_checked']} seconds checked, "
            f"{self.figures['blackbox_seconds_lost']} missing at the fleet ({len(during)} recorded during the cut, "
            f"moving in {self.figures['partition_moving_share']:.0%})"
        )
        self.check_acknowledged(vehicle, healed)

    def check_acknowledged(self, vehicle: str, healed_wall: float) -> None:
        """The fleet's acknowledgement passes the cut in the vehicle's own store (in its volume),
        and covers no second the fleet's store lacks."""
        from ares.deploy.rehearse import Rehearsal

        path = self.store_path(vehicle)
        try:
            self._wait("the mark past the cut", lambda: (Rehearsal._mark(path, vehicle) or 0) >= healed_wall, 90.0, 1.0)
            self.figures["acknowledged_after_s"] = round(time.time() - healed_wall, 2)
        except ContainerRehearsalError:
            self.figures["acknowledged_after_s"] = None
        mark = Rehearsal._mark(path, vehicle)
        covered = {k for k in self.seconds(vehicle, vehicle) if mark is not None and k <= mark}
        self.figures["acknowledged_not_at_fleet"] = len(covered - self.seconds("fleet", vehicle))
        self.progress(
            f"{vehicle}'s store acknowledged {self.figures['acknowledged_after_s']} s after the link returned; "
            f"{self.figures['acknowledged_not_at_fleet']} of the {len(covered)} seconds it covers missing at the fleet"
        )

    def _records(self, vehicle: str) -> dict[int, float | None]:
        from ares.deploy.rehearse import Rehearsal, _epoch

        rows = Rehearsal._store_records(self.store_path(vehicle), vehicle)
        return {int(_epoch(r["time"])): r.get("speed_mps") for r in rows}

    def check_router_restart(self) -> None:
        restarts = self._vehicle_restarts()
        began = time.monotonic()
        self.compose("fleet", "restart", "zenoh-router", timeout_s=120)
        self._wait("both vehicles back after the fleet router's restart", lambda: self.reachable() >= set(VEHICLES),
                   120.0)  # fmt: skip
        self.figures["router_restart_recovered_s"] = round(time.monotonic() - began, 2)
        self.figures["vehicle_restarts_during_router_restart"] = self._vehicle_restarts() - restarts
        self.progress(
            f"fleet router restarted: both back after {self.figures['router_restart_recovered_s']} s, "
            f"{self.figures['vehicle_restarts_during_router_restart']} vehicle processes restarted"
        )

    def _vehicle_restarts(self) -> int:
        total = 0
        for vehicle in VEHICLES:
            logs = self.engine.docker("logs", self.container(vehicle, "stack"), check=False, timeout_s=60)
            total += (logs.stdout + logs.stderr).count("supervisor: restart")
        return total

    def check_stack_restarts(self) -> None:
        """Every second the fleet heard from shuttle02 before its stack stopped is in its own store."""
        vehicle = VEHICLES[1]
        for how, key in (("restart", "restart_lost_s"), ("kill", "kill_lost_s")):
            before = time.time() - 1.0
            if how == "restart":
                self.compose(vehicle, "restart", "stack", timeout_s=180)
            else:
                self.engine.docker("kill", self.container(vehicle, "stack"))
                self.compose(vehicle, "up", "-d", "--no-build", "--pull", "never", "stack", timeout_s=180)
            self._wait(
                f"{vehicle}'s stack healthy after the {how}", lambda: self._healthy(vehicle, "stack"), 240.0, 2.0
            )
            heard = {k for k in self.seconds("fleet", vehicle) if k <= before}
            kept = self.seconds(vehicle, vehicle)
            self.figures[key] = len(heard - kept)
            self.progress(
                f"{vehicle}'s stack after a {how}: {len(heard)} seconds heard before, {len(heard - kept)} gone"
            )

    def _healthy(self, project: str, service: str) -> bool:
        state = self.engine.docker(
            "inspect", "--format", "{{.State.Health.Status}}", self.container(project, service), check=False
        ).stdout.strip()
        return state == "healthy"

    def _containers(self) -> list[str]:
        out = self.engine.docker("ps", "--filter", f"name={PREFIX}-", "--format", "{{.Names}}").stdout
        return sorted(out.split())

    # ---- the whole -------------------------------------------------------------------------------
    def run(self) -> dict[str, Any]:
        began = time.monotonic()
        self.figures["mongodb_run"] = False  # no image of it here: the embedded store stood in
        self.prepare()
        self.make_deployment()
        self.start_all()
        self.check_seen()
        self.check_secrets()
        self.check_limits()
        self.check_ports()
        self.check_refusals()
        self.check_partition()
        self.check_router_restart()
        self.check_stack_restarts()
        self.figures["seconds"] = round(time.monotonic() - began, 1)
        return self.figures

    def cleanup(self) -> dict[str, Any]:
        left: list[str] = []
        if self.engine is not None:
            logs = self.work / "logs"
            logs.mkdir(exist_ok=True)
            for project in self.projects:  # what the containers said, kept beside the run's figures
                try:
                    (logs / f"{project}.log").write_text(self.compose(project, "logs", "--no-color", check=False))
                except (subprocess.TimeoutExpired, OSError) as exc:
                    left.append(f"{project} logs: {exc}")
            for project in reversed(self.projects):
                try:
                    self.compose(project, "down", "-v", "--remove-orphans", "--timeout", "20", timeout_s=180,
                                 check=False)  # fmt: skip
                except (subprocess.TimeoutExpired, OSError) as exc:
                    left.append(f"{project}: {exc}")
            self.engine.docker("network", "rm", LINK, check=False)
            try:
                for kind, args in (
                    ("container", ("ps", "-a", "--filter", f"name={PREFIX}-", "--format", "{{.Names}}")),
                    ("network", ("network", "ls", "--filter", f"name={PREFIX}", "--format", "{{.Name}}")),
                    ("volume", ("volume", "ls", "--filter", f"name={PREFIX}", "--format", "{{.Name}}")),
                ):
                    left += [f"{kind} {name}" for name in self.engine.docker(*args, check=False).stdout.split()]
            except (subprocess.TimeoutExpired, EngineError) as exc:
                left.append(f"not listed: {exc}")
            self.engine.stop()
            if self.engine.started and self.engine.proc is not None and self.engine.proc.poll() is None:
                left.append(f"dockerd {self.engine.proc.pid}")
        return {"left_behind": left}


# what must be true for the rehearsal to pass, beside its own steps succeeding
MUST_HOLD = (
    "secrets_ok", "limits_in_force", "only_loopback_published", "stack_closed_to_other_networks",
    "refused_wrong_password", "refused_wrong_ca", "refused_acl", "fleet_command_refused", "local_acl_refused",
    "acknowledged_after_s", "partition_moving_share",
)  # fmt: skip


MUST_BE_NONE = (
    "blackbox_seconds_lost", "acknowledged_not_at_fleet", "restart_lost_s", "kill_lost_s",
    "vehicle_restarts_during_router_restart",
)  # fmt: skip


def _session(endpoint: str, user: str, password: str) -> dict:
    return {
        "mode": "client",
        "connect": {"endpoints": [endpoint]},
        "scouting": {"multicast": {"enabled": False}},
        "transport": {"auth": {"usrpwd": {"user": user, "password": password}}},
    }


def _write_json(path: Path, data: dict) -> None:
    pki.write_private(path, json.dumps(data, indent=1))


def _reset(ports: list[str]) -> Any:
    return _Tagged("!override", ports)


@dataclass
class _Tagged:
    tag: str
    value: Any


def _write_yaml(path: Path, data: Any) -> None:
    import yaml

    class Dumper(yaml.SafeDumper):
        pass

    Dumper.add_representer(_Tagged, lambda d, v: d.represent_sequence(v.tag, v.value))
    path.write_text(yaml.dump(data, Dumper=Dumper, sort_keys=False))


def _chown_tree(folder: Path, uid: int) -> None:
    for root, dirs, files in os.walk(folder):
        for name in (*dirs, *files):
            os.chown(Path(root) / name, uid, uid)
    os.chown(folder, uid, uid)


def rehearse_containers(work: Path, base: str = "debootstrap", partition_s: float = 60.0) -> dict[str, Any]:
    """The whole container rehearsal; always cleans up (SIGTERM becomes KeyboardInterrupt)."""
    work.mkdir(parents=True, exist_ok=True)
    rehearsal = ContainerRehearsal(work, base=base, partition_s=partition_s)
    previous = signal.signal(signal.SIGTERM, lambda *_: (_ for _ in ()).throw(KeyboardInterrupt()))
    try:
        figures = rehearsal.run()
        figures["ok"] = True
    except (ContainerRehearsalError, EngineError, subprocess.TimeoutExpired, OSError, ValueError, KeyError) as exc:
        figures = {**rehearsal.figures, "ok": False, "error": str(exc)}
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM: cleaned up below, and said
        figures = {**rehearsal.figures, "ok": False, "error": "interrupted (SIGINT or SIGTERM)"}
    finally:
        left = rehearsal.cleanup()
        signal.signal(signal.SIGTERM, previous)
    figures.update(left)
    held = all(figures.get(key) for key in MUST_HOLD) and all(figures.get(key) == 0 for key in MUST_BE_NONE)
    figures["ok"] = figures["ok"] and not left["left_behind"] and held
    return figures
