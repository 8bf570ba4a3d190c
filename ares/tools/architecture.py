"""docs/architecture.md: the layers and the processes in one picture, and where each of the
papers' equations lives (file and function). A tool of the documentation, as `ares describe
--markdown`'s docs/nodes.md is.

The page is printed by `ares describe --architecture` from data that the code itself keeps: the
layers (LAYERS, which tests/test_architecture.py holds equal to import-linter's contract in
pyproject.toml), the process table (ares.app.processes), the topic graph of the nodes' contracts
(ares.app.contracts) and the EQUATIONS table below, whose every function is checked to exist and
to name its equation in its docstring. A test fails when the page is stale.
"""

from __future__ import annotations

import importlib
import inspect
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from ares.app import contracts
from ares.app.processes import PROCESSES, Process

ARES = "ARES"  # the shuttle paper (docs/design.md names both)
DBW = "DBW"  # the drive-by-wire paper


@dataclass(frozen=True)
class Layer:
    packages: tuple[str, ...]  # import-linter's names, independent of each other within the layer
    name: str
    rule: str


# from the top down, as import-linter's layers contract lists them
LAYERS = (
    Layer(("ares.cli",), "the command line", "imports anything below"),
    Layer(
        ("ares.tools", "ares.deploy"),
        "tools (benches, experiments, the soak, figures) and deployment (PKI, routers, rehearsals)",
        "import the application and below, never each other",
    ),
    Layer(
        ("ares.app",),
        "the application: process table, supervisor, the run (interactive, headless) and its evaluations",
        "imports nodes and core",
    ),
    Layer(
        ("perception", "control", "managers", "blackbox", "drivers", "simulator"),
        "nodes: one process each, talking over the bus (drivers: the devices' wire formats)",
        "import core only, never each other",
    ),
    Layer(("ares.core",), "core: bus, messages, topics, node base, clock, configuration", "imports nothing above"),
)


@dataclass(frozen=True)
class Equation:
    paper: str  # ARES or DBW
    label: str  # as the paper numbers it: "eq. 6", "eqs. 11-13", "Algorithm 2", "Fig. 17"
    what: str
    target: str  # module:qualname of the function or class that computes it


EQUATIONS = (
    Equation(
        ARES,
        "eqs. 1-2",
        "yaw from GNSS positions d metres apart, and its variance",
        "perception.yaw_from_poses:YawFromPoses",
    ),
    Equation(
        ARES, "eq. 2", "the yaw's variance from the four position variances", "perception.yaw_from_poses:yaw_variance"
    ),
    Equation(
        ARES, "eqs. 3-5", "wheel odometry: the kinematic bicycle's ΔX, ΔY, Δψ", "perception.wheel_odometry:increments"
    ),
    Equation(ARES, "eq. 6", "the odometry score from the pose's covariance", "managers.odometry:score"),
    Equation(
        ARES,
        "eq. 7",
        "each ring point's road probability, from the three terms",
        "perception.road_detection:road_score",
    ),
    Equation(ARES, "eq. 8", "the height gradient's term", "perception.road_detection:gradient_term"),
    Equation(ARES, "eq. 9", "the relative height's term", "perception.road_detection:relative_height_term"),
    Equation(
        ARES,
        "eq. 10",
        "the term of the distance past the previous boundary",
        "perception.road_detection:boundary_distance_term",
    ),
    Equation(
        ARES,
        "Algorithm 1",
        "the normalised azimuth subtraction",
        "perception.road_detection:normalized_azimuth_subtraction",
    ),
    Equation(ARES, "Algorithm 2", "ground removal by heightmap", "perception.heightmap:ground_mask"),
    Equation(ARES, "eqs. 11-13", "MPC: kinematic model, input bounds, cost", "control.mpc:Mpc"),
    Equation(ARES, "eq. 11", "the kinematic model's prediction", "control.mpc:predict"),
    Equation(
        ARES,
        "eqs. 14-15",
        "road reactive control: PID on the offset from the road's centre",
        "control.rrc:RoadReactiveControl",
    ),
    Equation(ARES, "eqs. 16-17", "the speed profile from the path's curvature", "managers.speed:speed_profile"),
    Equation(DBW, "eqs. 4-8", "the board's discrete PID", "control.pid:PID"),
    Equation(
        DBW,
        "eqs. 9-14",
        "Ackermann: (v, κ) to steering-wheel angle and wheel speed",
        "control.ackermann:SetpointConversion",
    ),
    Equation(
        DBW,
        "eq. 13",
        "steering-wheel angle = 40 · front wheel angle",
        "ares.core.config.vehicle:VehicleProfile.steering_wheel_angle",
    ),
    Equation(DBW, "eq. 14", "wheel speed ω_w = v / (cos θ · r)", "control.ackermann:wheel_speed"),
    Equation(DBW, "Fig. 17", "the modes Manual, Ready, Automatic and their transitions", "control.dbw_bridge:DbwCore"),
    Equation(
        DBW,
        "eqs. 21-25",
        "MTBF, λ, R(t), MTTR, availability from the black box's records",
        "blackbox.register.reliability:figures",
    ),
)


def resolve(target: str) -> Any:
    """The function or class `module:qualname` names."""
    module_name, _, qualname = target.partition(":")
    found: Any = importlib.import_module(module_name)
    for part in qualname.split("."):
        found = getattr(found, part)
    return found


def _normalised(text: str) -> str:
    """One spelling: en dashes and minus signs as hyphens, "Eq. (13)" as "eq. 13", one space."""
    text = re.sub(r"\((\d+)\)", r"\1", text.replace("–", "-").replace("−", "-"))
    return re.sub(r"\s+", " ", text).lower()


def names_its_equation(eq: Equation) -> bool:
    """Whether the function's or class's own docstring names the equation."""
    return _normalised(eq.label) in _normalised(inspect.getdoc(resolve(eq.target)) or "")


def numbers(label: str) -> set[int]:
    """The equation numbers a label covers: "eqs. 11-13" -> {11, 12, 13}; "Algorithm 2" -> set()."""
    found = re.fullmatch(r"eqs?\. (\d+)(?:-(\d+))?", label)
    if found is None:
        return set()
    first = int(found.group(1))
    return set(range(first, int(found.group(2) or first) + 1))


# what the papers number and this table must place (but NOT_MODELLED)
PAPER_EQUATIONS = {ARES: set(range(1, 18)), DBW: set(range(4, 15)) | set(range(21, 26))}
PAPER_ALGORITHMS = {ARES: {"Algorithm 1", "Algorithm 2"}}
NOT_MODELLED = (
    (DBW, "eqs. 1-3", "the steering-angle sensor's two gears and its magnets: the board's hardware, not simulated"),
    (DBW, "eqs. 15-20", "the uncertainty of (v, κ) from the sensors' errors: the paper's analysis, not computed"),
)


def source_file(target: str) -> str:
    return target.partition(":")[0].replace(".", "/") + ".py"


# ---- the picture -------------------------------------------------------------------------------

# topics every process publishes or the clock uses: in the picture they would hide the data flow
_PLUMBING = ("events", "heartbeat/*", "clock/done", "sim/clock", "sim/clock/*")


def _package_of(spec: Process) -> str:
    module = spec.node.partition(":")[0]
    return "simulator" if module.startswith("simulator") else module.split(".")[0]


def _id(name: str, kind: str = "p") -> str:
    """A Mermaid id: processes (p_) and packages (pkg_) may share a name (blackbox)."""
    return f"{kind}_" + re.sub(r"\W", "_", name)


def data_flow(cfg: Mapping[str, Any], processes: Iterable[Process] = PROCESSES) -> dict[tuple[str, str], list[str]]:
    """(publisher, subscriber) -> the topics between them, but the plumbing and what only the black
    box reads (it records everything)."""
    topic_graph = contracts.graph(contracts.all_contracts(cfg, processes))
    flow: dict[tuple[str, str], list[str]] = {}
    for topic, ends in sorted(topic_graph.items()):
        if topic in _PLUMBING:
            continue
        for publisher in ends["publishers"]:
            for subscriber in ends["subscribers"]:
                if publisher != subscriber and subscriber != "blackbox":
                    flow.setdefault((publisher, subscriber), []).append(topic)
    return flow


def package_flow(cfg: Mapping[str, Any], processes: Iterable[Process] = PROCESSES) -> dict[tuple[str, str], list[str]]:
    """(publishing package, subscribing package) -> the topics between their processes (data_flow's,
    gathered by package; the supervisor counts as ares.app)."""
    package = {p.name: _package_of(p) for p in processes} | {"supervisor": "ares.app"}
    flow: dict[tuple[str, str], list[str]] = {}
    for (publisher, subscriber), topics in data_flow(cfg, processes).items():
        pair = (package[publisher], package[subscriber])
        if pair[0] != pair[1]:
            flow.setdefault(pair, [])
            flow[pair] += [t for t in topics if t not in flow[pair]]
    return {pair: _families(topics) for pair, topics in sorted(flow.items())}


def _families(topics: list[str]) -> list[str]:
    """lidar/roof/points, lidar/front_left/points ... -> lidar/*/points: one name per family of keys."""
    family = {t: re.sub(r"^(\w+)/\w+/(\w+)$", r"\1/*/\2", t) for t in topics}
    shared = {f for f in family.values() if list(family.values()).count(f) > 1}
    return sorted({family[t] if family[t] in shared else t for t in topics})


def picture(cfg: Mapping[str, Any], processes: Iterable[Process] = PROCESSES) -> list[str]:
    """A Mermaid flowchart: the layers from the top down (a thick arrow: may import), each node
    package with its processes, and the topics that flow between the packages' processes."""
    processes = list(processes)
    lines = ["```mermaid", "flowchart TB"]
    for depth, layer in enumerate(LAYERS):
        members = {package: [p.name for p in processes if _package_of(p) == package] for package in layer.packages}
        if "ares.app" in members:
            members["ares.app"] = ["supervisor"]  # no node of the table: it starts them
        boxes = [
            f'{_id(package, "pkg")}["<b>{package}</b>' + "".join(f"<br/>{name}" for name in names) + '"]'
            for package, names in members.items()
        ]
        if len(boxes) == 1:
            lines.append(f"  {boxes[0]}")
            continue
        lines.append(f'  subgraph L{depth}["{layer.name}: {layer.rule}"]')
        lines.append("    direction LR")
        lines += [f"    {box}" for box in boxes]
        lines.append("  end")
    for upper, lower in zip(LAYERS, LAYERS[1:]):
        lines += [f"  {_id(a, 'pkg')} ==> {_id(b, 'pkg')}" for a in upper.packages for b in lower.packages]
    for (publisher, subscriber), topics in package_flow(cfg, processes).items():
        lines.append(f'  {_id(publisher, "pkg")} -. "{", ".join(topics)}" .-> {_id(subscriber, "pkg")}')
    lines.append("```")
    return lines


# ---- the page ----------------------------------------------------------------------------------


def architecture_markdown(cfg: Mapping[str, Any]) -> str:
    out = [
        "# Architecture",
        "",
        "<!-- generated by `ares describe --architecture > docs/architecture.md`; "
        "tests/test_architecture.py fails when it is stale -->",
        "",
        "The floors ([design.md](design.md) §1), from the ground up, each one or more folders: the **core** imports "
        "nothing of the project above it; the **node packages** (perception, control, managers, drivers, "
        "blackbox and the simulator) import the core only and talk over the bus, never by importing each "
        "other; the **application** imports them; the **tools** and **deployment** the application and "
        "below, never each other; the **command line** anything. import-linter's contracts in "
        "pyproject.toml keep them (`lint-imports`, in the test command). Each process of the stack is one "
        "node class; its contract (inputs, outputs, rates, parameters) is in [nodes.md](nodes.md) and in "
        "its package's README.",
        "",
        "The picture: the layers from the top down (a thick arrow: may import), each package of the nodes "
        "with its processes, and the topics that flow between the packages' processes (dotted; every "
        "process also publishes `events` and its heartbeat, the simulator's clock ticks reach every process "
        "it feeds, and the black box records every topic: those are left out). The topics between single "
        "processes are in [nodes.md](nodes.md)'s topic graph.",
        "",
        *picture(cfg),
        "",
        "## Layers",
        "",
        "| layer | packages | rule |",
        "|---|---|---|",
        *[f"| {layer.name} | {', '.join(f'`{p}`' for p in layer.packages)} | {layer.rule} |" for layer in LAYERS],
        "",
        "## Where the papers' equations live",
        "",
        "ARES is the shuttle paper, DBW the drive-by-wire paper ([design.md](design.md) §3 sums both up). "
        "Each function or class below names its equation in its own docstring, and every equation the papers "
        "number is here (tests check both).",
        "",
        "| paper | equation | what | file | function |",
        "|---|---|---|---|---|",
        *[
            f"| {eq.paper} | {eq.label} | {eq.what} | [{source_file(eq.target)}](../{source_file(eq.target)}) "
            f"| `{eq.target.partition(':')[2]}` |"
            for eq in EQUATIONS
        ],
        *[f"| {paper} | {label} | {why} | | |" for paper, label, why in NOT_MODELLED],
        "",
        "## Processes",
        "",
        "| process | package | node class | safety relevant |",
        "|---|---|---|---|",
        *[
            f"| `{p.name}` | `{_package_of(p)}` | `{p.node}` | {'yes' if p.safety_relevant else 'no'} |"
            for p in PROCESSES
        ],
        "",
    ]
    return "\n".join(out)
