import math

import pytest

from ares.app.evaluation.lap_eval import SETTLE_S, LocalizationTracker


def feed(tracker, t_end, rtk_at, estimate_offset=0.0, score_at=lambda t, rtk: 0.95 if rtk else 0.1):
    """Truth at 20 Hz along the x axis at 2 m/s; estimates and scores at 50 Hz, a little late."""
    t = 0.0
    while t <= t_end:
        rtk = rtk_at(t)
        tracker.add_truth(t, 2 * t, 0.0, 0.0, rtk, 2.0)
        t = round(t + 0.05, 6)
    for k in range(int(t_end * 50)):
        tp = k / 50
        tracker.add_pose(tp, 2 * tp, estimate_offset if rtk_at(tp) else 0.3, 0.0)
        tracker.add_score(tp, score_at(tp, rtk_at(tp)))


def test_errors_and_scores_are_split_by_rtk_with_settling():
    tracker = LocalizationTracker()
    feed(tracker, 30.0, lambda t: not 10 <= t < 20, estimate_offset=0.02)
    summary = tracker.summary()
    assert summary["loc_rmse_rtk_m"] == pytest.approx(0.02, abs=1e-6)
    assert summary["loc_max_deadzone_m"] == pytest.approx(0.3, abs=1e-6)
    assert summary["score_min_rtk"] == 0.95 and summary["score_max_deadzone"] == 0.1
    assert summary["yaw_rmse_deg"] == 0.0


def test_a_low_score_while_settling_is_not_counted():
    tracker = LocalizationTracker()
    # the score needs a moment after RTK returns at t = 20, within the settling time
    feed(
        tracker,
        30.0,
        lambda t: not 10 <= t < 20,
        score_at=lambda t, rtk: 0.2 if (not rtk or 20 <= t < 20 + SETTLE_S / 2) else 0.97,
    )
    assert tracker.summary()["score_min_rtk"] == 0.97


def test_estimates_that_arrive_before_the_truth_are_kept_until_it_does():
    tracker = LocalizationTracker()
    tracker.add_truth(0.0, 0.0, 0.0, 0.0, True, 2.0)
    tracker.add_pose(0.0, 0.0, 0.0, 0.0)
    tracker.add_pose(3.0, 6.1, 0.0, math.radians(1.0))  # ahead of the truth received so far
    for k in range(1, 80):
        tracker.add_truth(k * 0.05, 2 * k * 0.05, 0.0, 0.0, True, 2.0)
    assert tracker.summary()["loc_rmse_rtk_m"] == pytest.approx(0.1, abs=1e-6)
    assert tracker.summary()["yaw_rmse_deg"] == pytest.approx(1.0, abs=1e-6)


def test_nothing_counts_before_the_first_estimate_and_the_vehicle_moving():
    tracker = LocalizationTracker()
    for k in range(200):  # standing still for 5 s, then 2 m/s
        t = k * 0.05
        v = 0.0 if t < 5 else 2.0
        tracker.add_truth(t, 0.0, 0.0, 0.0, True, v)
    tracker.add_pose(1.0, 0.0, 0.0, 0.0)  # the first estimate, before the vehicle moves
    for k in range(500):
        t = k * 0.02
        tracker.add_score(t, 0.0 if t < 5 + SETTLE_S else 0.99)
    assert tracker.summary()["score_min_rtk"] == 0.99
