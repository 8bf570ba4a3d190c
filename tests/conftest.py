"""Shared fixtures (what test modules share besides fixtures is in tests/helpers/).

- `port`: a free TCP port, so tests never collide with each other or a stack on 7447;
- `run_config`: the validated stack defaults (ares.app.run_config) with the bus pointed at that
  port (override more with tests.helpers.stack.make_run_config(port, overrides));
- `run_config_path`: that config written to a file, as ARES_RUN_CONFIG expects;
- `child_env`: the environment a node subprocess needs (ARES_RUN_CONFIG, PYTHONPATH, ...);
- `router`: an embedded router subprocess (`python -m ares.app.embedded_router`) listening on the port;
- `spawn_node`: start `python -m <module>` as a node process; killed at teardown;
- `store`: an embedded black-box store on a temporary file (the REST API's tests).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
# the test modules import tests.helpers: the repository root must be importable under `pytest` too
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from ares.core import config  # noqa: E402
from ares.core.localhost import free_port, stop_process, wait_for_port  # noqa: E402
from tests.helpers.api import open_test_store  # noqa: E402
from tests.helpers.stack import make_run_config  # noqa: E402


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """A whole-stack test is a stack test (scripts/test.sh runs `-m whole_stack` among those of `-m stack`)."""
    for item in items:
        if item.get_closest_marker("whole_stack") and not item.get_closest_marker("stack"):
            raise pytest.UsageError(f"{item.nodeid} is marked whole_stack but not stack")


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    """Which black-box stores the store contract (tests/test_store_contract.py) ran on, and which it
    could not, and why: a skipped engine is said in the summary, not only counted among the skips."""
    tested: set[str] = set()
    skipped: dict[str, str] = {}
    for reports in terminalreporter.stats.values():
        for report in reports:
            # user_properties come back from pytest-xdist's workers as lists: dict() takes both
            engine = dict(getattr(report, "user_properties", ())).get("store_engine")
            if engine is None or not isinstance(report, pytest.TestReport):
                continue
            if report.skipped:
                longrepr = report.longrepr
                reason = longrepr[2] if isinstance(longrepr, tuple) else str(longrepr)
                skipped[engine] = reason.removeprefix("Skipped: ")
            elif report.when == "call":
                tested.add(engine)
    not_tested = {engine: reason for engine, reason in skipped.items() if engine not in tested}
    if not tested and not not_tested:
        return
    line = "stores tested: " + (", ".join(sorted(tested)) or "none")
    if not_tested:
        line += "; not tested: " + ", ".join(f"{engine} ({reason})" for engine, reason in sorted(not_tested.items()))
    terminalreporter.write_line(line, yellow=bool(not_tested), bold=True)


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
        command = ["-m", "ares.core.launch", target] if ":" in target else ["-m", target]
        with (tmp_path / f"{name}.log").open("ab") as out:
            proc = subprocess.Popen(
                [sys.executable, *command],
                env=env,
                cwd=REPO,
                stdin=subprocess.DEVNULL,
                stdout=out,
                stderr=subprocess.STDOUT,
                process_group=0,
            )
        procs.append(proc)
        return proc

    yield spawn
    for proc in procs:
        stop_process(proc, group=True)


@pytest.fixture
def router(run_config, spawn_node, port) -> dict:
    """An embedded router subprocess on `port`; yields the run config that points at it."""
    proc = spawn_node("ares.app.embedded_router", "router")
    try:
        wait_for_port(port)
    except TimeoutError:
        proc.kill()
        raise
    yield run_config
    stop_process(proc, group=True)


@pytest.fixture
def store(tmp_path: Path):
    s = open_test_store(tmp_path / "blackbox.sqlite")
    yield s
    s.close()
