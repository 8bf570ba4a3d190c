"""The person at the wheel in a scenario (simulator/scenario.py `driver`): actions at a time or at
a place along the route, played by the simulator as the `sim/driver` service plays them (panel
events the drive-by-wire bridge reads, the plant driven by hand), each said in a `driver_action`
event. The takeover they make in the whole stack (DBW Fig. 28): tests/test_reproduce.py (dbw-takeover)."""

import pytest
from pydantic import ValidationError

from ares.app import run_config
from ares.core.clock import ManualClock
from ares.core.membus import MemoryNetwork
from ares.core.messages import PanelInput
from simulator.scenario import ScenarioDriverAction, load_scenario
from simulator.simulator_node import Simulator


def test_an_action_happens_at_a_time_or_at_a_place_and_a_pedal_within_its_travel():
    assert ScenarioDriverAction(action="steer", at_t_s=12, value=30).at_s_m is None
    assert ScenarioDriverAction(action="brake", at_s_m=40.0, value=1.0).at_t_s is None
    for bad in (
        {"action": "steer", "value": 30},  # neither
        {"action": "steer", "at_t_s": 1, "at_s_m": 2},  # both
        {"action": "throttle", "at_t_s": 1, "value": 1.5},  # past the pedal's travel
        {"action": "wave", "at_t_s": 1},
    ):
        with pytest.raises(ValidationError):
            ScenarioDriverAction(**bad)


def test_the_takeover_scenario_is_the_papers():
    takeover = load_scenario("takeover")
    takeovers = [(a.action, a.at_t_s) for a in takeover.driver if a.action in ("steer", "throttle")]
    assert takeovers == [("steer", 12.0), ("throttle", 73.0)]  # DBW Fig. 28


def test_the_simulator_plays_the_driver_at_its_times_and_places(tmp_path):
    scenario = tmp_path / "hands.yaml"
    scenario.write_text(
        "name: hands\nstart_s_m: 300\ndriver:\n"
        "  - {action: throttle, at_t_s: 0.2, value: 0.4, duration_s: 6}\n"
        "  - {action: steer, at_s_m: 303.0, value: -20, duration_s: 1}\n"
        "  - {action: button, at_t_s: 7.0}\n"
    )
    cfg = run_config.build(overrides={"scenario": str(scenario)})
    clock, network = ManualClock(), MemoryNetwork()
    sim = Simulator(cfg, clock=clock, bus=network.bus("sim", clock))
    sim.setup()
    listener = network.bus("test", clock)
    panel = listener.subscribe("vehicle/panel", queue=100)
    events = listener.subscribe("events", queue=100)
    for k in range(1, 801):  # 8 s at the physics rate
        t = round(k * 0.01, 9)
        clock.set(t)
        sim.step_once(t)
    said = [e for _, e in events.drain() if e.kind == "driver_action"]
    assert [e.data["action"] for e in said] == ["throttle", "steer", "button"]
    assert said[0].t == pytest.approx(0.2, abs=0.011) and said[2].t == pytest.approx(7.0, abs=0.011)
    assert 0.5 < said[1].t < 6.0 and "at s=303" in said[1].message  # where the throttle had taken it
    inputs = [(p.input, p.value) for _, p in panel.drain()]
    assert inputs == [(PanelInput.THROTTLE_PEDAL, 0.4), (PanelInput.STEERING_WHEEL, -20.0), (PanelInput.BUTTON, 1.0)]
    assert sim.plant.state.s > 303.0  # driven by hand, with no bridge to drive it
