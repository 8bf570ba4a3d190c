"""Access-control refusals made visible: a vehicle that publishes under another vehicle's id is
refused by the fleet router, and the fleet hears of it as an event.

Zenoh's router says what its access control refuses in its log, at trace level of the target
ACL_TARGET: "<zid> on ...+CertCommonName(shuttle01)+Username(shuttle01)+Transport(Tls)+<zid> is
unauthorized to Put (ingress) on ares/shuttle02/...". `ares deploy router --report-refusals`
turns its own log on for that target, reads it through a pipe in place of its stdout (what is
not a refusal goes on to the real stdout), and publishes each refusal of a vehicle reaching
under another vehicle's id as an `acl_refused` event under `ares/<fleet id>/events`, from the
router's own session: the fleet's black box stores it, the fleet page shows it. A burst of the
same refusal (who, key, action) is one event per REPEAT_S. zenohd logs the same lines (RUST_LOG=ACL_TARGET=trace);
with zenohd the events need its log fed to this reader (docs/deploy.md).
"""

from __future__ import annotations

import os
import queue
import re
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

ACL_TARGET = "zenoh::net::routing::interceptor::access_control"
REPEAT_S = 10.0
_REFUSED = re.compile(
    r"on (?P<subject>\S+) is unauthorized to (?P<action>Put|Delete|Declare/Undeclare Liveliness Token|"
    r"Declare/Undeclare Queryable) \(ingress\) on (?P<key>ares/(?P<vehicle>[^/\s]+)/\S*)"
)
_ANSI = re.compile(r"\x1b\[[0-9;]*m")


@dataclass(frozen=True)
class Refusal:
    who: str  # the vehicle id its certificate and user give
    action: str
    key: str
    under: str  # the vehicle id of the key

    def message(self) -> str:
        what = f"{self.who} tried to {self.action.lower()} under {self.under}'s id ({self.key})"
        return f"{what}: refused by access control"


def parse(line: str) -> Refusal | None:
    """A refusal of a vehicle reaching under another vehicle's id, from one log line; None else."""
    found = _REFUSED.search(_ANSI.sub("", line))
    if found is None:
        return None
    subject = found["subject"]
    names = re.findall(r"(?:CertCommonName|Username)\(([^)]+)\)", subject)
    if not names:
        return None  # a link without an identity (the fleet's own services): not a vehicle's
    who = names[0]
    if who == found["vehicle"]:
        return None  # under its own id: some other rule's matter (a fleet-only action)
    return Refusal(who, found["action"], found["key"], found["vehicle"])


class RefusalReader:
    """The router process's stdout replaced by a pipe read here (call `install` before the Zenoh
    session opens its log). `on_refusal` runs on a thread of its own, at most once per REPEAT_S
    for the same (who, key, action)."""

    def __init__(self, on_refusal: Callable[[Refusal], None]):
        self.on_refusal = on_refusal
        # reported from a thread of its own: publishing makes the router log (into the pipe), and
        # the reader must go on draining the pipe meanwhile, or a full pipe stalls the router
        self._found: queue.SimpleQueue[Refusal] = queue.SimpleQueue()
        self._last: dict[tuple[str, str, str], float] = {}
        self.seen = 0

    def install(self) -> None:
        import zenoh

        read_end, write_end = os.pipe()
        self._out = os.fdopen(os.dup(1), "w", buffering=1)
        os.dup2(write_end, 1)
        os.close(write_end)
        self._pipe = os.fdopen(read_end, "r", errors="replace")
        threading.Thread(target=self._read, name="refusals", daemon=True).start()
        threading.Thread(target=self._report, name="refusal-events", daemon=True).start()
        os.environ.pop("RUST_LOG", None)  # the target's level is what this reader needs
        zenoh.init_log_from_env_or(f"warn,{ACL_TARGET}=trace")

    def _read(self) -> None:
        for line in self._pipe:
            if "is authorized" in line or ("is unauthorized" in line and self._refused(line)):
                continue  # the access control's every decision: not for the operator's screen
            if ACL_TARGET not in line:
                self._out.write(line)

    def _refused(self, line: str) -> bool:
        refusal = parse(line)
        if refusal is None:
            return True
        self.seen += 1
        key = (refusal.who, refusal.key, refusal.action)
        now = time.monotonic()
        if now - self._last.get(key, -REPEAT_S) >= REPEAT_S:
            self._last[key] = now
            self._found.put(refusal)
        return True

    def _report(self) -> None:
        while True:
            self.on_refusal(self._found.get())

    def print(self, text: str) -> None:
        """What the router itself prints, to the real stdout."""
        self._out.write(text + "\n")
