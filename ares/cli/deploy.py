"""`ares deploy`: the fleet's certificates and credentials, the routers' configurations, a router
for the tests and the rehearsal, and the check of a deployment folder (docs/deploy.md)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from .args import CliError, Command, endpoint


def add_parser(subparsers: argparse._SubParsersAction) -> dict[str, Command]:
    deploy = subparsers.add_parser(
        "deploy",
        help="deployment: certificates, router configs, checks (docs/deploy.md)",
        description="Deploy a vehicle and the fleet with docker compose (deploy/, docs/deploy.md).",
    )
    sub = deploy.add_subparsers(dest="deploy", metavar="ACTION")
    certs = sub.add_parser(
        "certs",
        help="the fleet CA (made if absent), a vehicle's certificate and Zenoh credentials",
        description="Make the fleet's CA in DIR when it has none (with the fleet router's certificate), then "
        "the vehicle's router certificate (CN = its id), its Zenoh password on the fleet router and its "
        "processes' password on its own router, its router config with those credentials, and the fleet "
        "router's config admitting every vehicle issued. Issuing an id again rotates its keys.",
    )
    certs.add_argument("--fleet-ca", required=True, metavar="DIR", help="the fleet's CA folder")
    certs.add_argument("--vehicle", required=True, metavar="ID", help="the vehicle's id (ares/<id>/**)")
    certs.add_argument(
        "--fleet-host",
        action="append",
        metavar="NAME",
        help="a name or address of the fleet router in its certificate (repeat; default fleet-router, "
        "localhost); used only when the CA is made",
    )
    certs.add_argument(
        "--api-host",
        action="append",
        metavar="NAME",
        help="a name or address of the vehicle's REST API in its certificate (repeat; the id, localhost "
        "and 127.0.0.1 always)",
    )
    certs.add_argument(
        "--fleet-endpoint",
        type=endpoint,
        default="tls/fleet-router:7447",
        metavar="ENDPOINT",
        help="where the vehicle's router finds the fleet router (default tls/fleet-router:7447)",
    )
    rc = sub.add_parser(
        "router-config",
        help="print a router's config (the files in deploy/ are this output)",
        description="Print the fleet router's config for the given vehicles, or a vehicle router's without "
        "its credentials.",
    )
    rc.add_argument("kind", choices=["fleet", "vehicle"])
    rc.add_argument("--vehicles", default="", metavar="ID,ID", help="fleet: the vehicles admitted")
    rc.add_argument("-o", "--output", metavar="FILE", help="write to FILE instead of stdout")
    router = sub.add_parser(
        "router",
        help="run a router from a deployment's JSON5 file with eclipse-zenoh (stands in for zenohd)",
        description="Run a Zenoh router from a router config file, its /run/secrets/ paths read from "
        "--secrets; endpoints replaced when given. Prints one JSON line once listening; stops on SIGTERM.",
    )
    router.add_argument("--config", required=True, metavar="FILE", help="the router's JSON5 config")
    router.add_argument("--secrets", metavar="DIR", help="the folder that stands for /run/secrets")
    router.add_argument("--listen", action="append", type=endpoint, metavar="ENDPOINT", help="listen here instead")
    router.add_argument("--connect", action="append", type=endpoint, metavar="ENDPOINT", help="connect here instead")
    router.add_argument(
        "--report-refusals-as",
        metavar="ID",
        help="the fleet router: publish each vehicle refused for reaching under another's id as an "
        "acl_refused event under ares/ID/events (the fleet server's id, `fleet`)",
    )
    rehearse = sub.add_parser(
        "rehearse",
        help="the deployment across network namespaces: fleet and two vehicles (root)",
        description="Build a fleet host and two vehicle hosts as network namespaces joined by veth links, "
        "run the routers from the deployment's files, the fleet server and each vehicle's stack, and show: "
        "both vehicles on the fleet API, refused wrong password, another CA's certificate and a vehicle "
        "publishing under another's id, a cut link (unreachable, no black-box second lost), a fleet "
        "router restart. Removes everything it made at the end.",
    )
    rehearse.add_argument(
        "--containers",
        action="store_true",
        help="under a Docker engine: the images, the fleet's and two vehicles' compose stacks (root)",
    )
    rehearse.add_argument(
        "--base", choices=["debootstrap", "python"], default="debootstrap", help="--containers: the images' base"
    )
    rehearse.add_argument("--json", action="store_true", help="one JSON line of figures")
    rehearse.add_argument(
        "--light", action="store_true", help="each vehicle runs its black-box recorder only (no simulated stack)"
    )
    rehearse.add_argument("--partition-s", type=float, default=60.0, metavar="S", help="the link cut's length")
    rehearse.add_argument("--work", metavar="DIR", help="where the run's secrets, stores and logs go")
    images = sub.add_parser(
        "images",
        help="build the deployment's images under a Docker engine (started here if none runs; root)",
        description="Build the base (debootstrap: Debian bookworm from Debian's packages, imported; python: the "
        "official image, pulled) and the ares image from deploy/Dockerfile on it. Says how long each step took "
        "and how large each image is. Starts a Docker engine of its own when none answers, and stops it after.",
    )
    images.add_argument("--base", choices=["debootstrap", "python"], default="debootstrap")
    images.add_argument("--json", action="store_true", help="one JSON object instead of lines")
    chk = sub.add_parser(
        "check",
        help="validate a deployment folder (compose file, secrets, certificates, ARES configs)",
        description="Check a deployment folder (deploy/vehicle, deploy/fleet or a copy): Docker Compose's own "
        "`config -q`, then the project's checks (docs/deploy.md). Secrets are read from $ARES_SECRETS or the "
        "folder's secrets/. Exit 2 naming each problem.",
    )
    chk.add_argument("folder", metavar="DIR")
    chk.add_argument("--json", action="store_true", help="one JSON object instead of lines")
    manifest = sub.add_parser(
        "manifest",
        help="the installed stack's files hashed and signed with the fleet's release key",
        description="Hash every installed file of the project's packages and sign the list with the fleet's "
        "Ed25519 release key (made at KEY when absent, its public half at KEY.pub). A vehicle whose "
        "configuration names the manifest and the public key (section `release`) refuses to start "
        "`ares run` on any difference, naming the first file. Prints one JSON line.",
    )
    manifest.add_argument("--key", required=True, metavar="KEY", help="the fleet's release key (PEM, private)")
    manifest.add_argument("--out", required=True, metavar="MANIFEST", help="where the signed manifest goes")
    return {"deploy": cmd_deploy}


def cmd_deploy(args: argparse.Namespace) -> int:
    action = getattr(args, "deploy", None)
    if action == "certs":
        return _certs(args)
    if action == "router-config":
        return _router_config(args)
    if action == "router":
        return _router(args)
    if action == "check":
        return _check(args)
    if action == "rehearse":
        return _rehearse(args)
    if action == "manifest":
        return _manifest(args)
    if action == "images":
        return _images(args)
    raise CliError("ares deploy: give an action (certs, router-config, router, check, rehearse, manifest, images)")


def _images(args: argparse.Namespace) -> int:
    from ares.deploy.images import build_images

    result = build_images(args.base, lambda text: print(f"[images] {text}", file=sys.stderr, flush=True))
    if args.json:
        print(json.dumps(result.as_dict()))
    else:
        for image in result.images:
            print(f"{image.tag}: {image.size_mb:.0f} MB, built in {image.seconds:.0f} s")
            for step in image.steps:
                if step.cached or step.seconds >= 1.0:
                    print(f"  {'cached' if step.cached else f'{step.seconds:6.1f} s'}  {step.name[:100]}")
        if not result.ok:
            print(f"ares deploy images: {result.error}", file=sys.stderr)
    return 0 if result.ok else 1


def _manifest(args: argparse.Namespace) -> int:
    from ares.core.manifest import ReleaseRefused
    from ares.deploy import manifest

    try:
        made = manifest.make_manifest(Path(args.key), Path(args.out))
    except (manifest.ReleaseKeyError, ReleaseRefused, OSError) as exc:
        print(f"ares deploy manifest: {exc}", file=sys.stderr)
        return 2
    print(
        json.dumps(
            {
                "manifest": str(made.manifest),
                "files": made.files,
                "public_key": str(made.public_key),
                "created_key": made.created_key,
            }
        )
    )
    return 0


def _rehearse(args: argparse.Namespace) -> int:
    import json
    import tempfile

    from ares.deploy.rehearse import rehearse

    work = Path(args.work) if args.work else Path(tempfile.mkdtemp(prefix="ares-rehearsal-"))
    if args.containers:
        from ares.deploy.container_rehearsal import rehearse_containers

        figures = rehearse_containers(work, base=args.base, partition_s=args.partition_s)
    else:
        figures = rehearse(work, light=args.light, partition_s=args.partition_s)
    if args.json:
        print(json.dumps(figures))
    else:
        for key, value in figures.items():
            print(f"{key}: {value}")
    return 0 if figures.get("ok") else 1


def _certs(args: argparse.Namespace) -> int:
    from ares.deploy import pki, router_config

    try:
        issued = pki.issue_vehicle(Path(args.fleet_ca), args.vehicle, args.fleet_host, args.api_host)
        vehicle_cfg, fleet_cfg = router_config.write_for_vehicle(Path(args.fleet_ca), args.vehicle, args.fleet_endpoint)
    except pki.PkiError as exc:
        print(f"ares deploy certs: {exc}", file=sys.stderr)
        return 2
    print(
        json.dumps(
            {
                "ca": str(issued.ca),
                "created_ca": issued.created_ca,
                "vehicle": args.vehicle,
                "vehicle_secrets": str(issued.vehicle_dir),
                "vehicle_router_config": str(vehicle_cfg),
                "fleet_secrets": str(issued.fleet_dir),
                "fleet_router_config": str(fleet_cfg),
            }
        )
    )
    return 0


def _router_config(args: argparse.Namespace) -> int:
    from ares.deploy import pki, router_config

    try:
        if args.kind == "fleet":
            vehicles = [v for v in args.vehicles.split(",") if v]
            text = router_config.render(router_config.fleet_router(vehicles), "fleet")
        else:
            text = router_config.render(router_config.vehicle_router(), "vehicle")
    except pki.PkiError as exc:
        print(f"ares deploy router-config: {exc}", file=sys.stderr)
        return 2
    if args.output:
        Path(args.output).write_text(text)
    else:
        sys.stdout.write(text)
    return 0


def _router(args: argparse.Namespace) -> int:
    import zenoh

    from ares.deploy import router, router_config

    try:
        cfg = router_config.load(Path(args.config))
    except (OSError, ValueError) as exc:
        print(f"ares deploy router: {args.config}: {exc}", file=sys.stderr)
        return 2
    cfg = router.localize(cfg, Path(args.secrets) if args.secrets else None, args.listen, args.connect)
    try:
        router.serve(cfg, report_refusals_as=args.report_refusals_as)
    except zenoh.ZError as exc:
        print(f"ares deploy router: {str(exc).split(' at ')[0]}", file=sys.stderr)
        return 1
    return 0


def _check(args: argparse.Namespace) -> int:
    from ares.deploy import check

    try:
        report = check.check(Path(args.folder))
    except check.ComposeMissing as exc:
        print(f"ares deploy check: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(
            json.dumps(
                {"folder": str(report.folder), "ok": report.ok, "problems": report.problems, "checked": report.checked}
            )
        )
    else:
        for problem in report.problems:
            print(f"ares deploy check: {problem}", file=sys.stderr)
        if report.ok:
            print(f"ok: {report.folder} ({'; '.join(report.checked)})")
    return 0 if report.ok else 2
