"""`--speed max`: the simulator moves the clock on only when every process it feeds has done its
step; a process that stops answering is left out after a while and rejoins when it answers."""

from __future__ import annotations

import threading

import pytest

from ares.core import config
from ares.core.clock import DrivenClock, ManualClock
from ares.core.config import LockstepSettings, Params, param
from ares.core.lockstep import LockstepMaster, Pacer
from ares.core.membus import MemoryNetwork
from ares.core.messages import ClockDone
from ares.core.node import Node, Output, grid_after

NEVER = threading.Event()


def master_with(*participants: str, max_wait_s: float = 5.0, start_wait_s: float = 5.0):
    network = MemoryNetwork()
    settings = LockstepSettings(participants=list(participants), max_wait_s=max_wait_s, start_wait_s=start_wait_s)
    master = LockstepMaster(network.bus("sim", ManualClock()), settings, start=0.0)
    reporter = network.bus("participants", ManualClock())

    def done(process: str, t: float, next_due: float) -> None:
        reporter.publish("clock/done", ClockDone(t=t, process=process, next_due=next_due))

    return master, done


def test_the_clock_waits_for_everyone_to_join_then_for_whoever_is_due():
    master, done = master_with("localization", "controller")
    assert not master.wait_done(NEVER, max_wall_s=0.05)  # nobody has joined yet
    done("localization", 0.0, 0.02)
    assert not master.wait_done(NEVER, max_wall_s=0.05)  # the controller has not
    done("controller", 0.0, 0.05)
    assert master.wait_done(NEVER, max_wall_s=0.05) and master.next_due() == 0.02
    master.tick(0.02)  # localization is due now
    assert not master.wait_done(NEVER, max_wall_s=0.05)
    done("localization", 0.02, 0.04)
    assert master.wait_done(NEVER, max_wall_s=0.05) and master.next_due() == 0.04
    master.tick(0.04)
    done("localization", 0.04, 0.06)
    assert master.wait_done(NEVER, max_wall_s=0.05) and master.next_due() == 0.05
    master.tick(0.05)  # the controller is due
    assert not master.wait_done(NEVER, max_wall_s=0.05)
    done("controller", 0.05, 0.1)
    assert master.wait_done(NEVER, max_wall_s=0.05) and master.next_due() == 0.06
    assert master.take_changes() == []


def test_a_process_that_stops_answering_is_left_out_then_rejoins():
    master, done = master_with("path_manager", max_wait_s=0.2)
    done("path_manager", 0.0, 0.05)
    master.tick(0.05)
    assert master.wait_done(NEVER, max_wall_s=2.0)  # after max_wait_s: gone on without it
    assert master.take_changes() == [("path_manager", True)]
    assert master.next_due() is None
    done("path_manager", 0.05, 0.1)  # restarted, it reports again
    assert master.take_changes() == [("path_manager", False)] and master.next_due() == 0.1


def test_a_process_the_supervisor_found_dead_is_left_out_at_once_then_rejoins():
    master, done = master_with("mpc", "path_manager", max_wait_s=60.0)
    done("mpc", 0.0, 0.1)
    done("path_manager", 0.0, 0.05)
    master.tick(0.1)
    done("path_manager", 0.1, 0.15)
    assert not master.wait_done(NEVER, max_wall_s=0.05)  # the mpc is due and silent: the clock waits
    master.leave("mpc")  # ... until the supervisor says it died
    assert master.wait_done(NEVER, max_wall_s=0.05) and master.next_due() == 0.15
    assert master.take_changes() == [("mpc", True)]
    master.leave("mpc")  # said once
    assert master.take_changes() == []
    done("mpc", 0.1, 0.2)  # restarted, it reports again
    assert master.take_changes() == [("mpc", False)] and master.next_due() == 0.15


def test_a_process_that_never_joins_is_left_out_after_the_start_wait():
    master, done = master_with("blackbox", "gnss", start_wait_s=0.2)
    done("gnss", 0.0, 0.05)
    assert master.wait_done(NEVER, max_wall_s=2.0)
    assert master.take_changes() == [("blackbox", True)]


def test_due_times_on_the_grid_are_exact():
    # 0.1 / 0.05 is 2.0000000000000004 in floating point: computed apart, due times must still meet
    assert grid_after(0.1, 0.05) == 0.15 and grid_after(0.15, 0.05) == 0.2 and grid_after(0.3, 0.1) == 0.4
    # a time a hair short of a grid point is that point: the next one is due
    assert grid_after(0.0, 0.02) == 0.02 and grid_after(0.019999999999, 0.02) == 0.04


class Counter(Node):
    """Steps at 20 Hz and says so."""

    name = "counter"
    rate = 20.0
    ticks = Output("sim/truth")

    class Params(Params):
        rate_hz: float = param(20.0, "loop rate", unit="Hz", gt=0)

    def setup(self) -> None:
        self.stepped: list[float] = []

    def step(self, now: float) -> None:
        self.stepped.append(now)


def test_a_node_steps_exactly_on_its_grid_and_holds_the_clock_until_done():
    cfg = config.core_defaults()
    cfg["lockstep"]["participants"] = ["counter"]
    network = MemoryNetwork()
    clock = DrivenClock(0.0)
    node = Counter(cfg, clock=clock, bus=network.bus("counter", clock))
    node.setup()
    master = LockstepMaster(network.bus("sim", ManualClock()), LockstepSettings(participants=["counter"]), start=0.0)
    runner = threading.Thread(target=node.loop, daemon=True)
    runner.start()
    try:
        t = 0.0
        while t < 0.5 - 1e-9:
            assert master.wait_done(NEVER, max_wall_s=5.0), f"the node did not finish its step at {t}"
            t = round(t + 0.01, 9)  # the physics grid: the node is due every fifth tick
            master.tick(t)
        assert master.wait_done(NEVER, max_wall_s=5.0)
    finally:
        node.stop()
        runner.join(5)
    assert node.stepped == pytest.approx([round(0.05 * k, 9) for k in range(1, 11)], abs=1e-12)


def test_a_participant_hears_the_time_only_when_it_is_due_and_the_others_now_and_then():
    network = MemoryNetwork()
    heard = {
        name: network.bus(name, ManualClock()).subscribe(topic, queue=100)
        for name, topic in (
            ("localization", "sim/clock/localization"),
            ("controller", "sim/clock/controller"),
            ("api", "sim/clock"),
        )
    }
    settings = LockstepSettings(participants=["localization", "controller"], broadcast_period_s=0.05)
    master = LockstepMaster(network.bus("sim", ManualClock()), settings, start=0.0)
    reporter = network.bus("participants", ManualClock())

    def done(process: str, t: float, next_due: float) -> None:
        reporter.publish("clock/done", ClockDone(t=t, process=process, next_due=next_due))

    done("localization", 0.0, 0.02)
    done("controller", 0.0, 0.05)
    t = 0.0
    while t < 0.2 - 1e-9:
        assert master.wait_done(NEVER, max_wall_s=1.0)
        t = master.next_due()
        master.tick(t)
        for name, period in (("localization", 0.02), ("controller", 0.05)):
            if master.participants[name].next_due <= t + 1e-9:
                done(name, t, grid_after(t, period))
    ticks = {name: [round(m.t, 9) for _, m in sub.drain()] for name, sub in heard.items()}
    assert ticks["localization"] == [0.02, 0.04, 0.06, 0.08, 0.1, 0.12, 0.14, 0.16, 0.18, 0.2]
    assert ticks["controller"] == [0.05, 0.1, 0.15, 0.2]
    assert ticks["api"] == [0.02, 0.08, 0.14, 0.2]  # at least 0.05 s apart


def test_the_pacer_keeps_to_real_time_and_does_not_sprint_after_falling_behind():
    pacer = Pacer(1.0)
    assert pacer.wait_s(0.0, 0.1, wall=100.0) == pytest.approx(0.1)  # ahead of the wall: wait
    assert pacer.wait_s(0.1, 0.2, wall=100.15) == pytest.approx(0.05)
    # the machine falls 2 s behind (a slow step): the step goes at once, then the pace counts from there
    assert pacer.wait_s(0.2, 0.3, wall=102.3) == 0.0
    assert pacer.wait_s(0.3, 0.4, wall=102.32) == pytest.approx(0.08)
    # steps that each take longer than they stand for: never a wait (the machine sets the pace)
    assert all(pacer.wait_s(0.4 + k * 0.1, 0.5 + k * 0.1, wall=102.6 + k * 0.15) == 0.0 for k in range(10))
    assert Pacer(2.0).wait_s(0.0, 1.0, wall=5.0) == pytest.approx(0.5)  # twice real time
