"""`ares calibrate rrc-view` (ares/tools/harness/rrc_view.py): where road reactive control reads the road
at the vehicle, on simulated frames. Approaching the promenade's 12 m bend, road detection's fit
extrapolated back to x = 0 is far off; read from the frames seen 3-6 m back it is not."""

from __future__ import annotations

from ares.core.route import Route
from ares.tools.harness import rrc_view


def test_the_plan_covers_every_tight_bend_and_plain_road_clear_of_them():
    route = Route.from_tour("default")
    plan = rrc_view.sequences(route, plain=3, laterals=(0.0, 0.3))
    bends = [s for s in plan if s["group"] != "plain"]
    assert len(bends) == 2 * 4 and {s["lateral"] for s in bends} == {0.0, 0.3}
    assert "bend 761-788 m (kerb/kerb)" in {s["group"] for s in bends}
    plain = [s for s in plan if s["group"] == "plain"]
    assert len(plain) == 3 and all(s["frames"] == 101 for s in plain)


def test_frames_seen_metres_back_read_the_road_before_a_tight_bend_far_better_than_x_0():
    plan = [{"group": "into the 12 m bend", "s0": 755.0, "lateral": 0.0, "frames": 25}]  # 755-767 m
    report = rrc_view.run(plan=plan, ranges=((0.0, 0.0), (3.0, 6.0)))
    figures = report["groups"]["into the 12 m bend"]
    at_zero, behind = figures["0-0 m"], figures["3-6 m"]
    assert at_zero["frames"] == behind["frames"] == 25
    assert at_zero["offset_max_m"] > 0.5  # measured 1.34 m: the fit bends towards the bend ahead
    assert behind["offset_max_m"] < 0.15  # measured 0.009 m
    assert behind["heading_p95_deg"] < at_zero["heading_p95_deg"] / 3
    assert at_zero["not_followed"] == behind["not_followed"] == 0  # every frame agrees with the road seen
