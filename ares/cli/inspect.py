"""Commands that read the stack's own description: `describe`, `config check|show`, `replay`,
`calibrate`. None of them needs a running stack."""

from __future__ import annotations

import argparse
import json
import sys

from . import record
from .args import CliError, Command, non_negative_int, positive_float, positive_int


def add_parser(subparsers: argparse._SubParsersAction) -> dict[str, Command]:
    describe = subparsers.add_parser(
        "describe",
        help="every process's inputs, outputs, services and parameters, and the topic graph",
        description="Print each process's contract (inputs, outputs with their rates, services, parameters with "
        "their defaults, units and ranges) from its node class, and the topic graph. "
        "docs/nodes.md is `ares describe --markdown`; a node package's README holds "
        "`ares describe --package NAME --markdown`.",
    )
    describe.add_argument("name", nargs="?", metavar="NODE", help="one process (default: all)")
    describe.add_argument("--json", action="store_true", help="one JSON object")
    describe.add_argument("--markdown", action="store_true", help="the Markdown of docs/nodes.md")
    describe.add_argument(
        "--architecture",
        action="store_true",
        help="the Markdown of docs/architecture.md: the layers and processes in one picture, the papers' equations",
    )
    describe.add_argument(
        "--package",
        metavar="NAME",
        help="only this node package's processes (managers, perception, control, drivers, blackbox, "
        "simulator); with --markdown the generated part of NAME/README.md",
    )
    describe.add_argument(
        "--write",
        action="store_true",
        help="with --package: put the generated part in NAME/README.md, between its markers",
    )
    describe.add_argument(
        "--config",
        action="append",
        default=[],
        metavar="FILE",
        help="resolve rates and parameters with this configuration file",
    )

    cfg = subparsers.add_parser(
        "config",
        help="check a configuration file, show the merged configuration",
        description="Configuration files are YAML overrides of the defaults, section by "
        "section; `ares config show` prints every key with its meaning.",
    )
    cfg_sub = cfg.add_subparsers(dest="config_action", metavar="ACTION")
    check = cfg_sub.add_parser("check", help="validate configuration files (exit 2 on an error)")
    check.add_argument("files", nargs="+", metavar="FILE")
    show = cfg_sub.add_parser("show", help="the merged, validated configuration (defaults + files)")
    show.add_argument("files", nargs="*", metavar="FILE")
    show.add_argument("--json", action="store_true", help="JSON instead of commented YAML")

    replay = subparsers.add_parser(
        "replay",
        help="process replay: feed a node's recorded inputs back and compare its outputs",
        description="Replay recordings of `replay.record` processes through the current code and compare the "
        "outputs with the recorded ones (`check`), or make the current outputs the expected ones "
        "(`update`, after an intended change of behaviour).",
    )
    replay.add_argument(
        "action",
        metavar="check|update|FILE.mcap",
        help="check or update process replay recordings, or play an MCAP recording of the bus (`ares record`, "
        "`ares run --record`) into a bus, or with --node replay one process of it against its recorded outputs",
    )
    replay.add_argument("files", nargs="*", metavar="FILE", help="check|update: recordings (*.jsonl.gz)")
    record.add_replay_arguments(replay)

    calibrate = subparsers.add_parser(
        "calibrate",
        help="re-run the experiments that chose parameters",
        description="odometry: the odometry score's a, b, c (docs/odometry_score.md). lidars: the LiDARs' "
        "extrinsics, found against each other in a simulated warehouse from a wrong first guess and "
        "compared with the profile's (ARES §3.4.1; ares/tools/harness/calibration_warehouse.py). road: road "
        "detection's β (eqs. 7-10) and knobs, searched on simulated frames over every verge of the tour "
        "(docs/road_detection.md; ares/tools/harness/road_betas.py). rrc-view: where road reactive control "
        "reads the road at the vehicle, compared on simulated frames through the tour's tight bends and "
        "plain stretches (docs/control.md; ares/tools/harness/rrc_view.py).",
    )
    calibrate.add_argument("what", choices=["odometry", "lidars", "road", "rrc-view"])
    calibrate.add_argument("--laps", type=positive_float, default=1.0, metavar="N", help="odometry: laps to drive")
    calibrate.add_argument(
        "--seed",
        type=non_negative_int,
        default=None,
        metavar="S",
        help="odometry: the closed loop's; lidars: the scans' noise and the first guess; road, "
        "rrc-view: the frames' poses and the LiDARs' noise (default 0)",
    )
    calibrate.add_argument(
        "--samples",
        type=positive_int,
        default=4,
        metavar="N",
        help="road: sequences of frames per stretch of the tour (default 4)",
    )
    calibrate.add_argument(
        "--vehicle",
        default="ares_shuttle",
        metavar="NAME",
        help="lidars: a profile in ares/core/config/vehicles/ or a YAML file (default: ares_shuttle)",
    )
    calibrate.add_argument(
        "--offset-m",
        type=positive_float,
        default=0.10,
        metavar="M",
        help="lidars: how far off the first guess is (default: 0.10)",
    )
    calibrate.add_argument(
        "--offset-deg",
        type=positive_float,
        default=3.0,
        metavar="DEG",
        help="lidars: how much the first guess is turned (default: 3)",
    )
    calibrate.add_argument(
        "--write",
        metavar="PATH",
        help="lidars: write the profile with the calibrated extrinsics here (.yaml); road: a "
        "configuration file with the chosen values (.yaml, for --config)",
    )
    calibrate.add_argument(
        "--json", action="store_true", help="lidars, road, rrc-view: print one JSON object instead of the table"
    )
    return {"describe": cmd_describe, "config": cmd_config, "replay": cmd_replay, "calibrate": cmd_calibrate}


def _build(files: list[str]) -> dict:
    from ares.app import run_config
    from ares.core import config

    try:
        return run_config.build(tuple(files))
    except config.ConfigError as exc:
        raise CliError(str(exc)) from None


def cmd_describe(args: argparse.Namespace) -> int:
    from ares.app import contracts, processes

    cfg = _build(args.config)
    chosen = processes.PROCESSES
    if args.name:
        try:
            chosen = [processes.by_name(args.name)]
        except KeyError as exc:
            raise CliError(exc.args[0]) from None
    if args.write and not args.package:
        raise CliError("describe --write: name the package (--package NAME)")
    if args.package:
        from ares.tools import package_docs

        if args.package not in package_docs.NODE_PACKAGES:
            raise CliError(
                f"describe --package {args.package}: not a node package ({', '.join(package_docs.NODE_PACKAGES)})"
            )
        if args.name:
            raise CliError("describe: a process or a package, not both")
        if args.write:
            print(f"written: {package_docs.write(cfg, args.package)}")
            return 0
        if args.markdown:
            sys.stdout.write(package_docs.package_markdown(cfg, args.package))
            return 0
        chosen = package_docs.package_processes(args.package)
    if args.markdown:
        sys.stdout.write(contracts.nodes_markdown(cfg, chosen))
        return 0
    if args.architecture:
        from ares.tools.architecture import architecture_markdown

        sys.stdout.write(architecture_markdown(cfg))
        return 0
    found = contracts.all_contracts(cfg, chosen)
    graph = contracts.graph(contracts.all_contracts(cfg))
    if args.json:
        print(json.dumps({"processes": found, "topics": graph}))
        return 0
    for c in found:
        print("\n".join(contracts.markdown(c)))
    if not args.name and not args.package:
        print("\n".join(contracts.graph_markdown(graph)))
    return 0


def cmd_config(args: argparse.Namespace) -> int:
    from ares.app import run_config
    from ares.core import config

    if args.config_action not in ("check", "show"):
        raise CliError("which action? try `ares config check FILE` or `ares config show`")
    try:
        cfg = run_config.build(tuple(args.files))
    except config.ConfigError as exc:
        print(f"ares config: {exc}", file=sys.stderr)
        return 2
    if args.config_action == "check":
        print(f"ok: {', '.join(args.files)}")
        return 0
    if args.json:
        print(json.dumps(cfg, indent=1))
    else:
        sys.stdout.write(commented_yaml(cfg, run_config.stack_model()))
    return 0


def commented_yaml(cfg: dict, model) -> str:
    """The configuration as YAML, each key with its unit and meaning as a comment."""
    import yaml

    from ares.core import config

    lines: list[str] = []

    def emit(data: dict, current, indent: int) -> None:
        fields = getattr(current, "model_fields", {}) if current is not None else {}
        for key, value in data.items():
            field = fields.get(key)
            nested = config.model_in(field.annotation) if field is not None else None
            extra = field.json_schema_extra if field is not None and isinstance(field.json_schema_extra, dict) else {}
            note = " ".join(
                p
                for p in (
                    (f"[{extra['unit']}]" if extra.get("unit") else ""),
                    (field.description or "") if field is not None else "",
                )
                if p
            )
            comment = f"  # {note}" if note else ""
            pad = "  " * indent
            if isinstance(value, dict) and value and (nested is not None or key == "vehicle_profile"):
                lines.append(f"{pad}{key}:{comment}")
                emit(value, nested or config.VehicleProfile, indent + 1)
            else:
                text = yaml.safe_dump({key: value}, default_flow_style=True, width=10_000).strip()
                text = text[1:-1] if text.startswith("{") else text
                lines.append(f"{pad}{text}{comment}")

    emit(cfg, model, 0)
    return "\n".join(lines) + "\n"


def cmd_replay(args: argparse.Namespace) -> int:
    from ares.core import replay

    if args.action not in ("check", "update"):
        if not record.is_mcap(args.action):
            raise CliError(f"{args.action}: neither check, update nor an MCAP file")
        return record.cmd_replay_mcap(args, args.action)
    if not args.files:
        raise CliError(f"replay {args.action}: name the recordings (*.jsonl.gz)")
    failed = 0
    for path in args.files:
        try:
            result = replay.update(path) if args.action == "update" else replay.replay(path)
        except (OSError, ValueError) as exc:
            raise CliError(f"{path}: {exc}") from None
        if args.action == "update":
            print(f"{path}: {result.node}, {result.steps} steps, {result.outputs} outputs written as expected")
        elif result.ok:
            print(f"{path}: {result.node}, {result.steps} steps, {result.outputs} outputs: identical")
        else:
            failed += 1
            print(f"{path}: {result.node}: {len(result.mismatches)} mismatches, first:", file=sys.stderr)
            for m in result.mismatches[:5]:
                print(f"  {m}", file=sys.stderr)
    return 1 if failed else 0


def cmd_calibrate(args: argparse.Namespace) -> int:
    if args.what == "lidars":
        return _calibrate_lidars(args)
    if args.what == "road":
        return _calibrate_road(args)
    if args.what == "rrc-view":
        from ares.tools.harness import rrc_view

        report = rrc_view.run(args.seed or 0, verbose=not args.json)
        print(json.dumps(report) if args.json else rrc_view.table(report))
        return 0
    from ares.tools.harness.odometry_score import calibrate

    calibrate(args.laps, args.seed)
    return 0


def _calibrate_lidars(args: argparse.Namespace) -> int:
    from ares.core import config
    from ares.tools.harness import calibration_warehouse as lidar_calibration

    if args.write and not args.write.endswith((".yaml", ".yml")):
        print(
            f"ares calibrate: --write {args.write}: the profile must be a .yaml file (so that --vehicle takes it)",
            file=sys.stderr,
        )
        return 2
    try:
        report = lidar_calibration.calibrate(args.vehicle, args.seed or 0, args.offset_m, args.offset_deg)
    except (config.ConfigError, ValueError) as exc:  # an unknown or invalid profile, no LiDARs to calibrate
        print(f"ares calibrate: {exc}", file=sys.stderr)
        return 2
    if args.write:
        try:
            report["written"] = str(lidar_calibration.write_profile(report, args.write))
        except OSError as exc:
            raise CliError(f"cannot write {args.write}: {exc.strerror}") from None
    print(json.dumps(report) if args.json else lidar_calibration.table(report))
    if args.write and not args.json:
        print(f"written: {report['written']}")
    return 0


def _calibrate_road(args: argparse.Namespace) -> int:
    from ares.tools.harness import road_betas

    if args.write and not args.write.endswith((".yaml", ".yml")):
        print(f"ares calibrate: --write {args.write}: a configuration file must be .yaml", file=sys.stderr)
        return 2
    report, chosen = road_betas.calibrate(args.samples, args.seed or 0, verbose=not args.json)
    if args.write:
        try:
            with open(args.write, "w") as out:
                out.write(road_betas.overrides_yaml(chosen))
        except OSError as exc:
            raise CliError(f"cannot write {args.write}: {exc.strerror}") from None
        report["written"] = args.write
    print(json.dumps(report, default=float) if args.json else road_betas.table(report))
    if args.write and not args.json:
        print(f"written: {args.write}")
    return 0
