"""The stack's clock.

Every process of a run shares one epoch (wall-clock seconds, passed down by the supervisor)
and one speed factor. Stack time is (wall − epoch) · speed, so a simulated run at `--speed 5`
goes five times faster for every process at once, and a respawned process rejoins the same
timeline. Rates and timeouts in config are in stack seconds; process-health deadlines
(heartbeats, leases) stay in wall seconds because they judge the computer, not the vehicle.
"""
from __future__ import annotations

import os
import time

EPOCH_ENV = "ARES_CLOCK_EPOCH"
SPEED_ENV = "ARES_CLOCK_SPEED"


class Clock:
    def __init__(self, epoch: float | None = None, speed: float = 1.0):
        if speed <= 0:
            raise ValueError("clock speed must be positive")
        self.epoch = time.time() if epoch is None else epoch
        self.speed = speed

    @classmethod
    def from_env(cls) -> "Clock":
        epoch = os.environ.get(EPOCH_ENV)
        return cls(float(epoch) if epoch else None, float(os.environ.get(SPEED_ENV, "1")))

    def env(self) -> dict[str, str]:
        return {EPOCH_ENV: repr(self.epoch), SPEED_ENV: repr(self.speed)}

    def now(self) -> float:
        """Stack time in seconds since the run began."""
        return (time.time() - self.epoch) * self.speed

    def wall_for(self, stack_seconds: float) -> float:
        return stack_seconds / self.speed

    def sleep(self, stack_seconds: float) -> None:
        if stack_seconds > 0:
            time.sleep(stack_seconds / self.speed)

    def sleep_until(self, stack_time: float) -> None:
        self.sleep(stack_time - self.now())
