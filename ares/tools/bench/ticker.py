"""A tiny node for the supervisor's bench and tests: publishes a "tick" Event every second and
obeys a control file.

The control file is `$ARES_TEST_CONTROL_DIR/<process name>`. Its first word says what to do:

  (missing/empty)  tick normally
  exit N           exit with code N (read every step, so it also applies to restarts)
  hang             busy-loop forever while holding the GIL: the Zenoh liveliness token
                   (kept by Zenoh's own threads) stays alive but the heartbeat stops
  sleep            (read at start) never reach the loop: no token, no heartbeat
  ignore-term      (read at start) ignore SIGTERM, so a clean stop must escalate to SIGKILL
  grandchild       (read at start) start a `sleep` in its process group and write its pid to
                   `<control dir>/<process name>.grandchild`, to check nothing is orphaned
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from ares.core.messages import Event
from ares.core.node import Node

CONTROL_DIR_ENV = "ARES_TEST_CONTROL_DIR"


def control_file(directory: str | Path, process: str) -> Path:
    return Path(directory) / process


class Ticker(Node):
    """A test node: one "tick" event a second, and whatever its control file says."""

    name = "ticker"
    rate = 10.0

    def _command(self) -> list[str]:
        directory = os.environ.get(CONTROL_DIR_ENV)
        if not directory:
            return []
        try:
            return control_file(directory, self.name).read_text().split()
        except FileNotFoundError:
            return []

    def setup(self) -> None:
        self.ticks = 0
        self._last_tick = 0.0
        command = self._command()
        if command[:1] == ["ignore-term"]:
            signal.signal(signal.SIGTERM, signal.SIG_IGN)
        if command[:1] == ["grandchild"]:
            # exec'd at once by subprocess, so starting it after the Zenoh session is fine
            self.grandchild = subprocess.Popen(["sleep", "600"])
            path = control_file(os.environ[CONTROL_DIR_ENV], self.name + ".grandchild")
            path.write_text(str(self.grandchild.pid))
        if command[:1] == ["sleep"]:
            while True:  # stuck before declaring its token and sending a heartbeat
                time.sleep(1.0)

    def step(self, now: float) -> None:
        command = self._command()
        if command[:1] == ["exit"]:
            sys.exit(int(command[1]))
        if command[:1] == ["hang"]:
            self.log.warning("hanging in a busy loop that holds the GIL")
            sys.setswitchinterval(1e6)  # no other Python thread gets the GIL back
            while True:
                pass
        if now - self._last_tick >= 1.0:
            self._last_tick = now
            self.ticks += 1
            self.bus.publish(
                "events",
                Event(t=now, source=self.name, kind="tick", message=f"tick {self.ticks}", data={"pid": os.getpid()}),
            )
