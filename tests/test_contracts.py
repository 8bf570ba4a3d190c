"""Node contracts as data: every process declares its inputs, outputs, services and parameters;
`ares describe` and docs/nodes.md show them; the topic graph they form is whole (every input has
a publisher, a single-publisher topic has one); nothing undeclared gets onto the bus."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from ares.app import contracts, run_config
from ares.app.processes import PROCESSES, Process, for_run
from ares.core.clock import ManualClock
from ares.core.config import Params, param
from ares.core.membus import MemoryNetwork
from ares.core.messages import OdometryScore
from ares.core.node import ContractError, Input, Node, Output

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def cfg() -> dict:
    return run_config.build()


def test_every_process_runs_a_node_class_named_like_it(cfg):
    for spec in PROCESSES:
        cls = spec.node_class()
        assert cls.name == spec.name, f"{spec.node} is named {cls.name!r}, the table says {spec.name!r}"
        c = contracts.contract(spec, cfg)
        assert c["loop_hz"] > 0 and c["doc"], spec.name
        assert c["parameters"], f"{spec.name} declares no parameters"
        for p in c["parameters"]:
            assert p["doc"], f"parameter {p['name']} has no description"


def test_docs_nodes_md_is_what_ares_describe_prints(cfg):
    expected = contracts.nodes_markdown(cfg)
    actual = (REPO / "docs" / "nodes.md").read_text()
    assert actual == expected, "docs/nodes.md is stale: run `ares describe --markdown > docs/nodes.md`"


def test_the_topic_graph_is_whole(cfg):
    # plain simulation; the wire and vehicle runs' graphs: tests/test_vehicle_io.py
    graph = contracts.graph(contracts.all_contracts(cfg, for_run(True, True, False)))
    assert contracts.problems(graph) == []
    # the command the bridge obeys has exactly one source, and the bridge reads no other
    assert graph["movement/command"]["publishers"] == ["movement_manager"]
    assert graph["movement/command"]["subscribers"] == ["dbw_bridge"]
    # the controller's output reaches the bridge only through the movement gate (the black box records it)
    assert graph["control/setpoint"]["subscribers"] == ["movement_manager", "blackbox"]
    assert graph["dbw/actuators"]["subscribers"] == ["sim"]
    assert "supervisor" in graph["supervisor/state"]["publishers"]


def test_problems_in_a_graph_are_named():
    graph = {
        "path/match": {"publishers": [], "subscribers": ["controller"]},
        "control/setpoint": {"publishers": ["controller", "rogue"], "subscribers": ["dbw_bridge"]},
        "events": {"publishers": ["a", "b"], "subscribers": []},
    }
    found = contracts.problems(graph)
    assert found == [
        "path/match: read by controller but nobody publishes it",
        "control/setpoint: a single-publisher topic published by controller, rogue",
    ]


def test_the_simulator_waits_for_every_process_it_feeds(cfg):
    fed = contracts.fed_by(contracts.all_contracts(cfg, for_run(True, True, False)), "sim")
    assert fed == [
        "lidar_sim",
        "gnss",
        "localization",
        "odometry_manager",
        "path_manager",
        "speed_manager",
        "lidar_perception",
        "dbw_bridge",
        "mpc",
        "rrc",
        "pure_pursuit",
        "stanley",
        "control_manager",
        "obstacle_manager",
        "mission_manager",
        "awareness_manager",
        "movement_manager",
        "blackbox",
    ]


def test_declaring_a_topic_that_is_not_in_the_table_fails_when_the_class_is_defined():
    with pytest.raises(ContractError, match="localisation/pose"):

        class Misspelt(Node):
            pose = Input("localisation/pose")


def test_a_rate_naming_a_missing_parameter_fails_at_start(cfg):
    class NoSuchRate(Node):
        name = "no_such_rate"
        score = Output("odometry/score", rate="rate_hz_typo")

        class Params(Params):
            rate_hz: float = param(10.0, "loop rate", unit="Hz", gt=0)

    clock = ManualClock()
    with pytest.raises(ContractError, match="rate_hz_typo"):
        NoSuchRate(cfg, clock=clock, bus=MemoryNetwork().bus("no_such_rate", clock))


def test_publishing_or_subscribing_outside_the_contract_fails_at_once(cfg):
    from managers.odometry_node import OdometryManager

    clock = ManualClock()
    node = OdometryManager(cfg, clock=clock, bus=MemoryNetwork().bus("odometry_manager", clock))
    with pytest.raises(ContractError, match="add `Output\\('path/match'"):
        node.bus.publish("path/match", None)
    with pytest.raises(ContractError, match="declare `Input\\('sensors/imu'"):
        node.bus.subscribe("sensors/imu")
    node.bus.subscribe("localization/pose", on_message=lambda *_: None)  # declared: allowed


def test_ares_describe_json_lists_every_process():
    result = subprocess.run(
        [sys.executable, "-m", "ares.cli", "describe", "--json"], cwd=REPO, capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, result.stderr
    described = json.loads(result.stdout)
    assert [p["process"] for p in described["processes"]] == [p.name for p in PROCESSES]
    by_name = {p["process"]: p for p in described["processes"]}
    assert {
        "topic": "localization/pose",
        "schema": "Pose",
        "rate_hz": 50.0,
        "encoding": "json",
        "reliable": False,
        "doc": "every loop from the first fix on",
    } in by_name["localization"]["outputs"]
    assert by_name["dbw_bridge"]["services"][0]["name"] == "set_automatic_mode"
    assert any(
        p["name"] == "path_manager.radius_m" and p["value"] == 5.0 and p["unit"] == "m"
        for p in by_name["path_manager"]["parameters"]
    )
    assert described["topics"]["movement/command"]["subscribers"] == ["dbw_bridge"]


def _readme_template() -> str:
    text = (REPO / "README.md").read_text()
    found = re.search(r"<!-- node template -->\s*```python\n(.*?)```", text, re.S)
    assert found, "the README's node template is missing"
    return found.group(1)


def test_the_readmes_manager_template_is_one_file_that_runs(cfg):
    """Adding a manager is one file (the README's template) and one line of the process table."""
    namespace: dict = {}
    exec(compile(_readme_template(), "README template", "exec"), namespace)
    cls = next(v for v in namespace.values() if isinstance(v, type) and issubclass(v, Node) and v is not Node)
    spec = Process(cls.name, f"{__name__}:{cls.__name__}", safety_relevant=True)
    globals()[cls.__name__] = cls  # what the process table's "module:Class" finds
    try:
        contract = contracts.contract(spec, cfg)
        assert contract["inputs"] and contract["outputs"] and contract["parameters"]
        clock = ManualClock(1.0)
        net = MemoryNetwork()
        node = cls(cfg, clock=clock, bus=net.bus(cls.name, clock))
        node.setup()
        listener = net.bus("test", clock)
        events = listener.subscribe("events", queue=10)
        listener.publish("odometry/score", OdometryScore(t=1.0, score=0.95, covariance=1e-4, pose_age_s=0.02))
        node.step_once(1.0)
        listener.publish("odometry/score", OdometryScore(t=1.1, score=0.05, covariance=5e-3, pose_age_s=0.02))
        clock.set(1.1)
        node.step_once(1.1)
        assert [e.kind for _, e in events.drain()] == ["trust_lost"]
    finally:
        globals().pop(cls.__name__, None)
    assert len(_readme_template().splitlines()) <= 40, "the template is a reader's first manager: keep it short"


def test_the_simulators_truth_reaches_no_process_of_the_stack(cfg):
    # sim/truth and sim/world are for the evaluation (the headless runner) only: a vehicle-side
    # process that read them would be steering by what a real shuttle cannot know
    from ares.app.processes import PROCESSES

    sim_only = {p.name for p in PROCESSES if p.sim_only}
    for c in contracts.all_contracts(cfg):
        if c["process"] in sim_only:
            continue
        read = {i["topic"] for i in c["inputs"]}
        assert not read & {"sim/truth", "sim/world"}, c["process"]
