"""Every process's contract resolved with a configuration, the topic graph they form, and their
tables as `ares describe` prints them and docs/nodes.md holds them.

A contract: inputs (topic, schema, maximum age, queue), outputs (topic, schema, rate, encoding),
services (request and reply schemas) and parameters (name, type, default, unit, range, meaning)
of a node class (ares.core.node), with rates and ages taken from the configuration's values. The
supervisor is not a node (it hosts the router) but is part of the graph: it publishes
supervisor/state. Besides each node's declared outputs, every node publishes events and its
heartbeat (and clock/done at --speed max); those appear in the graph, not in each table.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from typing import Any, TypedDict

from pydantic import BaseModel
from pydantic.config import JsonValue

from ares.app import supervisor
from ares.app.processes import FLEET_SERVER, PROCESSES, Process
from ares.core import config, topics
from ares.core.node import IMPLICIT_OUTPUTS

SUPERVISOR = "supervisor"
CLOCK_FOR_STEPPERS, CLOCK_FOR_OTHERS = "sim/clock/*", "sim/clock"


# a contract as data, as `ares describe --json` prints it and the tables below are made from it
class InputRow(TypedDict):
    topic: str
    schema: str
    max_age_s: float | None
    queue: int
    doc: str


class OutputRow(TypedDict):
    topic: str
    schema: str
    rate_hz: float | None
    encoding: str
    reliable: bool
    doc: str


class ServiceRow(TypedDict):
    name: str
    request: str
    reply: str
    doc: str


class ParameterRow(TypedDict):
    name: str
    type: str
    value: JsonValue
    unit: JsonValue  # what param() put in the field's json_schema_extra
    range: str | None
    doc: str


class Contract(TypedDict):
    process: str
    node: str
    doc: str
    loop_hz: float
    loop_param: str | None
    safety_relevant: bool
    sim_only: bool
    wire: bool | None  # the simulator's variants: True with --wire only, False without
    driver: bool  # reads a device (on the vehicle, and with --wire)
    steps: bool
    drives_clock: bool
    inputs: list[InputRow]
    outputs: list[OutputRow]
    services: list[ServiceRow]
    calls: list[str]
    fleet_inputs: list[str]  # topics read from every vehicle on the network (the fleet's views)
    wire_inputs: list[str]  # device wires read (drivers; the simulator with --wire)
    wire_outputs: list[str]  # device wires written
    sections: list[str]
    parameters: list[ParameterRow]


def contract(spec: Process, cfg: Mapping[str, Any]) -> Contract:
    """One process's contract, with the values of `cfg`."""
    cls = spec.node_class()
    params = config.section(cfg, cls.section(), cls.Params)
    doc = (cls.__doc__ or "").strip().split("\n\n")[0].replace("\n", " ")
    rate_param = cls.rate if isinstance(cls.rate, str) else None
    return {
        "process": spec.name,
        "node": spec.node,
        "doc": doc,
        "loop_hz": cls.loop_rate_hz(params),
        "loop_param": f"{cls.section()}.{rate_param}" if rate_param else None,
        "safety_relevant": spec.safety_relevant,
        "sim_only": spec.sim_only,
        "wire": spec.wire,
        "driver": spec.driver,
        "steps": cls.steps,
        "drives_clock": cls.drives_clock(),
        "inputs": [
            {
                "topic": i.topic,
                "schema": i.entry.schema.schema_name(),
                "max_age_s": i.max_age_s(params),
                "queue": i.queue_size(params),
                "doc": i.doc,
            }
            for i in cls.inputs()
        ],
        "outputs": [
            {
                "topic": o.topic,
                "schema": o.entry.schema.schema_name(),
                "rate_hz": o.rate_hz(params),
                "encoding": o.entry.encoding,
                "reliable": o.entry.reliable,
                "doc": o.doc,
            }
            for o in cls.outputs()
        ],
        "services": [
            {
                "name": name,
                "request": topics.service(name).request.schema_name(),
                "reply": topics.service(name).reply.schema_name(),
                "doc": topics.service(name).doc,
            }
            for name in sorted(cls.services())
        ],
        "calls": sorted(cls.calls),
        "fleet_inputs": list(cls.fleet_inputs),
        "wire_inputs": list(cls.wire_inputs),
        "wire_outputs": list(cls.wire_outputs),
        "sections": [cls.section(), *cls.sections],
        "parameters": parameters(cls.Params, cls.section(), params)
        + [
            row
            for name, model in cls.sections.items()
            for row in parameters(model, name, config.section(cfg, name, model))
        ],
    }


def parameters(model: type[BaseModel], prefix: str, values: BaseModel | None = None) -> list[ParameterRow]:
    """Every leaf parameter of a section, flattened to dotted names, with its current value."""
    rows: list[ParameterRow] = []
    for name, field in model.model_fields.items():
        value = getattr(values, name) if values is not None else field.get_default(call_default_factory=True)
        nested = config.model_in(field.annotation)
        if nested is not None and isinstance(value, BaseModel):
            rows.extend(parameters(nested, f"{prefix}.{name}", value))
            continue
        extra = field.json_schema_extra if isinstance(field.json_schema_extra, dict) else {}
        bounds = []
        for meta in field.metadata:
            for attr, sign in (("ge", ">="), ("gt", ">"), ("le", "<="), ("lt", "<")):
                if getattr(meta, attr, None) is not None:
                    bounds.append(f"{sign} {getattr(meta, attr):g}")
        rows.append(
            {
                "name": f"{prefix}.{name}",
                "type": _type_name(field.annotation),
                "value": value.model_dump(mode="json") if isinstance(value, BaseModel) else _jsonable(value),
                "unit": extra.get("unit"),
                "range": ", ".join(bounds) or None,
                "doc": field.description or "",
            }
        )
    return rows


def _jsonable(value: Any) -> Any:
    return json.loads(json.dumps(value, default=str))


def _type_name(annotation: Any) -> str:
    text = getattr(annotation, "__name__", None) if isinstance(annotation, type) else None
    return text or str(annotation).replace("typing.", "")


def all_contracts(cfg: Mapping[str, Any], processes: Iterable[Process] = PROCESSES) -> list[Contract]:
    return [contract(spec, cfg) for spec in processes]


def graph(contracts: list[Contract]) -> dict[str, dict[str, list[str]]]:
    """topic -> {"publishers": [...], "subscribers": [...]}, the supervisor and every node's
    implicit outputs (events, heartbeat) included."""
    out: dict[str, dict[str, list[str]]] = {}

    def entry(topic: str) -> dict[str, list[str]]:
        return out.setdefault(topic, {"publishers": [], "subscribers": []})

    driven = any(c["drives_clock"] for c in contracts)  # a simulator: on the vehicle the clock is the wall's

    for c in contracts:
        for o in c["outputs"]:
            entry(o["topic"])["publishers"].append(c["process"])
        for i in c["inputs"]:
            entry(i["topic"])["subscribers"].append(c["process"])
        for implicit in IMPLICIT_OUTPUTS:
            entry(implicit)["publishers"].append(c["process"])
        if driven and not c["drives_clock"]:  # --speed max: steppers hear the time when due, the others now and then
            entry(CLOCK_FOR_STEPPERS if c["steps"] else CLOCK_FOR_OTHERS)["subscribers"].append(c["process"])
    for topic in supervisor.OUTPUTS:
        entry("heartbeat/*" if topic.startswith("heartbeat/") else topic)["publishers"].append(SUPERVISOR)
    for topic in supervisor.INPUTS:
        if driven or topic != CLOCK_FOR_OTHERS:
            entry(topic)["subscribers"].append(SUPERVISOR)
    return dict(sorted(out.items()))


def problems(topic_graph: dict[str, dict[str, list[str]]]) -> list[str]:
    """Inputs nobody publishes, and single-publisher topics with several publishers."""
    found = []
    for topic, ends in topic_graph.items():
        entry = topics.find(topic)
        optional = entry is not None and entry.optional  # an optional device's (vehicle_io.ntrip)
        if ends["subscribers"] and not ends["publishers"] and not optional:
            found.append(f"{topic}: read by {', '.join(ends['subscribers'])} but nobody publishes it")
        if entry is not None and not entry.shared and len(set(ends["publishers"])) > 1:
            found.append(f"{topic}: a single-publisher topic published by {', '.join(ends['publishers'])}")
    return found


def fed_by(contracts: list[Contract], source: str) -> list[str]:
    """Every process that steps and that `source`'s outputs feed, directly or through others, in
    table order: the processes the simulator waits for at --speed max."""
    # a device wire counts as a topic: the simulator with --wire feeds the drivers through it
    outputs = {c["process"]: {o["topic"] for o in c["outputs"]} | set(c["wire_outputs"]) for c in contracts}
    reached: set[str] = set()
    flowing = set(outputs.get(source, ()))
    changed = True
    while changed:
        changed = False
        for c in contracts:
            name = c["process"]
            if name == source or name in reached:
                continue
            if any(i["topic"] in flowing for i in c["inputs"]) or flowing & set(c["wire_inputs"]):
                reached.add(name)
                flowing |= outputs[name]
                changed = True
    return [c["process"] for c in contracts if c["process"] in reached and c["steps"]]


# ---- as text -----------------------------------------------------------------------------------


def _cell(value: object) -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        return f"{value:.10g}"
    if isinstance(value, (dict, list)):
        return json.dumps(value).replace("|", "\\|")
    return str(value).replace("|", "\\|").replace("\n", " ")


def _table(headers: list[str], rows: list[list[object]]) -> list[str]:
    if not rows:
        return ["(none)", ""]
    lines = ["| " + " | ".join(headers) + " |", "|" + "|".join("---" for _ in headers) + "|"]
    lines += ["| " + " | ".join(_cell(v) for v in row) + " |" for row in rows]
    return lines + [""]


def markdown(c: Contract) -> list[str]:
    loop = (
        f"{c['loop_hz']:g} Hz" + (f" (`{c['loop_param']}`)" if c["loop_param"] else "")
        if c["steps"]
        else f"an asyncio event loop (heartbeat at {c['loop_hz']:g} Hz)"
    )
    flags = ", ".join(
        f
        for f, on in (
            ("safety relevant", c["safety_relevant"]),
            ("simulation only", c["sim_only"]),
            ("with `--wire` only", c["wire"] is True),
            ("without `--wire`", c["wire"] is False),
            ("a device driver: on the vehicle and with `--wire`", c["driver"]),
        )
        if on
    )
    lines = [
        f"## {c['process']}" + (" (`--wire`)" if c["wire"] else ""),
        "",
        f"`{c['node']}` — {c['doc']}",
        "",
        f"Loop: {loop}" + (f"; {flags}" if flags else "") + ".",
        "",
        "**Inputs**",
        "",
    ]
    lines += _table(
        ["topic", "schema", "max age (s)", "queue", ""],
        [[f"`{i['topic']}`", i["schema"], i["max_age_s"], i["queue"] or "-", i["doc"]] for i in c["inputs"]],
    )
    lines += ["**Outputs**", ""]
    lines += _table(
        ["topic", "schema", "rate (Hz)", "encoding", ""],
        [[f"`{o['topic']}`", o["schema"], o["rate_hz"], o["encoding"], o["doc"]] for o in c["outputs"]],
    )
    lines += ["**Services**", ""]
    lines += _table(
        ["service", "request", "reply", ""],
        [[f"`{s['name']}`", s["request"], s["reply"], s["doc"]] for s in c["services"]],
    )
    if c["calls"]:
        lines += ["Calls: " + ", ".join(f"`{name}`" for name in c["calls"]), ""]
    if c["fleet_inputs"]:
        lines += [
            "Fleet inputs (every vehicle's, `ares/*/<topic>`): " + ", ".join(f"`{t}`" for t in c["fleet_inputs"]),
            "",
        ]
    if c["wire_inputs"] or c["wire_outputs"]:
        reads = ", ".join(f"`{w}`" for w in c["wire_inputs"]) or "-"
        writes = ", ".join(f"`{w}`" for w in c["wire_outputs"]) or "-"
        lines += [f"Device wires (docs/vehicle_io.md): reads {reads}; writes {writes}", ""]
    lines += ["**Parameters**", ""]
    lines += _table(
        ["name", "value", "unit", "range", ""],
        [[f"`{p['name']}`", p["value"], p["unit"], p["range"], p["doc"]] for p in c["parameters"]],
    )
    return lines


def graph_markdown(topic_graph: dict[str, dict[str, list[str]]]) -> list[str]:
    lines = [
        "## Topic graph",
        "",
        "Every topic, who publishes it and who reads it (`events`, heartbeats and "
        "`clock/done`: every process; the clock topics at `--speed max` only; the drawing leaves those out).",
        "",
    ]
    rows: list[list[object]] = []
    for topic, ends in topic_graph.items():
        entry = topics.find(topic)
        rows.append(
            [
                f"`{topic}`",
                entry.schema.schema_name() if entry else "?",
                ", ".join(ends["publishers"]) or "-",
                ", ".join(ends["subscribers"]) or "-",
            ]
        )
    lines += _table(["topic", "schema", "published by", "read by"], rows)
    lines += ["```mermaid", "flowchart LR"]
    for topic, ends in topic_graph.items():
        if topic in IMPLICIT_OUTPUTS or topic in (CLOCK_FOR_STEPPERS, CLOCK_FOR_OTHERS):
            continue
        for pub in ends["publishers"]:
            for sub in ends["subscribers"]:
                lines.append(f"    {pub} -->|{topic}| {sub}")
    return lines + ["```", ""]


def common_markdown(cfg: Mapping[str, Any]) -> list[str]:
    """The sections every process reads (core) and those of the composition layer."""
    from ares.app.run_config import COMPOSITION_SECTIONS

    core = config.core(cfg)
    rows = [
        row
        for name in config.CORE_SECTIONS
        if name != "vehicle_profile"
        for row in _section_rows(config.CoreConfig, name, getattr(core, name))
    ]
    rows += [
        row
        for name, model in COMPOSITION_SECTIONS.items()
        for row in parameters(model, name, config.section(cfg, name, model))
    ]
    lines = [
        "## Every process",
        "",
        "The core sections every process reads, and those of the supervisor and of "
        "`ares route import`; the vehicle profile (`vehicle_profile`, from `ares/core/config/vehicles/`) is "
        "`ares config show`'s.",
        "",
    ]
    return lines + _table(
        ["name", "value", "unit", "range", ""],
        [[f"`{p['name']}`", p["value"], p["unit"], p["range"], p["doc"]] for p in rows],
    )


def _section_rows(model: type[BaseModel], name: str, value: object) -> list[ParameterRow]:
    field = model.model_fields[name]
    nested = config.model_in(field.annotation)
    if nested is not None and isinstance(value, BaseModel):
        return parameters(nested, name, value)
    extra = field.json_schema_extra if isinstance(field.json_schema_extra, dict) else {}
    return [
        {
            "name": name,
            "type": _type_name(field.annotation),
            "value": _jsonable(value),
            "unit": extra.get("unit"),
            "range": None,
            "doc": field.description or "",
        }
    ]


def nodes_markdown(cfg: Mapping[str, Any], processes: Iterable[Process] = PROCESSES) -> str:
    """docs/nodes.md: every process's tables with the default configuration, and the topic graph."""
    contracts = all_contracts(cfg, processes)
    lines = [
        "# Nodes",
        "",
        "Generated by `ares describe --markdown` from the node classes of the process table "
        "(`ares/app/processes.py`); a test fails when this file is stale. Values are the defaults.",
        "",
    ]
    lines += common_markdown(cfg)
    for c in contracts:
        lines += markdown(c)
    lines += graph_markdown(graph(contracts))
    if list(processes) == PROCESSES:
        lines += [
            "",
            "## The fleet server's processes",
            "",
            "`ares fleet serve` (`processes.FLEET_SERVER`, deploy/fleet): they read every vehicle's topics "
            "on the fleet router (fleet inputs) and are no part of a vehicle's stack.",
            "",
        ]
        for c in all_contracts(cfg, FLEET_SERVER):
            lines += markdown(c)
    return "\n".join(lines).rstrip() + "\n"
