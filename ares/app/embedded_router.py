"""The embedded Zenoh router: one router-mode session on 127.0.0.1 hosted by the stack, so it
runs without an external zenohd. In deployment a zenohd container takes its place."""

from __future__ import annotations

import logging
import signal
import threading

import zenoh

from ares.core import config
from ares.core.bus import bus_settings, zenoh_config
from ares.core.node import setup_logging

log = logging.getLogger("router")


def main() -> None:
    setup_logging("router")
    cfg = config.current()
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    session = zenoh.open(zenoh_config(bus_settings(cfg), mode="router"))
    log.info("router listening on %s", cfg["bus"]["router"])
    try:
        # wait in short slices: the signal may be delivered to one of Zenoh's threads, and the
        # Python handler only runs once the main thread wakes up
        while not stop.wait(0.2):
            pass
    finally:
        session.close()


if __name__ == "__main__":
    main()
