"""The repository, the tests' run configurations, a headless run of the whole stack, polling."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

from ares.app import run_config as stack_config
from ares.core import config
from ares.core.localhost import free_port

REPO = Path(__file__).resolve().parents[2]
LIGHT_LIDARS = REPO / "tests" / "light_lidars.yaml"  # the perception run casts fewer LiDAR rays
NO_LIDARS = REPO / "tests" / "no_lidars.yaml"  # the others run without the LiDARs


def make_run_config(port: int, overrides: dict | None = None) -> dict:
    """The validated stack defaults (ares.app.run_config), without LiDARs, the bus on `port`."""
    base = config.deep_merge({"bus": {"router": f"tcp/127.0.0.1:{port}"}}, config.load_yaml(NO_LIDARS))
    return stack_config.build(overrides=config.deep_merge(base, overrides or {}))


def headless(*args: str, timeout_s: float = 600, lidars: Path = NO_LIDARS) -> dict:
    env = {**os.environ, "ARES_RUNS_DIR": os.environ.get("ARES_TEST_RUNS_DIR", "/tmp/ares-test-runs")}
    listen = f"tcp/127.0.0.1:{free_port()}"  # never the default ports of a stack running here
    isolation = ["--listen", listen, "--api-port", str(free_port()), "--config", str(lidars)]
    if "--store" not in args:  # keep test records out of the developer's data/
        isolation += ["--store", os.path.join(env["ARES_RUNS_DIR"], f"blackbox-{os.getpid()}-{free_port()}.sqlite")]
    proc = subprocess.run(
        [sys.executable, "-m", "ares.cli", "run", "--headless", *isolation, *args],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout_s,
        stdin=subprocess.DEVNULL,
    )
    lines = proc.stdout.strip().splitlines()
    assert proc.returncode == 0, f"exit {proc.returncode}\n{proc.stdout[-2000:]}\n{proc.stderr[-3000:]}"
    return json.loads(lines[-1])


def wait_until(condition, timeout_s: float, what: str, interval_s: float = 0.01):
    """Poll `condition` until it is true (its value is returned) or fail after timeout_s."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")
        time.sleep(interval_s)
