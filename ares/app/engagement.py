"""Engaging a running stack as a safety driver and the navigation system would: waiting for its
processes (`wait_for`, `wait_until_ready_to_drive`), then the Auto/Manual button on the simulated
panel and the `set_automatic_mode` service (`engage_automatic`). `RunFailed` is how a run that
cannot go on says why (a headless drive's figures so far with it)."""

from __future__ import annotations

import threading
import time

from ares.core.bus import Bus, ServiceError
from ares.core.messages import DriveMode, DriverCommand

STARTUP_TIMEOUT_S = 60.0  # wall seconds for every process to come up and publish
ENGAGE_TIMEOUT_S = 10.0
READY_MAX_AGE_S = 0.5  # stack seconds: the controller's status is this fresh when it is ready


class RunFailed(RuntimeError):
    figures: dict | None = None  # a headless run's figures up to the failure


def wait_for(condition, timeout_s: float, what: str, stop: threading.Event) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        if stop.is_set():
            raise RunFailed("interrupted")
        if time.monotonic() > deadline:
            raise RunFailed(f"timed out waiting for {what}")
        time.sleep(0.05)


def wait_until_ready_to_drive(bus: Bus, stop: threading.Event) -> None:
    """Until the control manager forwards a controller's candidate (not a stop): localization, the
    path manager and a controller are up and trusted. Process start-up takes wall seconds, which
    at --speed X are X times as many vehicle seconds: a run engaged before this would count them
    in its lap time."""
    status = bus.subscribe("control/status")
    try:
        wait_for(
            lambda: status.alive(READY_MAX_AGE_S) and status.latest.controller != "stop",
            STARTUP_TIMEOUT_S,
            "a controller in charge (localization, path manager, a controller and the control manager up)",
            stop,
        )
    finally:
        bus.unsubscribe(status)


def engage_automatic(bus: Bus, car_state, stop: threading.Event) -> None:
    """When the stack is ready to drive: Manual -> Ready with the panel button, then Ready ->
    Automatic with the service."""
    wait_for(lambda: car_state.latest is not None, STARTUP_TIMEOUT_S, "the drive-by-wire bridge", stop)
    wait_until_ready_to_drive(bus, stop)
    if car_state.latest.mode == DriveMode.MANUAL:
        bus.call("sim/driver", DriverCommand(t=bus.clock.now(), action="BUTTON"))
        wait_for(lambda: car_state.latest.mode == DriveMode.READY, ENGAGE_TIMEOUT_S, "Ready mode", stop)
    deadline = time.monotonic() + ENGAGE_TIMEOUT_S
    while True:
        try:
            reply = bus.call("set_automatic_mode")
            if reply.accepted:
                return
            reason = reply.reason
        except ServiceError as exc:
            reason = str(exc)
        if time.monotonic() > deadline:
            raise RunFailed(f"Automatic mode refused: {reason}")
        time.sleep(0.2)
