"""How a soak injects each kind of fault into the running stack (ares.tools.soak.plan's kinds).

| kind                   | how                                                                        |
|------------------------|----------------------------------------------------------------------------|
| kill/hang/busy_process | the supervisor signals the process: SIGKILL, SIGSTOP, SIGUSR1 (a process   |
|                        | spawned for a soak busy-loops holding the GIL on it: ares.core.launch)     |
| gnss_outage, rtk_loss, | the simulator's `sim/sensor_fault` service, from now for the duration      |
| imu_frozen             |                                                                            |
| lidar_covered          | the LiDAR simulator's `sim/lidar_fault`: covered, uncovered at the end      |
| lidar_silent           | the LiDAR simulator's process SIGKILLed (the supervisor restarts it)       |
| router_restart         | the soak's own router process SIGKILLed, started again after the duration |
| store_unavailable      | the black box's SQLite file held under an exclusive lock for the duration |
| bad_api_burst          | requests with no, forged or expired-looking tokens, to unknown routes, with |
|                        | malformed bodies and ranges: each must get a 4xx, none a 5xx or no answer |
| obstacles in the path  | in the soak's scenario file, appearing ahead of the shuttle at their time  |
|                        | (the LiDAR simulator places them: simulator.obstacles): nothing to do here  |

The injections that last (the lock, the router's absence, the burst) run on threads of their own,
so that the soak goes on measuring meanwhile; `wait` joins them at the end.
"""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

from ares.core.bus import BaseBus, ServiceError
from ares.core.clock import Clock
from ares.core.localhost import wait_for_port
from ares.core.messages import LidarFault, SensorFault
from ares.tools.soak.plan import PlannedFault

SENSOR_FAULT = {"gnss_outage": "gnss_outage", "rtk_loss": "gnss_no_corrections", "imu_frozen": "freeze_imu"}
SIGNAL_OF = {"kill_process": "kill", "hang_process": "hang", "busy_process": "busy"}
LIDAR_PROCESS = "lidar_sim"
LASTING = ("lidar_covered", "router_restart", "store_unavailable", "bad_api_burst")  # they report when done
WALL_CAP_S = 60.0  # a lasting fault never holds longer than this in wall time (a stalled clock)


class RouterProcess:
    """The soak's Zenoh router, a process of its own (`python -m ares.app.embedded_router`), so
    that a fault can kill it and start it again while every process of the stack stays up."""

    def __init__(self, config_path: Path, endpoint: str, log_path: Path):
        self.config_path, self.endpoint, self.log_path = config_path, endpoint, log_path
        self.proc: subprocess.Popen | None = None
        self.restarts = 0

    def start(self) -> None:
        env = {**os.environ, "ARES_RUN_CONFIG": str(self.config_path), "ARES_PROCESS_NAME": "router"}
        with self.log_path.open("ab") as out:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "ares.app.embedded_router"],
                env=env,
                stdin=subprocess.DEVNULL,
                stdout=out,
                stderr=subprocess.STDOUT,
                process_group=0,
            )
        wait_for_port(int(self.endpoint.rsplit(":", 1)[1]), proc=self.proc)

    def kill(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait(timeout=5)

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGTERM)
            try:
                self.proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.kill()


class Injectors:
    def __init__(
        self,
        bus: BaseBus,
        clock: Clock,
        inject_process: Callable[[str, str], str],
        router: RouterProcess | None,
        store_path: str | None,
        api_base: str | None,
        vehicle_id: str,
    ):
        self.bus, self.clock, self.inject_process = bus, clock, inject_process
        self.router, self.store_path, self.api_base, self.vehicle_id = router, store_path, api_base, vehicle_id
        self.threads: list[threading.Thread] = []
        self.results: dict[int, dict] = {}  # a lasting injection's outcome, by fault index, once done

    def inject(self, fault: PlannedFault, at_t: float) -> tuple[bool, str]:
        """Start the fault now (stack time at_t); (injected, what was done)."""
        kind = fault.kind
        try:
            if kind in SIGNAL_OF:
                assert fault.target is not None  # the plan gives process faults a target
                return True, self.inject_process(fault.target, SIGNAL_OF[kind])
            if kind in SENSOR_FAULT:
                reply = self.bus.call(
                    "sim/sensor_fault", SensorFault(t=at_t, kind=SENSOR_FAULT[kind], duration_s=fault.duration_s)
                )
                return reply.ok, reply.detail
            if kind == "lidar_covered":
                return self._cover(fault, at_t)
            if kind == "lidar_silent":
                return True, self.inject_process(LIDAR_PROCESS, "kill")
            if kind == "router_restart":
                return self._lasting(fault, at_t, self._restart_router)
            if kind == "store_unavailable":
                return self._lasting(fault, at_t, self._lock_store)
            if kind == "bad_api_burst":
                return self._lasting(fault, at_t, self._bad_requests)
            if kind in ("pedestrian_in_path", "parked_object_in_path"):
                return True, "placed ahead of the shuttle by the LiDAR simulator (the soak's scenario)"
        except (ServiceError, KeyError, OSError) as exc:
            return False, f"{type(exc).__name__}: {exc}"
        return False, f"no injector for {kind}"

    # ---- lasting faults -----------------------------------------------------------------------------
    def _lasting(
        self, fault: PlannedFault, at_t: float, work: Callable[[PlannedFault, float], dict]
    ) -> tuple[bool, str]:
        def run() -> None:
            try:
                self.results[fault.index] = work(fault, at_t)
            except Exception as exc:  # an injector that failed is a finding of the soak, not its end
                self.results[fault.index] = {"error": f"{type(exc).__name__}: {exc}"}

        thread = threading.Thread(target=run, name=f"soak-{fault.kind}-{fault.index}", daemon=True)
        self.threads = [t for t in self.threads if t.is_alive()] + [thread]
        thread.start()
        return True, "started"

    def _until(self, t_end: float) -> None:
        """Wait until the stack clock reaches t_end (at most WALL_CAP_S of wall time)."""
        deadline = time.monotonic() + WALL_CAP_S
        while self.clock.now() < t_end and time.monotonic() < deadline:
            time.sleep(0.02)

    def _cover(self, fault: PlannedFault, at_t: float) -> tuple[bool, str]:
        assert fault.target is not None  # the plan gives lidar_covered a LiDAR
        reply = self.bus.call("sim/lidar_fault", LidarFault(t=at_t, sensor=fault.target, blocked=True))
        if not reply.ok:
            return False, reply.detail

        def uncover(f: PlannedFault, t: float) -> dict:
            self._until(t + f.duration_s)
            for _ in range(20):  # the LiDAR simulator may be restarting: it must be uncovered in the end
                try:
                    done = self.bus.call(
                        "sim/lidar_fault", LidarFault(t=self.clock.now(), sensor=f.target, blocked=False)
                    )
                    return {"uncovered_t": round(self.clock.now(), 2), "uncovered": done.ok}
                except ServiceError:
                    time.sleep(0.5)
            return {"uncovered": False}

        self._lasting(fault, at_t, uncover)
        return True, reply.detail

    def _restart_router(self, fault: PlannedFault, at_t: float) -> dict:
        if self.router is None:
            return {"error": "this soak has no router process of its own"}
        self.router.kill()
        self._until(at_t + fault.duration_s)
        self.router.start()
        self.router.restarts += 1
        return {"router_down_until_t": round(self.clock.now(), 2)}

    def _lock_store(self, fault: PlannedFault, at_t: float) -> dict:
        if self.store_path is None:
            return {"error": "the store is not a file here"}
        db = sqlite3.connect(self.store_path, timeout=5.0, isolation_level=None)
        try:
            db.execute("BEGIN EXCLUSIVE")
            self._until(at_t + fault.duration_s)
            db.execute("ROLLBACK")
        finally:
            db.close()
        return {"store_back_t": round(self.clock.now(), 2)}

    def _bad_requests(self, fault: PlannedFault, at_t: float) -> dict:
        import httpx

        if self.api_base is None:
            return {"error": "no API in this run"}
        base, vid = self.api_base, self.vehicle_id
        forged = "eyJhbGciOiJIUzI1NiJ9.eyJzdWIiOiJhZG1pbiIsInJvbGUiOiJhZG1pbiJ9.c2lnbmF0dXJl"
        bad = [
            ("GET", f"/vehicles/{vid}/records", {}, None),  # no token
            ("GET", f"/vehicles/{vid}/records", {"Authorization": f"Bearer {forged}"}, None),  # forged
            ("GET", f"/vehicles/{vid}/records?start=yesterday&end=-1", {"Authorization": "Bearer x"}, None),
            ("GET", "/no/such/route", {}, None),
            ("GET", "/vehicles/../../etc/passwd/records", {}, None),
            ("POST", "/auth/token", {}, {"username": "nobody", "password": "wrong"}),
            ("POST", "/auth/token", {"Content-Type": "application/json"}, "{not json"),
            ("POST", f"/vehicles/{vid}/rearm", {"Authorization": "Bearer expired"}, None),
            ("DELETE", f"/vehicles/{vid}/records", {}, None),
        ]
        answers: dict[str, int] = {}
        with httpx.Client(base_url=base, verify=False, timeout=10.0) as client:  # the run's self-signed cert
            for i in range(fault.requests):
                method, path, headers, body = bad[i % len(bad)]
                try:
                    if isinstance(body, dict):
                        response = client.request(method, path, headers=headers, data=body)
                    else:
                        response = client.request(method, path, headers=headers, content=body)
                    key = str(response.status_code)
                except httpx.HTTPError as exc:
                    key = f"no answer ({type(exc).__name__})"
                answers[key] = answers.get(key, 0) + 1
        wrong = {k: n for k, n in answers.items() if not (k.isdigit() and 400 <= int(k) < 500)}
        return {"api_answers": answers, "api_not_4xx": sum(wrong.values())}

    def wait(self, timeout_s: float = 30.0) -> None:
        for thread in self.threads:
            thread.join(timeout=timeout_s)
