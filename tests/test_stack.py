"""The whole stack, as a newcomer runs it: real processes, a real router, the simulated shuttle.

Two runs need it whole: the clock the simulator drives (`--speed max`, every process in lockstep)
against the wall clock, and a hung movement manager, which only real processes, the bridge's own
watchdog and the real supervisor can show. The drives that measure the stack's figures (the tour
through an RTK-loss zone, perception, the mission with killed processes, a receiver's log from the
south) run in one process on the in-memory bus: tests/test_in_process_stack.py.
"""

import math
import os
import signal
import threading
import time

import pytest

from ares.app import stack
from ares.app.engagement import engage_automatic
from ares.app.processes import for_run
from ares.app.run_options import RunOptions
from ares.app.supervisor import Supervisor
from ares.core import config
from ares.core.clock import ScaledClock
from ares.core.localhost import free_port
from ares.core.messages import DriveMode
from ares.core.route import load_route
from tests.helpers.records import assert_drive_recorded
from tests.helpers.stack import NO_LIDARS, headless, make_run_config

pytestmark = [pytest.mark.stack, pytest.mark.whole_stack]


def test_the_simulator_driven_clock_behind_the_wires_gives_the_wall_clock_result(tmp_path):
    """The same drive twice: on the wall clock (hurried) with the sensors on the bus, then on the
    clock the simulator drives with the simulator behind its wires (--wire: NMEA on a pty, CAN
    frames on udp_multicast, read by the drivers). Same lap: neither the lockstep nor the wires
    change the drive, and the drivers lose and refuse nothing."""
    route = tmp_path / "s_bend.csv"
    # 6 m straight, a 90 degree bend of ~15 m radius, 6 m straight
    points = [(x, 0.0) for x in range(0, 6, 2)]
    points += [(6 + 15 * math.sin(a), 15 - 15 * math.cos(a)) for a in [i * math.pi / 40 for i in range(21)]]
    points += [(21.0, 15 + y) for y in range(2, 8, 2)]
    route.write_text("\n".join(f"{x:.3f},{y:.3f}" for x, y in points))
    stores = {speed: tmp_path / f"blackbox_{speed}.sqlite" for speed in ("2", "max")}
    # the wall clock, hurried (timers as at real time), through the function `ares run` calls; then
    # `ares run` itself, its last line, on the clock the simulator drives
    scaled_run = stack.run(
        RunOptions(
            headless=True,
            route=str(route),
            speed=2.0,
            store=str(stores["2"]),
            config_files=(str(NO_LIDARS),),
            listen=f"tcp/127.0.0.1:{free_port()}",
            api_port=free_port(),
            run_dir=tmp_path / "run_2",
        )
    )
    assert (scaled_run.ok, scaled_run.exit_code, scaled_run.run_dir) == (True, 0, tmp_path / "run_2"), scaled_run.error
    assert scaled_run.figures["laps"] == 0 and scaled_run.figures["route"] == "s_bend"  # an open route, to its end
    scaled = scaled_run.summary()
    fast = headless("--route", str(route), "--speed", "max", "--wire", "--store", str(stores["max"]))
    assert (scaled["clock"], fast["clock"]) == ("scaled", "driven")
    assert "drivers" not in scaled
    drivers = fast["drivers"]
    # no LiDARs in this run; the RTK corrections from the NTRIP caster, through the receiver's port
    assert set(drivers) == {"gnss", "can", "ntrip", "gnss/rtcm"}
    for device, figures in drivers.items():
        assert figures["published"] > 0 and figures["connected"], (device, figures)
        assert figures["lost"] == 0 and figures["malformed"] == {}, (device, figures)
    assert fast["corrections"]["source"].startswith("ntrip 127.0.0.1:")
    assert fast["corrections"]["rtk_fixed_share"] > 0.9 and fast["corrections"]["outages"] == 0
    assert drivers["gnss"]["published"] >= 5 * fast["total_time_s"] * 0.9  # every 5 Hz epoch
    assert drivers["can"]["published"] >= (20 + 50) * fast["total_time_s"] * 0.9  # speed frames and the IMU
    # the margins are for a shared, noisy machine, where real time is what varies (the clock
    # starts when the stack is ready to drive, so process start-up is not in the lap)
    assert fast["lap_time_s"] == pytest.approx(scaled["lap_time_s"], rel=0.05)
    assert fast["distance_m"] == pytest.approx(scaled["distance_m"], rel=0.02)
    assert abs(fast["xte_rmse_m"] - scaled["xte_rmse_m"]) < 0.03
    assert abs(fast["xte_max_m"] - scaled["xte_max_m"]) < 0.08
    # the recorder is one of the processes the simulator waits for: a record for every second of
    # either drive, and `ares run` counts them once the stack has stopped
    for speed, result in (("2", scaled), ("max", fast)):
        assert_drive_recorded(stores[speed], result, math.floor(result["total_time_s"]))


def test_a_hung_movement_manager_stops_the_vehicle_and_the_supervisor_brings_it_back(tmp_path):
    """The movement manager is the bridge's only source of commands: hung, the bridge's watchdog
    stops the shuttle (a hung control manager is the movement gate's missing input: a controlled
    stop, tests/test_movement.py)."""
    cfg = make_run_config(
        free_port(), {"blackbox_store": {"uri": str(tmp_path / "bb.sqlite")}, "api": {"port": free_port()}}
    )
    clock = ScaledClock(2.0)
    sup = Supervisor(cfg, for_run(True, cfg["lidars"]), tmp_path / "run", clock)
    stop = threading.Event()
    sup.start()
    loop = threading.Thread(target=sup.run, args=(stop,), daemon=True)
    loop.start()
    try:
        bus = sup.bus
        truth = bus.subscribe("sim/truth")
        car = bus.subscribe("dbw/car_state")
        deadline = time.monotonic() + 60
        while truth.latest is None and time.monotonic() < deadline:
            time.sleep(0.1)
        engage_automatic(bus, car, stop)
        while truth.latest.v < 2.0 and time.monotonic() < deadline:
            time.sleep(0.1)
        assert truth.latest.v >= 2.0, "the shuttle never got going"

        speed_before = truth.latest.v
        os.kill(sup.children["movement_manager"].pid, signal.SIGSTOP)  # hung: token and heartbeat go quiet
        killed = time.monotonic()
        while not car.latest.watchdog_tripped and time.monotonic() - killed < 5:
            time.sleep(0.02)
        assert car.latest.watchdog_tripped, "the bridge did not notice the silent movement manager"
        assert car.latest.v_command == 0.0 and car.latest.kappa_command == 0.0
        assert car.latest.mode == DriveMode.AUTOMATIC
        slowest = speed_before
        # the supervisor restarts the movement manager; commands return and the shuttle drives on
        while (car.latest.watchdog_tripped or truth.latest.v < 1.0) and time.monotonic() - killed < 30:
            slowest = min(slowest, truth.latest.v)
            time.sleep(0.02)
        assert sup.children["movement_manager"].restarts == 1
        assert slowest < 0.5, "the shuttle did not stop while the movement manager was hung"
        assert not car.latest.watchdog_tripped and truth.latest.v >= 1.0
        route = load_route(config.core(cfg))
        assert abs(route.project(truth.latest.x, truth.latest.y, truth.latest.s)[1]) < 0.5
    finally:
        stop.set()
        loop.join(timeout=5)
        sup.stop()
