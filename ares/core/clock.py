"""The stack's clock: one timeline for every process of a run, and it never goes back.

Four kinds, chosen by `ares run` and passed to every child through the environment:

- wall (the vehicle): real seconds since the run's epoch, on CLOCK_MONOTONIC (shared by every
  process and container of the machine): a step of the system clock (NTP once 4G is back, a
  wrong RTC at boot) neither freezes nor rewinds the stack; the calendar time of stack time 0 is
  read once, at the start of the run.
- scaled (simulation, `--speed X`): CLOCK_MONOTONIC times X since the run's epoch.
- driven (simulation, `--speed max`): the simulator publishes the time (`sim/clock`) and moves
  it on only once every process it feeds has done its work (ares.core.lockstep); each process's
  clock is the latest time it heard.
- manual (tests): set by hand.

Rates and timeouts in config are in stack seconds; process-health deadlines (heartbeats, leases)
stay in wall seconds because they judge the computer, not the vehicle. `utc(t)` gives the
vehicle's calendar time of a stack time (the black box's record times): at --speed 5 it runs
ahead of the wall clock.
"""

from __future__ import annotations

import math
import os
import threading
import time
from collections.abc import Mapping
from datetime import UTC, datetime

MODE_ENV = "ARES_CLOCK_MODE"
EPOCH_ENV = "ARES_CLOCK_EPOCH"  # wall mode: time.time() at t = 0; scaled: time.monotonic() at t = 0
UTC_EPOCH_ENV = "ARES_CLOCK_UTC_EPOCH"  # time.time() at t = 0: the calendar time of stack time 0
SPEED_ENV = "ARES_CLOCK_SPEED"
START_ENV = "ARES_CLOCK_START"  # driven: the latest time known when the process was started


class Clock:
    """Base of the clocks. `now()` is stack seconds since the run began."""

    mode = "base"

    def __init__(self, utc_epoch: float | None = None):
        self.utc_epoch = time.time() if utc_epoch is None else float(utc_epoch)

    def now(self) -> float:
        raise NotImplementedError

    def utc(self, t: float) -> datetime:
        return datetime.fromtimestamp(self.utc_epoch + t, tz=UTC)

    def wait_until(self, t: float, stop: threading.Event, max_wall_s: float) -> bool:
        """Block until stack time t, `stop` or at most max_wall_s of wall time; True once t is reached."""
        raise NotImplementedError

    def sleep(self, stack_seconds: float) -> None:
        """Let stack_seconds of stack time pass (a helper for tools and tests)."""
        target = self.now() + stack_seconds
        never = threading.Event()
        while not self.wait_until(target, never, 0.5):
            pass

    def env(self) -> dict[str, str]:
        return {MODE_ENV: self.mode, UTC_EPOCH_ENV: repr(self.utc_epoch)}

    @staticmethod
    def from_env(environ: Mapping[str, str] | None = None) -> Clock:
        e = os.environ if environ is None else environ
        mode = e.get(MODE_ENV, "wall")
        utc_epoch = float(e[UTC_EPOCH_ENV]) if e.get(UTC_EPOCH_ENV) else None
        if mode == "wall":
            return WallClock(float(e[EPOCH_ENV]) if e.get(EPOCH_ENV) else None, utc_epoch)
        if mode == "scaled":
            return ScaledClock(
                float(e.get(SPEED_ENV, "1")), float(e[EPOCH_ENV]) if e.get(EPOCH_ENV) else None, utc_epoch
            )
        if mode == "driven":
            return DrivenClock(float(e.get(START_ENV, "0")), utc_epoch)
        raise ValueError(f"{MODE_ENV}={mode!r}: expected wall, scaled or driven")


class ScaledClock(Clock):
    """Simulation at `speed` times real time, on CLOCK_MONOTONIC."""

    mode = "scaled"

    def __init__(self, speed: float = 1.0, epoch: float | None = None, utc_epoch: float | None = None):
        if not (speed > 0 and math.isfinite(speed)):
            raise ValueError("clock speed must be a positive number")
        self.speed = float(speed)
        self.epoch = time.monotonic() if epoch is None else float(epoch)
        super().__init__(utc_epoch if utc_epoch is not None else time.time() - (time.monotonic() - self.epoch))

    def now(self) -> float:
        return (time.monotonic() - self.epoch) * self.speed

    def wait_until(self, t: float, stop: threading.Event, max_wall_s: float) -> bool:
        delay = (t - self.now()) / self.speed
        if delay > 0:
            stop.wait(min(delay, max_wall_s))
        return self.now() >= t

    def env(self) -> dict[str, str]:
        return {**super().env(), EPOCH_ENV: repr(self.epoch), SPEED_ENV: repr(self.speed)}


class WallClock(ScaledClock):
    """The vehicle's clock: real seconds since the run began."""

    mode = "wall"

    def __init__(self, epoch: float | None = None, utc_epoch: float | None = None):
        super().__init__(1.0, epoch, utc_epoch)


class DrivenClock(Clock):
    """The simulator's time as last heard (`advance`, from the `sim/clock` subscription)."""

    mode = "driven"
    speed = math.inf

    def __init__(self, start: float = 0.0, utc_epoch: float | None = None):
        super().__init__(utc_epoch)
        self._t = float(start)
        self._changed = threading.Condition()
        self._waiting_for: list[float] = []  # the times waiters need: earlier ticks wake nobody

    def now(self) -> float:
        return self._t

    def advance(self, t: float) -> None:
        with self._changed:
            if t > self._t:
                self._t = t
                if any(t >= needed for needed in self._waiting_for):
                    self._changed.notify_all()

    def wait_until(self, t: float, stop: threading.Event, max_wall_s: float) -> bool:
        deadline = time.monotonic() + max_wall_s
        with self._changed:
            self._waiting_for.append(t)
            try:
                while self._t < t and not stop.is_set():
                    left = deadline - time.monotonic()
                    if left <= 0:
                        break
                    self._changed.wait(min(left, 0.05))  # 50 ms: notice `stop` without a second condition
            finally:
                self._waiting_for.remove(t)
            return self._t >= t

    def env(self) -> dict[str, str]:
        return {**super().env(), START_ENV: repr(self._t)}


class ManualClock(Clock):
    """Time that moves only when a test says so."""

    mode = "manual"
    speed = math.inf

    def __init__(self, t: float = 0.0, utc_epoch: float | None = None):
        super().__init__(utc_epoch)
        self._t = float(t)

    def now(self) -> float:
        return self._t

    def set(self, t: float) -> None:
        if t < self._t:
            raise ValueError(f"the clock does not go back ({t} < {self._t})")
        self._t = float(t)

    def advance(self, dt: float) -> float:
        self.set(self._t + dt)
        return self._t

    def wait_until(self, t: float, stop: threading.Event, max_wall_s: float) -> bool:
        return self._t >= t
