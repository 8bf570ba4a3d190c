"""Reliability figures (DBW paper §5.4) and how the black box's records are tallied into them."""

from __future__ import annotations

import math
from datetime import UTC, datetime, timedelta

import pytest

from blackbox.register import reliability as rel

T0 = datetime(2025, 6, 1, 8, 0, 0, tzinfo=UTC)


def rec(second: int, mode: str = "AUTOMATIC", down: str | None = None) -> dict:
    processes = {"controller": {"state": "running", "restarts": 0}, "dbw_bridge": {"state": "running", "restarts": 0}}
    if down:
        processes[down] = {"state": "restarting", "restarts": 1}
    return {"time": T0 + timedelta(seconds=second), "mode": mode, "processes": processes}


def at(second: float) -> datetime:
    return T0 + timedelta(seconds=second)


def test_paper_figures():
    # 812 h of tests, 788 h in operation, 29 failures (eqs. 21-25)
    f = rel.figures(operating_hours=788, failures=29, repair_hours=812 - 788, t_hours=10)
    assert f.mtbf_hours == pytest.approx(27.17, abs=0.005)
    assert f.failure_rate_per_hour == pytest.approx(0.0368, abs=0.00005)
    assert f.mttr_hours == pytest.approx(0.8275, abs=0.0001)
    assert f.availability * 100 == pytest.approx(97.04, abs=0.005)
    assert f.reliability == pytest.approx(math.exp(-10 / (788 / 29)))


def test_no_failure_and_no_operation():
    f = rel.figures(operating_hours=5.0, failures=0, repair_hours=0.0, t_hours=3)
    assert f.mtbf_hours is None and f.mttr_hours is None
    assert f.failure_rate_per_hour == 0.0 and f.reliability == 1.0 and f.availability == 1.0
    f = rel.figures(operating_hours=0.0, failures=0, repair_hours=0.0)
    assert (f.mtbf_hours, f.failure_rate_per_hour, f.reliability, f.mttr_hours, f.availability) == (None,) * 5
    f = rel.figures(operating_hours=0.0, failures=2, repair_hours=1.0, t_hours=1)
    assert f.mtbf_hours == 0.0 and f.failure_rate_per_hour is None and f.reliability == 0.0
    assert f.mttr_hours == 0.5 and f.availability == 0.0
    f = rel.figures(operating_hours=0.0, failures=1, repair_hours=0.0)
    assert f.availability is None
    with pytest.raises(ValueError):
        rel.figures(operating_hours=-1, failures=0, repair_hours=0)


def test_is_up():
    assert rel.is_up(rec(0))
    assert not rel.is_up(rec(0, mode="MANUAL"))
    assert not rel.is_up(rec(0, down="controller"))
    assert not rel.is_up({"time": T0, "mode": None, "processes": {}})
    assert rel.is_up({"time": T0, "mode": "AUTOMATIC", "processes": {}})


def test_tally_one_outage_with_cascade():
    # 100 s up, a fault at 100.4 s, a second fault (same outage) at 105 s, 60 s in MANUAL, back up
    records = (
        [rec(s) for s in range(100)]
        + [rec(s, mode="MANUAL") for s in range(100, 160)]
        + [rec(s) for s in range(160, 200)]
    )
    tally = rel.tally_window(records, [at(100.4), at(105)], until=at(200))
    assert tally.failures == 1
    assert tally.operating_s == 140
    assert tally.repair_s == pytest.approx(59.6)  # 100.4 s -> first record up again at 160 s
    assert tally.open_failures == 0
    f = tally.figures(t_hours=1)
    assert f.mtbf_hours == pytest.approx(140 / 3600)
    assert f.availability == pytest.approx(140 / (140 + 59.6))


def test_process_down_is_not_repaired_yet():
    # back in AUTOMATIC at 110 s but the controller is still restarting until 120 s
    records = (
        [rec(s) for s in range(100)]
        + [rec(s, mode="MANUAL") for s in range(100, 110)]
        + [rec(s, down="controller") for s in range(110, 120)]
        + [rec(s) for s in range(120, 130)]
    )
    tally = rel.tally_window(records, [at(99.5)], until=at(130))
    assert tally.failures == 1 and tally.repair_s == pytest.approx(20.5) and tally.operating_s == 110


def test_fault_outside_operation_is_no_failure():
    # parked in MANUAL: a FAULT then is not a failure of operation
    records = [rec(s, mode="MANUAL") for s in range(50)] + [rec(s) for s in range(50, 100)]
    tally = rel.tally_window(records, [at(10)], until=at(100))
    assert tally.failures == 0 and tally.repair_s == 0 and tally.operating_s == 50


def test_unrepaired_failure_counts_to_window_end():
    records = [rec(s) for s in range(30)] + [rec(s, mode="MANUAL") for s in range(30, 60)]
    tally = rel.tally_window(records, [at(30)], until=at(90))
    assert tally.failures == 1 and tally.open_failures == 1
    assert tally.repair_s == pytest.approx(60)


def test_two_failures_and_fault_after_last_record():
    records = (
        [rec(s) for s in range(10)] + [rec(s, mode="MANUAL") for s in range(10, 15)] + [rec(s) for s in range(15, 30)]
    )
    tally = rel.tally_window(records, [at(10), at(30.5), at(500)], until=at(40))
    # 10 s: failure, repaired at 15; 30.5 s: last record (29) is up and within 2 s -> failure, open
    # until 40; 500 s is beyond the window's end and ignored
    assert tally.failures == 2 and tally.open_failures == 1
    assert tally.repair_s == pytest.approx(5 + 9.5)


def test_empty_window():
    tally = rel.tally_window([], [], until=T0)
    f = tally.figures()
    assert tally.operating_s == 0 and tally.failures == 0 and f.mtbf_hours is None and f.availability is None
