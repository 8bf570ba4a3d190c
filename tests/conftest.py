"""Shared fixtures for tests that use a real Zenoh bus.

- `port`: a free TCP port, so tests never collide with each other or a stack on 7447;
- `run_config`: the validated stack defaults (ares.run_config) with the bus pointed at that
  port (override more with the `make_run_config(port, overrides)` helper);
- `run_config_path`: that config written to a file, as ARES_RUN_CONFIG expects;
- `child_env`: the environment a node subprocess needs (ARES_RUN_CONFIG, PYTHONPATH, ...);
- `router`: an embedded router subprocess (`python -m ares.router`) listening on the port;
- `spawn_node`: start `python -m <module>` as a node process; killed at teardown.
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from ares import config, run_config as stack_config
from ares.localhost import free_port, stop_process, wait_for_port  # noqa: F401  (tests import them from here)

REPO = Path(__file__).resolve().parents[1]
# test modules import these helpers as `tests.conftest`: the repository root must be importable,
# under `pytest` too
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))


LIGHT_LIDARS = REPO / "tests" / "light_lidars.yaml"    # the perception run casts fewer LiDAR rays
NO_LIDARS = REPO / "tests" / "no_lidars.yaml"          # the others run without the LiDARs


def make_run_config(port: int, overrides: dict | None = None) -> dict:
    base = config.deep_merge({"bus": {"router": f"tcp/127.0.0.1:{port}"}}, config.load_yaml(NO_LIDARS))
    return stack_config.build(overrides=config.deep_merge(base, overrides or {}))


@pytest.fixture
def port() -> int:
    return free_port()


@pytest.fixture
def run_config(port) -> dict:
    return make_run_config(port)


@pytest.fixture
def run_config_path(tmp_path, run_config) -> Path:
    return config.write_run_config(run_config, tmp_path / "config.json")


@pytest.fixture
def child_env(run_config_path) -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO), env.get("PYTHONPATH", "")) if p)
    env[config.RUN_CONFIG_ENV] = str(run_config_path)
    env["PYTHONUNBUFFERED"] = "1"
    return env


@pytest.fixture
def spawn_node(child_env, tmp_path):
    """spawn_node("module:Class" or module, name, **env) -> Popen, in its own process group, output in
    tmp_path/<name>.log; every node still running is stopped at teardown."""
    procs: list[subprocess.Popen] = []

    def spawn(target: str, name: str, **extra_env: str) -> subprocess.Popen:
        env = {**child_env, "ARES_PROCESS_NAME": name, **extra_env}
        # a node class ("module:Class") runs as the supervisor runs it; anything else is a module
        command = ["-m", "ares.launch", target] if ":" in target else ["-m", target]
        with (tmp_path / f"{name}.log").open("ab") as out:
            proc = subprocess.Popen([sys.executable, *command], env=env, cwd=REPO, stdin=subprocess.DEVNULL,
                                    stdout=out, stderr=subprocess.STDOUT, process_group=0)
        procs.append(proc)
        return proc

    yield spawn
    for proc in procs:
        stop_process(proc, group=True)


@pytest.fixture
def router(run_config, spawn_node, port) -> dict:
    """An embedded router subprocess on `port`; yields the run config that points at it."""
    proc = spawn_node("ares.router", "router")
    try:
        wait_for_port(port)
    except TimeoutError:
        proc.kill()
        raise
    yield run_config
    stop_process(proc, group=True)
