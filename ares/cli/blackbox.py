"""The black box's REST API: `ares api` serves it, `ares users` manages its users."""

from __future__ import annotations

import argparse
import json
import sys

from .args import CliError, Command, port


def add_parser(subparsers: argparse._SubParsersAction) -> dict[str, Command]:
    api = subparsers.add_parser(
        "api",
        help="serve the black box's REST API over HTTPS",
        description="Serve the black box's REST API (read-only: records, events, reliability; "
        "users for admins) over HTTPS with the configured certificate, or a self-signed "
        "one for localhost kept in the API's state directory. Settings: the `api:` "
        "section of the configuration.",
    )
    api.add_argument("--host", metavar="H", help="address to listen on (default api.host, 127.0.0.1)")
    api.add_argument("--port", type=port, metavar="P", help="port (default api.port, 8443)")
    api.add_argument(
        "--store",
        metavar="URI",
        help="mongodb:// URI or the embedded store's file "
        "(default: blackbox.register.store.record_store, else the embedded store)",
    )
    api.add_argument(
        "--insecure-http",
        action="store_true",
        help="serve plain HTTP instead of HTTPS (tokens and records in clear: trusted networks only)",
    )

    users = subparsers.add_parser(
        "users",
        help="REST API users: add, list",
        description="Users of the black box's REST API and their roles (auditor, operator, fleet, admin).",
    )
    users_sub = users.add_subparsers(dest="users", metavar="ACTION")
    add = users_sub.add_parser(
        "add",
        help="add a user; the password is read from stdin",
        description="Add a user. The password is read from stdin: asked twice without "
        "echo on a terminal; from a pipe, one line (or two identical lines).",
    )
    add.add_argument("name", metavar="NAME", help="user name (lower-case letters, digits, '_', '.', '-')")
    add.add_argument("--role", required=True, choices=["auditor", "operator", "fleet", "admin"])
    add.add_argument("--store", metavar="URI", help="mongodb:// URI or the embedded store's file")
    lst = users_sub.add_parser("list", help="list users and their roles", description="List the API's users.")
    lst.add_argument("--store", metavar="URI", help="mongodb:// URI or the embedded store's file")
    lst.add_argument("--json", action="store_true", help="print one JSON object")
    return {"api": cmd_api, "users": cmd_users}


def _api_context(args: argparse.Namespace):
    """(configuration, ApiSettings, StoreSettings, store URI) of `ares api` / `ares users`."""
    from ares.core import config
    from blackbox.api import ApiSettings
    from blackbox.register.store.record_store import StoreSettings

    try:
        cfg = config.current()
        settings = config.section(cfg, "api", ApiSettings)
        store_settings = config.section(cfg, "blackbox_store", StoreSettings)
    except (config.ConfigError, OSError, ValueError) as exc:
        raise CliError(f"cannot read the configuration: {exc}") from None
    uri = getattr(args, "store", None) or store_settings.location()
    return cfg, settings, store_settings, uri


def _open_store(uri: str, settings):
    from blackbox.register.store.open_store import open_store
    from blackbox.register.store.record_store import StoreUnavailable

    try:
        store = open_store(uri, settings=settings)
        store.ping()
    except StoreUnavailable as exc:
        raise CliError(f"black box store unavailable: {exc}") from None
    return store


def cmd_api(args: argparse.Namespace) -> int:
    from blackbox.api import serve

    cfg, settings, store_settings, uri = _api_context(args)
    try:
        serve(
            settings,
            uri,
            vehicle_id=cfg["vehicle_id"],
            store_settings=store_settings,
            insecure_http=args.insecure_http,
            host=args.host,
            port=args.port,
        )
    except OSError as exc:  # address in use, certificate directory not writable, ...
        raise CliError(f"cannot serve the API: {exc}") from None
    except ValueError as exc:  # e.g. a configured certificate without its key
        raise CliError(str(exc)) from None
    return 0


def _read_new_password() -> str:
    if sys.stdin.isatty():
        import getpass

        first = getpass.getpass("password: ")
        if getpass.getpass("again: ") != first:
            raise CliError("the two passwords differ")
        return first
    lines = sys.stdin.read().splitlines()
    if not lines or not lines[0]:
        raise CliError("no password on stdin (pipe one line, or two identical lines)")
    if len(lines) > 2 or (len(lines) == 2 and lines[1] != lines[0]):
        raise CliError("stdin must hold the password on one line, or twice on two lines")
    return lines[0]


def cmd_users(args: argparse.Namespace) -> int:
    if args.users not in ("add", "list"):
        raise CliError("which action? try `ares users add NAME --role ROLE` or `ares users list`")
    _, settings, store_settings, uri = _api_context(args)
    from blackbox.api.credentials import Passwords, UserError, add_user, check_new_user
    from blackbox.register.store.record_store import StoreUnavailable

    if args.users == "add":
        password = _read_new_password()
        try:  # before the store is opened: a bad name or password costs nothing
            check_new_user(args.name, args.role, password, settings.auth.min_password_length)
        except UserError as exc:
            raise CliError(str(exc)) from None
    store = _open_store(uri, store_settings)
    try:
        if args.users == "add":
            user = add_user(
                store,
                Passwords(settings.auth.argon2),
                args.name,
                args.role,
                password,
                settings.auth.min_password_length,
            )
            print(f"added {user.name} ({user.role})")
            return 0
        users = store.list_users()
        if args.json:
            print(
                json.dumps(
                    {"users": [{"name": u.name, "role": u.role, "created": u.created.isoformat()} for u in users]}
                )
            )
        else:
            for u in users:
                print(f"{u.name:<32}  {u.role:<8}  {u.created.isoformat()}")
            if not users:
                print("(no users: add one with `ares users add NAME --role admin`)", file=sys.stderr)
        return 0
    except UserError as exc:
        raise CliError(str(exc)) from None
    except StoreUnavailable as exc:
        raise CliError(f"black box store unavailable: {exc}") from None
    finally:
        store.close()
