"""Self-awareness checks (managers/awareness.py): each sensor and process fault gives its
level and a cause that says what is wrong; level 1 outranks level 2; faults clear by themselves."""

from __future__ import annotations

import pytest

from ares.core.messages import Imu, LidarHealth, LidarStatus, ProcessState, ProcessStatus, SupervisorState
from managers.awareness import CRITICAL, LOW, NOMINAL, AwarenessChecks, AwarenessParams
from tests.helpers.gnss import fix

P = AwarenessParams()
LIDARS = ["front_left", "front_right", "roof"]
WELL = LidarHealth(rate_hz=10.0, points=20000, road_points=3000, age_s=0.05)


def imu(t: float, k: int) -> Imu:
    return Imu(
        t=t,
        yaw=0.1,
        roll=0.0,
        pitch=0.0,
        gyro_x=0.001 * k,
        gyro_y=0.0,
        gyro_z=0.01,
        accel_x=0.0,
        accel_y=0.0,
        accel_z=9.81,
    )


def supervisor(t: float, **states: ProcessState) -> SupervisorState:
    names = ("localization", "mpc", "movement_manager", "blackbox")
    return SupervisorState(
        t=t,
        processes=[
            ProcessStatus(
                name=n,
                state=states.get(n, ProcessState.RUNNING),
                safety_relevant=n != "blackbox",
                last_failure="liveliness lost" if n in states else "",
            )
            for n in names
        ],
    )


def fed(
    seconds: float = 3.0,
    imu_hz: float = 50.0,
    gnss_hz: float = 5.0,
    frozen_after: float | None = None,
    rtk_until: float | None = None,
    var: float = 2.5e-5,
) -> AwarenessChecks:
    checks = AwarenessChecks(P, LIDARS, started_at=0.0)
    for k in range(int(seconds * imu_hz)):
        t = k / imu_hz
        checks.on_imu(imu(t, k if frozen_after is None or t < frozen_after else int(frozen_after * imu_hz)))
    for k in range(int(seconds * gnss_hz)):
        t = k / gnss_hz
        checks.on_gnss(fix(t, rtk=rtk_until is None or t < rtk_until, var=var))
    return checks


def lidars(t: float, **faults: LidarHealth) -> LidarStatus:
    return LidarStatus(t=t, sensors={name: faults.get(name, WELL) for name in LIDARS})


def test_all_well_is_nominal():
    found = fed().assess(3.0, lidars(2.95), supervisor(2.9))
    assert found.level == NOMINAL and found.causes == []
    assert set(found.sensors.values()) == {"ok"} and set(found.processes) == {"localization", "mpc", "movement_manager"}


@pytest.mark.parametrize(
    "fault,level,says",
    [
        (
            {"roof": LidarHealth(rate_hz=10.0, points=3, road_points=0, blind=True)},
            CRITICAL,
            "lidar roof: blind: no points (covered or failed)",
        ),
        (
            {"front_left": LidarHealth(rate_hz=10.0, points=9000, road_points=12)},
            LOW,
            "lidar front_left: 12 road points < 200 (the road hidden)",
        ),
        (
            {"front_right": LidarHealth(rate_hz=4.0, points=9000, road_points=900)},
            CRITICAL,
            "lidar front_right: 4.0 Hz < 8",
        ),
    ],
)
def test_a_blocked_or_slow_lidar_is_level_1(fault, level, says):
    checks = fed()
    checks.assess(0.95, lidars(0.9), supervisor(0.9))  # the LiDARs have been running since
    found = checks.assess(3.0, lidars(2.95, **fault), supervisor(2.9))
    assert found.level == level and found.causes == [says]


def test_no_lidar_status_is_level_2():
    found = fed().assess(3.0, lidars(1.5), supervisor(2.9))
    assert found.level == LOW and found.causes == ["lidars: no status from perception"]


@pytest.mark.parametrize(
    "kwargs,says",
    [
        ({"imu_hz": 20.0}, "imu: 20 Hz < 30"),
        ({"frozen_after": 2.0}, "imu: frozen: the same reading for 1.0 s"),
    ],
)
def test_imu_faults_are_level_2(kwargs, says):
    found = fed(**kwargs).assess(3.0, lidars(2.95), supervisor(2.9))
    assert found.level == LOW and found.causes == [says]


def walk(
    seconds: float,
    gnss_hz: float = 5.0,
    var: float = 2.5e-5,
    rtk_until: float | None = None,
    rtk_again: float | None = None,
):
    """The manager's life: IMU at 50 Hz and GNSS as asked, checked every 0.5 s; the assessments."""
    checks = AwarenessChecks(P, LIDARS, started_at=0.0)
    found, k_imu, k_gnss = [], 0, 0
    for step in range(1, int(seconds * 2) + 1):
        t = step / 2
        while k_imu / 50 <= t:
            checks.on_imu(imu(k_imu / 50, k_imu))
            k_imu += 1
        while k_gnss / gnss_hz <= t:
            tg = k_gnss / gnss_hz
            rtk = rtk_until is None or tg < rtk_until or (rtk_again is not None and tg >= rtk_again)
            checks.on_gnss(fix(tg, rtk=rtk, var=var))
            k_gnss += 1
        found.append((t, checks.assess(t, lidars(t - 0.05), supervisor(t - 0.05))))
    return found


@pytest.mark.parametrize(
    "kwargs,says",
    [
        ({"gnss_hz": 2.0}, "2.0 Hz < 4"),
        ({"var": 0.8}, "variance 1.60 m² > 1.00"),
        ({"rtk_until": 0.5}, "no RTK corrections"),
    ],
)
def test_a_gnss_outage_is_the_control_managers_for_5_minutes_then_level_2(kwargs, says):
    found = walk(320.0, **kwargs)
    assert all(a.level == NOMINAL for t, a in found if t <= 300.0)
    t, last = found[-1]
    assert last.level == LOW and len(last.causes) == 1
    assert last.causes[0].startswith("gnss: an outage longer than 300 s: " + says)
    assert last.sensors["gnss"].startswith(says)


def test_corrections_back_clear_the_outage():
    found = walk(420.0, rtk_until=50.0, rtk_again=400.0)
    levels = {t: a.level for t, a in found}
    assert levels[340.0] == NOMINAL and levels[360.0] == LOW and levels[401.0] == NOMINAL


def test_a_process_down_is_level_2_and_only_whitelisted_ones_count():
    checks = fed()
    found = checks.assess(
        3.0, lidars(2.95), supervisor(2.9, mpc=ProcessState.RESTARTING, blackbox=ProcessState.RESTARTING)
    )
    assert found.level == LOW and found.causes == ["process mpc: restarting (liveliness lost)"]
    assert checks.assess(3.0, lidars(2.95), None).causes == ["processes: no state from the supervisor"]


def test_level_1_outranks_level_2_and_every_cause_is_kept():
    found = fed(imu_hz=10.0).assess(
        3.0,
        lidars(2.95, roof=LidarHealth(rate_hz=0.0, points=0, road_points=0, blind=True)),
        supervisor(2.9, mpc=ProcessState.STARTING),
    )
    assert found.level == CRITICAL and len(found.causes) == 3


def test_without_lidars_only_the_other_checks_run():
    checks = AwarenessChecks(P, [], started_at=0.0)
    for k in range(150):
        checks.on_imu(imu(k / 50, k))
    for k in range(15):
        checks.on_gnss(fix(k / 5))
    assert checks.assess(3.0, None, supervisor(2.9)).level == NOMINAL


def test_a_lidars_rate_is_judged_once_it_has_run_a_window_but_a_blind_one_at_once():
    checks = fed()
    starting = LidarHealth(rate_hz=3.0, points=20000, road_points=3000)
    assert checks.assess(3.0, lidars(2.95, roof=starting), supervisor(2.9)).level == NOMINAL
    assert checks.assess(5.0, lidars(4.95, roof=starting), supervisor(4.9)).level == CRITICAL
    blind = AwarenessChecks(P, LIDARS, started_at=0.0)
    found = blind.assess(
        0.5, lidars(0.45, roof=LidarHealth(rate_hz=1.0, points=0, road_points=0, blind=True)), supervisor(0.4)
    )
    assert found.level == CRITICAL


def test_lidars_back_after_a_gap_get_a_window_again_before_their_rate_counts():
    checks = fed(seconds=12.0)
    starting = LidarHealth(rate_hz=3.0, points=20000, road_points=3000)
    assert checks.assess(3.0, lidars(2.95), supervisor(2.9)).level == NOMINAL
    gap = checks.assess(6.0, None, supervisor(5.9))  # perception restarted: nothing
    assert gap.level == LOW and "lidars: no status from perception" in gap.causes
    assert checks.assess(8.0, lidars(7.95, roof=starting), supervisor(7.9)).level == NOMINAL  # warming up again
    assert checks.assess(10.5, lidars(10.45, roof=starting), supervisor(10.4)).level == CRITICAL


def test_a_restarted_perceptions_rates_count_once_it_has_counted_a_window():
    checks = fed(seconds=12.0)
    assert checks.assess(3.0, lidars(2.95), supervisor(2.9)).level == NOMINAL
    # perception restarted within a status period: no gap, but its rates start from nothing
    restarting = LidarHealth(rate_hz=1.0, points=20000, road_points=3000, counting_s=0.1)
    assert checks.assess(3.1, lidars(3.05, roof=restarting, front_left=restarting), supervisor(3.0)).level == NOMINAL
    slow = LidarHealth(rate_hz=3.0, points=20000, road_points=3000, counting_s=2.5)
    assert checks.assess(6.0, lidars(5.95, roof=slow), supervisor(5.9)).level == CRITICAL


def test_a_corrections_outage_is_named_for_what_it_is():
    """Without RTK, the corrections' state names the cause: a 4G link down, or corrections too old;
    fresh corrections leave no corrections problem (then it is the sky, not the link)."""
    from ares.core.messages import CorrectionsStatus

    checks = fed(seconds=10.0, rtk_until=1.0)
    down = CorrectionsStatus(t=9.5, source="ntrip 10.0.0.1:2101/BASE", link="down", age_s=23.0, frames=40)
    down = down.model_copy(update={"detail": "silent: no byte for 5 s"})
    checks.on_corrections(down)
    found = checks.assess(10.0, lidars(9.95), supervisor(9.95))
    assert found.level == NOMINAL  # the control manager's, for five minutes
    assert found.sensors["corrections"] == "link down (silent: no byte for 5 s), the newest 23 s old"
    assert found.sensors["gnss"].startswith(
        "no RTK corrections (link down (silent: no byte for 5 s), the newest 23 s old)"
    )
    old = CorrectionsStatus(t=9.5, source="simulated 4G link", link="streaming", age_s=12.0, frames=40)
    checks.on_corrections(old)
    assert (
        checks.assess(10.0, lidars(9.95), supervisor(9.95)).sensors["corrections"]
        == "streaming but the newest 12 s old"
    )
    fresh = CorrectionsStatus(t=9.5, source="simulated 4G link", link="streaming", age_s=0.4, frames=41)
    checks.on_corrections(fresh)
    found = checks.assess(10.0, lidars(9.95), supervisor(9.95))
    assert found.sensors["corrections"] == "ok" and found.sensors["gnss"].startswith("no RTK corrections for")


def blackbox_status(t: float, *, store_up: bool = True, dropped: int = 0, lost: int = 0, in_memory: int = 0):
    from ares.core.messages import BlackboxStatus

    return BlackboxStatus(
        t=t,
        store_up=store_up,
        written=int(t),
        events_written=0,
        dropped=dropped,
        events_dropped=0,
        lost=lost,
        store_faults=0 if store_up else 3,
        spooled=0,
        in_memory=in_memory,
        last_error="" if store_up else "database or disk is full",
    )


def test_a_black_box_store_down_holding_every_record_is_said_and_is_no_cause():
    """The store on a full disk while the writer's memory holds the records: nothing is lost, the
    shuttle drives on, and the operator sees why the black box is not writing."""
    checks = fed()
    checks.on_blackbox(blackbox_status(2.0))
    checks.on_blackbox(blackbox_status(3.0, store_up=False, in_memory=40))
    found = checks.assess(3.0, lidars(2.95), supervisor(2.9))
    assert found.level == NOMINAL and found.causes == []
    assert found.sensors["blackbox"] == "store down (0 spooled, 40 in memory): database or disk is full"


def test_a_black_box_losing_records_is_level_2_until_it_keeps_everything_again():
    checks = fed(seconds=30.0)
    checks.on_blackbox(blackbox_status(2.0, store_up=False, in_memory=7200))
    assert checks.assess(2.0, lidars(1.95), supervisor(1.9)).level == NOMINAL  # a count, not a loss yet
    checks.on_blackbox(blackbox_status(3.0, store_up=False, dropped=1, in_memory=7200))
    found = checks.assess(3.0, lidars(2.95), supervisor(2.9))
    assert found.level == LOW and found.causes == ["blackbox: losing records (1 lost since it started)"]
    # the store back: the count stays, no new loss; level 2 holds for blackbox_loss_hold_s after the last
    checks.on_blackbox(blackbox_status(3.0 + P.blackbox_loss_hold_s - 0.5, dropped=1))
    assert checks.assess(3.0 + P.blackbox_loss_hold_s, lidars(12.9), supervisor(12.9)).level == LOW
    checks.on_blackbox(blackbox_status(3.0 + P.blackbox_loss_hold_s + 1.0, dropped=1))
    found = checks.assess(3.0 + P.blackbox_loss_hold_s + 1.0, lidars(13.9), supervisor(13.9))
    assert found.level == NOMINAL and found.sensors["blackbox"] == "ok"


def test_a_restarted_recorder_counting_from_zero_is_no_loss_and_a_silent_one_is_said():
    checks = fed()
    checks.on_blackbox(blackbox_status(1.0, dropped=5))
    checks.on_blackbox(blackbox_status(2.0, dropped=0))  # a new recorder process
    found = checks.assess(2.0, lidars(1.95), supervisor(1.9))
    assert found.level == NOMINAL
    found = checks.assess(2.0 + P.blackbox_status_timeout_s + 1.0, lidars(7.95), supervisor(7.9))
    assert found.sensors["blackbox"] == "no status for 6 s"
    assert "blackbox" not in " ".join(found.causes)  # a dead recorder is the supervisor's to judge


def test_without_a_black_box_nothing_is_said_of_it():
    found = fed().assess(3.0, lidars(2.95), supervisor(2.9))
    assert "blackbox" not in found.sensors
