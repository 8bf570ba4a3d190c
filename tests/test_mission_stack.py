"""The mission in the whole stack (real processes, the Zenoh router, --speed max): a POI's actions
with passengers and the ramp, surviving a killed mission manager; a killed MPC brings a controlled
stop, a restart and the tour goes on; the operator's pause and resume (tests/scenarios/)."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.helpers.stack import headless

pytestmark = pytest.mark.stack
SCENARIOS = Path(__file__).parent / "scenarios"


def test_a_library_stop_survives_a_killed_mission_manager_and_the_tour_goes_on():
    result = headless(
        "--speed", "max", "--seconds", "90", "--scenario", str(SCENARIOS / "library_stop_with_faults.yaml")
    )
    assert result["ok"] and result["collisions"] == 0
    assert result["invariant_violations"] == 0, result["invariant_examples"]
    assert result["poi_actions"] == [
        ["Library", a] for a in ("STOP", "OPENING_DOORS", "TAKEOFF_RAMP", "PICKUP_RAMP", "CLOSING_DOORS", "NEXT_POI")
    ]
    faults = {f["target"]: f for f in result["faults"]}
    assert set(faults) == {"mission_manager", "mpc"}
    # standing at the Library when its manager died: the gate's stop begins as its limit goes stale
    assert faults["mission_manager"]["time_to_safe_state_s"] <= 1.0
    # the MPC killed on the move: a controlled stop within 1 s, the restart, and on again
    mpc = faults["mpc"]
    assert mpc["time_to_safe_state_s"] <= 1.0 and mpc["resumed_after_s"] is not None
    assert any(level == 2 and "mpc" in cause for _, level, cause in result["level_history"])
    assert [(a[1], a[2]) for a in result["scenario_actions"] if a[1] in ("pause", "resume")] == [
        ("pause", True),
        ("resume", True),
    ]
    assert result["mission"]["kind"] == "tour" and result["mission"]["poi"] == "Lakeside"
    assert result["distance_m"] > 80
