"""`ares deploy rehearse`: the deployment across real network hosts, on this machine.

Linux network namespaces stand in for the compose hosts (no docker engine here): a fleet host
and two vehicle hosts, each vehicle joined to the fleet by a veth link of its own (10.77.<k>.0/24),
and the operator's link from this machine to the fleet host (10.77.0.0/24, the fleet's API). The
routers run the deployment's JSON5 files (ares/deploy/router_config.py) through `ares deploy
router`, with certificates and credentials from a fleet CA made for the run:

- fleet host: the fleet router (TLS 7447 for the vehicles, TCP 7448 for the fleet's services,
  reporting access-control refusals), `ares fleet serve` (fleet_sync and fleet_api);
- each vehicle host: its router (connecting to the fleet over TLS) and its stack, `ares run
  --speed paced` without LiDARs (`--light`: only its black-box recorder, on the wall clock).

What it shows, in order: both vehicles reachable on the fleet API; a router with a wrong password
and one with a certificate of another CA refused; a vehicle publishing under the other's id
refused by access control (the fleet hears nothing of it, and an `acl_refused` event reaches the
fleet's black box); the fleet's credentials calling `mission/goal` on shuttle01, refused by its
router (`fleet_command_refused`); shuttle01's API putting the car's state, a key outside its
contract, refused by its own router (`local_acl_refused`: every process logs in as its name and
may use only its contract's keys); shuttle01's link cut for `partition_s` (the fleet marks it unreachable; it
drives on; after the link returns every second its black box recorded reaches the fleet's store);
the fleet router killed and started again (both vehicles back on the fleet, no vehicle process
restarted). One JSON object of figures. Every namespace, link and process it made is removed at
the end, also on Ctrl-C, SIGTERM or failure.
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

from ares.core.localhost import stop_process
from ares.deploy import pki, router_config
from ares.deploy.router import localize

VEHICLES = ("shuttle01", "shuttle02")
API_PORT = 8443
FLEET_ID = "fleet"
PROBE_S = 3.0  # a refused link: not linked within this long (a refusal is seen at once; this is the margin)


class RehearsalError(RuntimeError):
    """A step that could not be done (not root, no `ip`, a process that did not come up)."""


@dataclass
class Host:
    name: str  # the network namespace
    address: str  # where the others reach it


@dataclass
class Rehearsal:
    work: Path
    light: bool = False
    partition_s: float = 60.0
    progress: Callable[[str], None] = lambda text: print(f"[rehearse] {text}", file=sys.stderr, flush=True)
    tag: str = field(default_factory=lambda: f"ar{os.getpid() % 100000}")
    procs: list[subprocess.Popen] = field(default_factory=list)
    namespaces: list[str] = field(default_factory=list)
    links: list[str] = field(default_factory=list)  # root-namespace ends of veth pairs
    figures: dict[str, Any] = field(default_factory=dict)

    # ---- hosts and links ----------------------------------------------------------------------
    def _ip(self, *args: str) -> None:
        done = subprocess.run(["ip", *args], capture_output=True, text=True, check=False)
        if done.returncode != 0:
            raise RehearsalError(f"ip {' '.join(args)}: {done.stderr.strip()}")

    def _namespace(self, role: str) -> str:
        name = f"{self.tag}-{role}"
        self._ip("netns", "add", name)
        self.namespaces.append(name)
        self._ip("-n", name, "link", "set", "lo", "up")
        return name

    def _veth(self, a_ns: str | None, a_addr: str, b_ns: str, b_addr: str, suffix: str) -> str:
        """A veth pair, ends named <tag><suffix>a / b; returns the b end's name (in b_ns)."""
        a, b = f"{self.tag}{suffix}a", f"{self.tag}{suffix}b"
        self._ip("link", "add", a, "type", "veth", "peer", "name", b)
        if a_ns is None:
            self.links.append(a)
        else:
            self._ip("link", "set", a, "netns", a_ns)
        self._ip("link", "set", b, "netns", b_ns)
        for ns, end, addr in ((a_ns, a, a_addr), (b_ns, b, b_addr)):
            prefix = ["-n", ns] if ns else []
            self._ip(*prefix, "addr", "add", f"{addr}/24", "dev", end)
            self._ip(*prefix, "link", "set", end, "up")
        return b

    def build_hosts(self) -> None:
        if os.geteuid() != 0:
            raise RehearsalError("the rehearsal builds network namespaces: run it as root")
        if shutil.which("ip") is None:
            raise RehearsalError("the rehearsal needs the `ip` command (iproute2)")
        self.fleet = Host(self._namespace("fleet"), "10.77.0.2")
        self._veth(None, "10.77.0.1", self.fleet.name, self.fleet.address, "o")  # the operator's link
        self.hosts: dict[str, Host] = {}
        self.uplinks: dict[str, str] = {}  # vehicle -> its end of its link to the fleet
        for k, vehicle in enumerate(VEHICLES, start=1):
            ns = self._namespace(f"v{k}")
            self.uplinks[vehicle] = self._veth(self.fleet.name, f"10.77.{k}.1", ns, f"10.77.{k}.2", f"v{k}")
            self.hosts[vehicle] = Host(ns, f"10.77.{k}.2")
        self.progress(f"hosts: fleet {self.fleet.name}, " + ", ".join(f"{v} {h.name}" for v, h in self.hosts.items()))

    # ---- processes ----------------------------------------------------------------------------
    def _start(self, ns: str, name: str, *args: str, env: dict | None = None) -> subprocess.Popen:
        log = open(self.work / "logs" / f"{name}.log", "w")  # noqa: SIM115 (the process keeps it)
        proc = subprocess.Popen(
            ["ip", "netns", "exec", ns, sys.executable, *args],
            stdout=log,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            start_new_session=True,
            env={**os.environ, **(env or {})},
        )
        proc.name = name  # type: ignore[attr-defined]
        self.procs.append(proc)
        return proc

    def _run(self, ns: str, *args: str, timeout_s: float = 30.0) -> dict:
        done = subprocess.run(
            ["ip", "netns", "exec", ns, sys.executable, *args],
            capture_output=True,
            text=True,
            timeout=timeout_s,
            check=False,
        )
        lines = done.stdout.strip().splitlines()
        if done.returncode != 0 or not lines:
            raise RehearsalError(f"{' '.join(args[:4])}: exit {done.returncode}: {done.stderr.strip()[-500:]}")
        return json.loads(lines[-1])

    def _log_says(self, name: str, text: str) -> bool:
        return text in (self.work / "logs" / f"{name}.log").read_text(errors="replace")

    def _wait(self, what: str, cond: Callable[[], Any], timeout_s: float, step_s: float = 0.2) -> Any:
        deadline = time.monotonic() + timeout_s
        while True:
            value = cond()
            if value:
                return value
            dead = [p.name for p in self.procs if p.poll() is not None]  # type: ignore[attr-defined]
            if dead:
                raise RehearsalError(f"waiting for {what}: {', '.join(dead)} exited (logs in {self.work / 'logs'})")
            if time.monotonic() > deadline:
                raise RehearsalError(f"timed out after {timeout_s:.0f} s waiting for {what}")
            time.sleep(step_s)

    # ---- the deployment -----------------------------------------------------------------------
    def make_secrets(self) -> None:
        self.ca = self.work / "ca"
        fleet_names = [f"10.77.{k}.1" for k in range(1, len(VEHICLES) + 1)]
        for vehicle in VEHICLES:
            pki.issue_vehicle(self.ca, vehicle, fleet_names)
        # another fleet's CA, for the certificate that must be refused
        pki.issue_vehicle(self.work / "other-ca", VEHICLES[1], fleet_names)
        fleet_cfg = localize(
            router_config.fleet_router(list(VEHICLES)),
            self.ca / "fleet",
            [f"tls/0.0.0.0:{router_config.ROUTER_PORT}", f"tcp/127.0.0.1:{router_config.LOCAL_PORT}"],
        )
        self._write_json("fleet-router.json5", fleet_cfg)
        for k, vehicle in enumerate(VEHICLES, start=1):
            self._write_json(f"{vehicle}-router.json5", self._vehicle_router(vehicle, k, self.ca))
        self.fleet_password = (self.ca / "fleet" / "zenoh_fleet_password").read_text().strip()

    def _vehicle_router(self, vehicle: str, k: int, ca: Path, password: str | None = None) -> dict:
        folder = ca / "vehicles" / vehicle
        user = (folder / "zenoh_user").read_text().strip()
        password = password or (folder / "zenoh_password").read_text().strip()
        cfg = router_config.with_credentials(router_config.vehicle_router(), user, password)
        return localize(
            cfg,
            folder,
            [f"tcp/127.0.0.1:{router_config.LOCAL_PORT}"],
            [f"tls/10.77.{k}.1:{router_config.ROUTER_PORT}"],
        )

    def _client(self, name: str, endpoint: str, user: str, password: str) -> Path:
        cfg = {
            "mode": "client",
            "connect": {"endpoints": [endpoint]},
            "scouting": {"multicast": {"enabled": False}},
            "transport": {"auth": {"usrpwd": {"user": user, "password": password}}},
        }
        return self._write_json(name, cfg)

    def _write_json(self, name: str, data: dict) -> Path:
        path = self.work / name
        pki.write_private(path, json.dumps(data, indent=1))
        return path

    def start_fleet(self) -> None:
        from blackbox.api.credentials import Argon2Settings, Passwords, add_user
        from blackbox.register.store.sqlite_store import SqliteStore

        self.fleet_store = self.work / "fleet.sqlite"
        self.api_password = secrets.token_urlsafe(16)
        store = SqliteStore(str(self.fleet_store))
        add_user(store, Passwords(Argon2Settings(time_cost=1, memory_kib=8192, parallelism=1)), "fleet1", "fleet",
                 self.api_password, 10)  # fmt: skip
        store.close()
        self._start_fleet_router()
        fleet_yaml = {
            "vehicle_id": FLEET_ID,
            "simulate": False,
            "bus": {
                "router": f"tcp/127.0.0.1:{router_config.LOCAL_PORT}",
                "embedded_router": False,
                "mode": "client",
                "user": pki.FLEET_USER,
                "password_file": str(self.ca / "fleet" / "zenoh_fleet_password"),
            },
            "blackbox_store": {"uri": str(self.fleet_store)},
            "api": {"host": "0.0.0.0", "port": API_PORT, "state_dir": str(self.work / "fleet-api")},
        }
        self._write_json("fleet.yaml", fleet_yaml)
        self._start(
            self.fleet.name,
            "fleet-server",
            "-m",
            "ares.cli",
            "fleet",
            "serve",
            "--config",
            str(self.work / "fleet.yaml"),
            "--run-dir",
            str(self.work / "fleet-run"),
        )
        self.api = self._wait("the fleet's API", self._api_client, 60.0, 0.5)
        self.progress(f"fleet server up: API on https://{self.fleet.address}:{API_PORT}")

    def _start_fleet_router(self) -> None:
        self._start(
            self.fleet.name,
            "fleet-router",
            "-m",
            "ares.cli",
            "deploy",
            "router",
            "--config",
            str(self.work / "fleet-router.json5"),
            "--report-refusals-as",
            FLEET_ID,
        )
        self._wait("the fleet router", lambda: self._log_says("fleet-router", '"router"'), 20.0, 0.1)

    def _api_client(self):
        import httpx

        context = ssl.create_default_context()
        context.check_hostname, context.verify_mode = False, ssl.CERT_NONE  # the run's self-signed cert
        client = httpx.Client(base_url=f"https://{self.fleet.address}:{API_PORT}/api/v1", verify=context, timeout=5)
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

    def fleet_view(self) -> dict[str, dict]:
        import httpx

        try:
            r = self.api.get("/fleet")
        except httpx.HTTPError:
            return {}
        if r.status_code == 401:  # the token expired: a new one
            self.api = self._api_client() or self.api
            return {}
        return {v["vehicle_id"]: v for v in r.json().get("vehicles", [])} if r.status_code == 200 else {}

    def reachable(self) -> set[str]:
        return {v for v, state in self.fleet_view().items() if state.get("reachable")}

    def start_vehicles(self) -> dict[str, float]:
        started = {}
        for k, vehicle in enumerate(VEHICLES, start=1):
            host = self.hosts[vehicle]
            self._start(
                host.name, f"{vehicle}-router", "-m", "ares.cli", "deploy", "router",
                "--config", str(self.work / f"{vehicle}-router.json5"),
            )  # fmt: skip
            self._wait(f"{vehicle}'s router", lambda v=vehicle: self._log_says(f"{v}-router", '"router"'), 20.0, 0.1)
            folder = self.ca / "vehicles" / vehicle
            vehicle_yaml = {
                "vehicle_id": vehicle,
                "lidars": False,
                "mission_manager": {"autostart": "drive"},
                "sim": {"start_s_m": 0.0 if k == 1 else 340.0},
                "bus": {
                    "router": f"tcp/127.0.0.1:{router_config.LOCAL_PORT}",
                    "embedded_router": False,
                    "mode": "client",
                    "credentials_file": str(folder / "zenoh_local_users"),  # each process as its name
                },
                # as deploy/vehicle/ares.yaml: nothing purged that the fleet has not acknowledged
                "blackbox_store": {"uri": str(self.work / f"{vehicle}.sqlite"), "keep_until_acknowledged": True},
                "api": {"port": API_PORT, "state_dir": str(self.work / f"{vehicle}-api")},
            }
            self._write_json(f"{vehicle}.yaml", vehicle_yaml)
            started[vehicle] = time.monotonic()
            if self.light:  # the black box alone, on the wall clock
                self._start(
                    host.name, f"{vehicle}-stack", "-m", "ares.cli", "node", "blackbox",
                    env={"ARES_RUN_CONFIG": str(self._run_config(vehicle))},
                )  # fmt: skip
            else:
                self._start(
                    host.name, f"{vehicle}-stack", "-m", "ares.cli", "run", "--speed", "paced",
                    "--config", str(self.work / f"{vehicle}.yaml"), "--run-dir", str(self.work / f"{vehicle}-run"),
                )  # fmt: skip
        return started

    def _run_config(self, vehicle: str) -> Path:
        from ares.app import run_config

        cfg = run_config.build((str(self.work / f"{vehicle}.yaml"),))
        return self._write_json(f"{vehicle}-run.json", cfg)

    # ---- the checks ---------------------------------------------------------------------------
    def check_seen(self, started: dict[str, float]) -> None:
        seen: dict[str, float] = {}

        def both() -> bool:
            now = time.monotonic()
            for vehicle in self.reachable() & set(VEHICLES):
                seen.setdefault(vehicle, now - started[vehicle])
            return len(seen) == len(VEHICLES)

        self._wait("both vehicles on the fleet API", both, 120.0, 0.2)
        up = {v: self._first_record_s(v, started[v]) for v in VEHICLES}
        self.figures["vehicles_seen"] = len(seen)
        self.figures["seen_within_s"] = round(max(seen.values()), 2)
        self.figures["seen_after_stack_up_s"] = round(max(max(seen[v] - up[v], 0.0) for v in VEHICLES), 2)
        self.figures["stack_up_s"] = round(max(up.values()), 2)
        self.progress(
            f"both vehicles live on the fleet API {self.figures['seen_within_s']} s after their stacks were started "
            f"({self.figures['seen_after_stack_up_s']} s after their first black-box second)"
        )

    def _first_record_s(self, vehicle: str, started: float) -> float:
        """When the vehicle's black box wrote its first second (its stack is up), since `started`."""
        first = min(self._seconds(self.work / f"{vehicle}.sqlite", vehicle) or [0])
        wall_now, mono_now = time.time(), time.monotonic()
        return max(first - (wall_now - (mono_now - started)), 0.0) if first else mono_now - started

    def check_refusals(self) -> None:
        v2 = self.hosts[VEHICLES[1]]
        wrong = self._vehicle_router(VEHICLES[1], 2, self.ca, password="not-its-password")
        wrong["listen"] = {"endpoints": []}
        self.figures["refused_wrong_password"] = not self._run(
            v2.name, "-m", "ares.deploy.probe", "link", str(self._write_json("wrong-password.json5", wrong)),
            str(PROBE_S),
        )["linked"]  # fmt: skip
        other = self._vehicle_router(VEHICLES[1], 2, self.work / "other-ca")
        other["listen"] = {"endpoints": []}
        self.figures["refused_wrong_ca"] = not self._run(
            v2.name, "-m", "ares.deploy.probe", "link", str(self._write_json("other-ca.json5", other)),
            str(PROBE_S),
        )["linked"]  # fmt: skip
        # the positive control: shuttle02's own router, with the right secrets, is linked all along
        right_linked = VEHICLES[1] in self.reachable()
        self.progress(
            f"refused: wrong password {self.figures['refused_wrong_password']}, another CA's certificate "
            f"{self.figures['refused_wrong_ca']} ({VEHICLES[1]} with its own secrets on the fleet: {right_linked})"
        )
        self.figures["refused_wrong_password"] &= right_linked
        self.figures["refused_wrong_ca"] &= right_linked
        # shuttle01's API (it may put events) publishes under shuttle02's id and its own: the fleet hears only its own
        v1 = self.hosts[VEHICLES[0]]
        speaker = self._local_client(VEHICLES[0], "api")
        ear = self._client(
            "ear.json5", f"tcp/127.0.0.1:{router_config.LOCAL_PORT}", pki.FLEET_USER, self.fleet_password
        )
        own, other_key = f"ares/{VEHICLES[0]}/events", f"ares/{VEHICLES[1]}/events"
        listener = self._probe(self.fleet.name, "listen", ear, "9", own, other_key)
        for key in (other_key, own):
            self._run(v1.name, "-m", "ares.deploy.probe", "put", str(speaker), key, "10")
        heard = self._said(listener)["received"]
        refused_event = self._wait("the acl_refused event in the fleet's black box", self._acl_event, 15.0, 0.5)
        self.figures["refused_acl"] = heard[other_key] == 0 and heard[own] > 0 and bool(refused_event)
        self.figures["acl_refusal_event"] = refused_event
        self.progress(f"access control: heard {heard}; the fleet's event: {refused_event!r}")

    def check_fleet_commands(self) -> None:
        """The fleet's credentials try to start a mission on shuttle01: its router refuses the call
        (the vehicle's service never hears it), while the fleet's status call on the same link is
        answered."""
        vehicle, v1 = VEHICLES[0], self.hosts[VEHICLES[0]]
        goal, status = f"ares/{vehicle}/srv/mission/goal", f"ares/{vehicle}/srv/supervisor/status"
        fleet = self._client(
            "fleet-caller.json5", f"tcp/127.0.0.1:{router_config.LOCAL_PORT}", pki.FLEET_USER, self.fleet_password
        )
        # each service served by the process whose contract declares it, logged in as that process
        serving = [
            self._probe(v1.name, "serve", self._local_client(vehicle, "mission_manager"), "10", goal),
            self._probe(v1.name, "serve", self._local_client(vehicle, "supervisor"), "10", status),
        ]
        time.sleep(1.0)  # the queryables' declarations reach the fleet router
        drive = json.dumps({"t": 0.0, "operator": "fleet", "drive": True})
        answered = self._run(self.fleet.name, "-m", "ares.deploy.probe", "call", str(fleet), drive, goal, status)
        queried = {k: v for probe in serving for k, v in self._said(probe)["queried"].items()}
        refused = answered["answered"][goal] == 0 and queried[goal] == 0
        self.figures["fleet_command_refused"] = refused and answered["answered"][status] > 0
        self.progress(f"the fleet's mission/goal on {vehicle}: answered {answered['answered']}, heard {queried}")

    def check_local_acl(self) -> None:
        """On shuttle01's own router: its API puts the car's state (outside its contract) and then
        an event (its own output); the black box's recorder, which reads both, hears only the event."""
        vehicle, v1 = VEHICLES[0], self.hosts[VEHICLES[0]]
        forged, own = f"ares/{vehicle}/dbw/car_state", f"ares/{vehicle}/events"
        listener = self._probe(v1.name, "listen", self._local_client(vehicle, "blackbox"), "7", forged, own)
        speaker = self._local_client(vehicle, "api")
        for key in (forged, own):
            self._run(v1.name, "-m", "ares.deploy.probe", "put", str(speaker), key, "10")
        heard = self._said(listener)["received"]
        self.figures["local_acl_refused"] = heard[forged] == 0 and heard[own] > 0
        self.progress(f"{vehicle}'s API outside its contract ({forged}), then inside it ({own}): heard {heard}")

    def _local_client(self, vehicle: str, user: str) -> Path:
        """A session config of the vehicle's process `user` on its own router, with its password."""
        passwords = pki.read_users(self.ca / "vehicles" / vehicle / "zenoh_local_users")
        endpoint = f"tcp/127.0.0.1:{router_config.LOCAL_PORT}"
        return self._client(f"{vehicle}-{user}.json5", endpoint, user, passwords[user])

    def _probe(self, ns: str, what: str, cfg: Path, *args: str) -> subprocess.Popen:
        """A listening or serving probe, started and ready (its first line said)."""
        name = f"probe-{what}-{cfg.stem}"
        probe = subprocess.Popen(
            ["ip", "netns", "exec", ns, sys.executable, "-m", "ares.deploy.probe", what, str(cfg), *args],
            stdout=subprocess.PIPE, stderr=open(self.work / "logs" / f"{name}.log", "w"), text=True,  # noqa: SIM115
            start_new_session=True,
        )  # fmt: skip
        probe.name = name  # type: ignore[attr-defined]
        self.procs.append(probe)
        assert probe.stdout is not None
        probe.stdout.readline()  # listening / serving
        return probe

    def _said(self, probe: subprocess.Popen) -> dict:
        """A probe's last line, once it has ended."""
        out = probe.communicate(timeout=30)[0].strip().splitlines()
        self.procs.remove(probe)
        if not out:
            raise RehearsalError(f"{probe.name} said nothing (exit {probe.returncode}; logs/{probe.name}.log)")  # type: ignore[attr-defined]
        return json.loads(out[-1])

    def _acl_event(self) -> str | None:
        from datetime import UTC, datetime, timedelta

        now = datetime.now(UTC)
        r = self.api.get(
            f"/vehicles/{FLEET_ID}/events",
            params={"start": (now - timedelta(minutes=10)).isoformat(), "end": (now + timedelta(minutes=1)).isoformat(),
                    "kind": "acl_refused", "page_size": 1000},
        )  # fmt: skip
        events = r.json().get("events", []) if r.status_code == 200 else []
        # the probe's own refusal: a running stack may have had others under that id (a reply routed there)
        said = f"under {VEHICLES[1]}'s id (ares/{VEHICLES[1]}/events)"
        probe = [e["message"] for e in events if said in e["message"]]
        return probe[0] if probe else None

    def check_partition(self) -> None:
        vehicle, host = VEHICLES[0], self.hosts[VEHICLES[0]]
        self.progress(f"cutting {vehicle}'s link for {self.partition_s:g} s")
        self._ip("-n", host.name, "link", "set", self.uplinks[vehicle], "down")
        cut = time.monotonic()
        cut_wall = time.time()
        self._wait(f"{vehicle} unreachable on the fleet", lambda: vehicle not in self.reachable(), 30.0, 0.1)
        self.figures["unreachable_after_s"] = round(time.monotonic() - cut, 2)
        self.progress(f"the fleet marked {vehicle} unreachable after {self.figures['unreachable_after_s']} s")
        time.sleep(max(self.partition_s - (time.monotonic() - cut), 0.0))
        self._ip("-n", host.name, "link", "set", self.uplinks[vehicle], "up")
        healed_wall = time.time()
        self.figures["partition_s"] = round(time.monotonic() - cut, 1)
        self._wait(f"{vehicle} back on the fleet", lambda: vehicle in self.reachable(), 60.0, 0.2)
        self.figures["reachable_again_after_s"] = round(time.time() - healed_wall, 2)
        during = [r for r in self._records(vehicle) if cut_wall <= r[0] <= healed_wall]
        moving = [r for r in during if (r[1] or 0.0) > 0.3]
        self.figures["partition_vehicle_seconds"] = len(during)
        self.figures["partition_moving_share"] = round(len(moving) / max(len(during), 1), 3)

        # every second the vehicle recorded up to a moment after the link returned, at the fleet
        until = time.time() - 2.0

        def lost() -> list[int]:
            on_vehicle = {k for k in self._seconds(self.work / f"{vehicle}.sqlite", vehicle) if k <= until}
            return sorted(on_vehicle - set(self._seconds(self.fleet_store, vehicle)))

        try:
            self._wait("the partition's seconds in the fleet's store", lambda: not lost(), 60.0, 0.5)
        except RehearsalError:
            pass
        missing = lost()
        self.figures["blackbox_seconds_lost"] = len(missing)
        self.figures["blackbox_seconds_checked"] = len(
            [k for k in self._seconds(self.work / f"{vehicle}.sqlite", vehicle) if k <= until]
        )
        self.progress(
            f"after the link returned: {self.figures['blackbox_seconds_checked']} seconds of {vehicle}'s black box "
            f"checked, {len(missing)} missing at the fleet; it drove {self.figures['partition_moving_share']:.0%} "
            "of the partition"
        )
        self.check_acknowledged(vehicle, healed_wall)

    def check_acknowledged(self, vehicle: str, healed_wall: float) -> None:
        """The fleet's acknowledgement passes the cut, and covers no second the fleet lacks."""
        path = self.work / f"{vehicle}.sqlite"
        try:
            self._wait(
                f"{vehicle}'s mark past the cut", lambda: (self._mark(path, vehicle) or 0) >= healed_wall, 60.0, 0.5
            )
            self.figures["acknowledged_after_s"] = round(time.time() - healed_wall, 2)
        except RehearsalError:
            self.figures["acknowledged_after_s"] = None
        mark = self._mark(path, vehicle)
        covered = {k for k in self._seconds(path, vehicle) if mark is not None and k <= mark}
        self.figures["acknowledged_not_at_fleet"] = len(covered - set(self._seconds(self.fleet_store, vehicle)))
        self.progress(
            f"{vehicle}'s store acknowledged by the fleet {self.figures['acknowledged_after_s']} s after the link "
            f"returned; of the {len(covered)} seconds it covers, {self.figures['acknowledged_not_at_fleet']} "
            "missing at the fleet"
        )

    @staticmethod
    def _mark(path: Path, vehicle: str) -> int | None:
        from blackbox.register.store.record_store import StoreUnavailable
        from blackbox.register.store.sqlite_store import SqliteStore

        try:
            store = SqliteStore(str(path))
        except StoreUnavailable:
            return None
        try:
            return store.acknowledged(vehicle)
        except StoreUnavailable:
            return None
        finally:
            store.close()

    def check_router_restart(self) -> None:
        restarts_before = self._restarts()
        router = next(p for p in self.procs if p.name == "fleet-router")  # type: ignore[attr-defined]
        stop_process(router, timeout_s=5, group=True)
        self.procs.remove(router)
        self._wait("the fleet to lose both vehicles", lambda: not self.reachable(), 30.0, 0.2)
        started = time.monotonic()
        self._start_fleet_router()
        self._wait("both vehicles back after the router's restart", lambda: self.reachable() >= set(VEHICLES), 60, 0.2)
        self.figures["router_restart_recovered_s"] = round(time.monotonic() - started, 2)
        self.figures["vehicle_restarts_during_router_restart"] = self._restarts() - restarts_before
        self.progress(
            f"fleet router restarted: both vehicles back after {self.figures['router_restart_recovered_s']} s, "
            f"{self.figures['vehicle_restarts_during_router_restart']} vehicle processes restarted"
        )

    def _restarts(self) -> int:
        """Process restarts on the vehicles, as their supervisors' logs say (0 with --light)."""
        total = 0
        for vehicle in VEHICLES:
            logs = self.work / f"{vehicle}-run" / "logs"
            if logs.is_dir():
                total += sum(f.read_text(errors="replace").count("supervisor: restart") for f in logs.glob("*.log"))
        return total

    @staticmethod
    def _store_records(path: Path, vehicle: str) -> list[dict]:
        from datetime import UTC, datetime

        from blackbox.register.store.record_store import StoreUnavailable
        from blackbox.register.store.sqlite_store import SqliteStore

        if not path.exists():
            return []
        try:
            store = SqliteStore(str(path))
        except StoreUnavailable:
            return []
        try:
            return store.records(vehicle, datetime(2000, 1, 1, tzinfo=UTC), datetime(2100, 1, 1, tzinfo=UTC),
                                 limit=1_000_000)  # fmt: skip
        except StoreUnavailable:
            return []
        finally:
            store.close()

    def _seconds(self, path: Path, vehicle: str) -> list[int]:
        return [int(_epoch(r["time"])) for r in self._store_records(path, vehicle)]

    def _records(self, vehicle: str) -> list[tuple[float, float | None]]:
        return [
            (_epoch(r["time"]), r.get("speed_mps"))
            for r in self._store_records(self.work / f"{vehicle}.sqlite", vehicle)
        ]

    # ---- the whole ------------------------------------------------------------------------------
    def run(self) -> dict[str, Any]:
        began = time.monotonic()
        (self.work / "logs").mkdir(parents=True, exist_ok=True)
        self.build_hosts()
        self.make_secrets()
        self.start_fleet()
        started = self.start_vehicles()
        self.check_seen(started)
        self.check_refusals()
        self.check_fleet_commands()
        self.check_local_acl()
        self.check_partition()
        self.check_router_restart()
        self.figures["light"] = self.light
        self.figures["seconds"] = round(time.monotonic() - began, 1)
        return self.figures

    def cleanup(self) -> dict[str, Any]:
        for proc in reversed(self.procs):
            stop_process(proc, timeout_s=8, group=True)
        self.procs.clear()
        for ns in self.namespaces:
            subprocess.run(["ip", "netns", "pids", ns], capture_output=True, check=False)
            pids = subprocess.run(["ip", "netns", "pids", ns], capture_output=True, text=True, check=False).stdout
            for pid in pids.split():
                try:
                    os.kill(int(pid), signal.SIGKILL)
                except (ProcessLookupError, ValueError):
                    pass
            subprocess.run(["ip", "netns", "delete", ns], capture_output=True, check=False)
        for link in self.links:
            subprocess.run(["ip", "link", "delete", link], capture_output=True, check=False)
        listed = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True, check=False).stdout
        links = subprocess.run(["ip", "-o", "link"], capture_output=True, text=True, check=False).stdout
        return {
            "namespaces_left": [ns for ns in self.namespaces if ns in listed],
            "links_left": [link for link in self.links if f" {link}@" in links or f" {link}:" in links],
        }


def _epoch(value: Any) -> float:
    from blackbox.fleet.sync import epoch_of

    return epoch_of(value) if not isinstance(value, int | float) else float(value)


def rehearse(work: Path, light: bool = False, partition_s: float = 60.0) -> dict[str, Any]:
    """The whole rehearsal; always cleans up (also on SIGTERM: it becomes KeyboardInterrupt)."""
    work.mkdir(parents=True, exist_ok=True)
    rehearsal = Rehearsal(work, light=light, partition_s=partition_s)
    previous = signal.signal(signal.SIGTERM, lambda *_: (_ for _ in ()).throw(KeyboardInterrupt()))
    try:
        figures = rehearsal.run()
        figures["ok"] = True
    except (RehearsalError, subprocess.TimeoutExpired, OSError, ValueError, KeyError) as exc:
        figures = {**rehearsal.figures, "ok": False, "error": str(exc), "logs": str(work / "logs")}
    finally:
        left = rehearsal.cleanup()
        signal.signal(signal.SIGTERM, previous)
    figures.update(left)
    return figures
