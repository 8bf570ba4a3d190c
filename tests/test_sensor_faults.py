"""A scenario's sensor errors (simulator.scenario.ScenarioFault; simulator/sensors.py): each fault kind
takes the fields it needs and refuses the others; the sensors read them while they hold; and
the built-in dead_reckoning_drift makes dead reckoning drift, in the closed-loop harness."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pydantic import ValidationError

from ares.core import config
from ares.core.geodesy import LocalFrame
from ares.core.route import Route
from ares.tools.harness import closed_loop
from simulator.params import SimParams
from simulator.scenario import ScenarioFault, load_scenario
from simulator.sensors import SensorSuite
from simulator.vehicle import VehicleState


@pytest.mark.parametrize(
    "fields,message",
    [
        ({"kind": "gyro_bias"}, "needs bias_deg_s"),
        ({"kind": "block_lidar", "sensor": "roof"}, "needs at_t_s"),
        ({"kind": "wheel_speed_scale", "scale": 0.02, "sensor": "roof"}, "has no sensor"),
        ({"kind": "gnss_outage", "s_start_m": 5.0}, "needs both s_start_m and s_end_m"),
        ({"kind": "gnss_outage", "s_start_m": 5.0, "s_end_m": 50.0, "at_t_s": 3.0}, "not both"),
        ({"kind": "wheel_speed_scale", "scale": 0.8}, "less than 0.5"),
    ],
)
def test_a_fault_refuses_what_its_kind_does_not_take(fields, message):
    with pytest.raises(ValidationError, match=message):
        ScenarioFault(**fields)


def test_the_sensors_read_the_faults_while_they_hold():
    route = Route.from_tour("default")
    faults = [
        ScenarioFault(kind="gnss_outage", s_start_m=100.0, s_end_m=200.0),
        ScenarioFault(kind="wheel_speed_scale", scale=0.02, at_t_s=10.0),
        ScenarioFault(kind="gyro_bias", bias_deg_s=0.5, at_t_s=10.0, duration_s=5.0),
    ]
    suite = SensorSuite(route, SimParams(), LocalFrame(config.UtmOrigin()), 0.3, noise=False, faults=faults)
    state = VehicleState(t=5.0, s=150.0, yaw_rate=0.1, wheel_speed_rad_s=10.0)
    assert not suite.gnss.fix_available(150.0, 5.0) and not suite.gnss.rtk_available(150.0, 5.0)
    assert suite.gnss.fix_available(250.0, 5.0) and suite.gnss.rtk_available(250.0, 5.0)
    assert suite.can.measure(state)["wheel_speed_rad_s"] == pytest.approx(10.0)  # before t = 10
    assert suite.imu.measure(state)["gyro_z"] == pytest.approx(0.1)
    state.t = 12.0
    assert suite.can.measure(state)["wheel_speed_rad_s"] == pytest.approx(10.2)
    assert suite.imu.measure(state)["gyro_z"] == pytest.approx(0.1 + math.radians(0.5))
    state.t = 16.0  # the bias has ended
    assert suite.imu.measure(state)["gyro_z"] == pytest.approx(0.1)


def test_dead_reckoning_drifts_metres_over_the_outage_of_the_built_in_scenario():
    """Driven from the true pose (the controller is not the point here): the fused pose is within
    centimetres before the outage and metres off by its end."""
    scenario = load_scenario("dead_reckoning_drift")
    outage = next(f for f in scenario.faults if f.kind == "gnss_outage")
    r = closed_loop.run(
        seconds=150, s0=outage.s_start_m - 40.0, use_truth_pose=True, overrides={"scenario": "dead_reckoning_drift"}
    )
    err = np.hypot(r["est_x"] - r["x"], r["est_y"] - r["y"])
    before = (r["s"] > outage.s_start_m - 30.0) & (r["s"] < outage.s_start_m)
    inside = (r["s"] > outage.s_start_m) & (r["s"] < outage.s_end_m)
    assert np.nanmax(err[before]) < 0.1
    assert np.nanmax(err[inside]) > 2.0 and r["s"][inside].max() > outage.s_end_m - 20.0
    assert r["score"][inside][-20:].max() < 0.1  # the odometry manager no longer trusts it
