"""`--speed max`: the simulator drives the stack clock, and no process is left behind.

The simulator is the clock master. Every other process it feeds (the participants, listed in
`lockstep.participants` by `ares run` from the topic graph) steps on the period grid of its
own rate and, after each step, reports on `clock/done` the time its next step is due. The
master moves the clock from t to a later time only once every participant is due later than
t, i.e. has done its work for t. So a slow process slows the simulation instead of receiving
stale data, and a run gives the same figures as at real time.

A participant hears the time on its own key (`sim/clock/<process>`) when its step is due, and
only then: with a dozen processes on two cores, waking every process at every tick would cost
more than the steps themselves. The processes outside the lockstep (supervisor, API) hear it on
`sim/clock` every `broadcast_period_s`.

Between two ticks the simulator advances its physics and publishes its sensors (stamped with
their own times) before publishing the tick: a process stepping at time t has seen every
sensor message up to t, and the commands the bridge sent at t reach the physics after t.

A participant that does not report for `max_wait_s` (wall) is left out until it reports again
(a dead process restarted by the supervisor rejoins with its first report); one the supervisor
says is dead or restarting is left out at once (`leave`): the world does not stop for a crashed
process, as it would not on the vehicle. At start the master waits up to `start_wait_s` for
everyone to join.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from typing import cast

from ares.core.bus import BaseBus, Publisher, PublisherFamily
from ares.core.config import LockstepSettings
from ares.core.messages import ClockDone, ClockTick
from ares.core.schema import Msg

log = logging.getLogger("ares.core.lockstep")


@dataclass
class _Participant:
    next_due: float | None = None  # None: not joined yet
    heard_at: float = 0.0  # monotonic time of its last report
    left_out: bool = False


class LockstepMaster:
    def __init__(
        self,
        bus: BaseBus,
        settings: LockstepSettings,
        start: float,
        ticks: Publisher[Msg] | None = None,
        participant_ticks: PublisherFamily | None = None,
    ):
        self.bus = bus
        self.settings = settings
        self.t = float(start)
        self._cond = threading.Condition()
        self._started = time.monotonic()
        self._ticked_at = time.monotonic()  # a participant due now became due at the latest tick
        self.participants = {name: _Participant() for name in settings.participants}
        self.left_out_events: list[tuple[str, bool]] = []  # (process, left out?) for the node to report
        self._ticks = ticks or bus.publisher("sim/clock")
        self._participant_ticks = participant_ticks or PublisherFamily(bus, "sim/clock/*")
        self._broadcast_at = -float("inf")
        bus.subscribe("clock/done", on_message=self._on_done)

    def _on_done(self, _topic: str, msg: Msg) -> None:  # a transport thread: record and return
        done = cast(ClockDone, msg)  # the topic table's schema of clock/done, checked on receipt
        with self._cond:
            p = self.participants.get(done.process)
            if p is None:
                return
            # a participant repeats its report while it waits: only news counts as being heard
            if done.next_due != p.next_due:
                p.next_due, p.heard_at = done.next_due, time.monotonic()
            if p.left_out:
                p.left_out = False
                self.left_out_events.append((done.process, False))
            self._cond.notify_all()

    def leave(self, process: str) -> None:
        """Leave a participant out now (the supervisor found it dead or hung): it rejoins with its
        first report after its restart."""
        with self._cond:
            p = self.participants.get(process)
            if p is not None and not p.left_out and p.next_due is not None:
                p.left_out, p.next_due = True, None
                self.left_out_events.append((process, True))
                self._cond.notify_all()

    def next_due(self) -> float | None:
        """The earliest time a joined participant is due (None if none is)."""
        with self._cond:
            dues = [p.next_due for p in self.participants.values() if p.next_due is not None and not p.left_out]
        return min(dues) if dues else None

    def wait_done(self, stop: threading.Event, max_wall_s: float = 0.2) -> bool:
        """Block until every participant is due after the current time (True), or stop/max_wall_s."""
        deadline = time.monotonic() + max_wall_s
        with self._cond:
            while not stop.is_set():
                pending = self._pending(time.monotonic())
                if not pending:
                    return True
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._cond.wait(min(left, 0.05))
        return False

    def _pending(self, now: float) -> list[str]:
        waiting = []
        joining = now - self._started < self.settings.start_wait_s
        for name, p in self.participants.items():
            if p.left_out:
                continue
            if p.next_due is None:
                if joining:
                    waiting.append(name)
                else:
                    p.left_out = True
                    self.left_out_events.append((name, True))
                continue
            if p.next_due <= self.t + 1e-9:
                if now - max(self._ticked_at, p.heard_at) > self.settings.max_wait_s:
                    p.left_out = True
                    self.left_out_events.append((name, True))
                else:
                    waiting.append(name)
        return waiting

    def tick(self, t: float) -> None:
        """Move the clock to t: tell every participant due by then (and any not in step, so that
        it can catch up), and now and then everyone else."""
        with self._cond:
            self.t = t
            self._ticked_at = time.monotonic()
            due = [
                name
                for name, p in self.participants.items()
                if p.next_due is None or p.left_out or p.next_due <= t + 1e-9
            ]
            broadcast = t - self._broadcast_at >= self.settings.broadcast_period_s - 1e-9
            if broadcast:
                self._broadcast_at = t
        self._send(t, due, broadcast)

    def repeat_tick(self) -> None:
        """The current time again, to everyone, for a participant that missed it (started or
        restarted while the tick went out): it would otherwise wait for a tick that never comes."""
        self._send(self.t, list(self.participants), True)

    def _send(self, t: float, participants: list[str], broadcast: bool) -> None:
        tick = ClockTick(t=t)
        for name in participants:
            self._participant_ticks[name].put(tick)
        if broadcast:
            self._ticks.put(tick)

    def take_changes(self) -> list[tuple[str, bool]]:
        with self._cond:
            out, self.left_out_events = self.left_out_events, []
        return out


class Pacer:
    """`--speed paced`: the lockstep at most `pace` stack seconds per wall second. Behind (the
    machine too slow for the stack), it counts again from where it is instead of sprinting to
    catch up; a run on a big machine is real time, on a small one slower, never faster."""

    def __init__(self, pace: float, slack_s: float = 0.1):
        self.pace = float(pace)
        self.slack_s = slack_s
        self._anchor: tuple[float, float] | None = None  # (wall, stack time)

    def wait_s(self, now: float, target: float, wall: float) -> float:
        """Wall seconds to wait before stepping the clock from `now` to `target`, at wall time `wall`."""
        if self._anchor is None:
            self._anchor = (wall, now)
        elif self._due(self._anchor, target) < wall - self.slack_s:
            self._anchor = (wall, target)  # behind: step now, and count from here
        return max(self._due(self._anchor, target) - wall, 0.0)

    def _due(self, anchor: tuple[float, float], t: float) -> float:
        wall0, t0 = anchor
        return wall0 + (t - t0) / self.pace
