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
        help="REST API users: add, list, role, passwd, disable, enable, delete",
        description="Users of the black box's REST API and their roles (auditor, operator, fleet, admin). "
        "A change of role or password, a disabling or a deletion refuses every token the user holds "
        "at its next request.",
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
    role = users_sub.add_parser("role", help="change a user's role", description="Change a user's role.")
    role.add_argument("name", metavar="NAME")
    role.add_argument("role", choices=["auditor", "operator", "fleet", "admin"])
    role.add_argument("--store", metavar="URI", help="mongodb:// URI or the embedded store's file")
    passwd = users_sub.add_parser(
        "passwd",
        help="change a user's password, read from stdin",
        description="Change a user's password; read from stdin as `add` reads it.",
    )
    passwd.add_argument("name", metavar="NAME")
    passwd.add_argument("--store", metavar="URI", help="mongodb:// URI or the embedded store's file")
    for action, what in (
        ("disable", "refuse a user's logins and tokens (kept, `enable` undoes it)"),
        ("enable", "allow a disabled user again"),
        ("delete", "remove a user"),
    ):
        sub = users_sub.add_parser(action, help=what, description=what[0].upper() + what[1:] + ".")
        sub.add_argument("name", metavar="NAME")
        sub.add_argument("--store", metavar="URI", help="mongodb:// URI or the embedded store's file")
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
    from ares.core import config
    from blackbox.api import serve
    from blackbox.register import snapshot_files

    cfg, settings, store_settings, uri = _api_context(args)
    beside = store_settings.model_copy(update={"uri": uri})  # --store: the snapshots are beside it
    try:
        serve(
            settings,
            uri,
            vehicle_id=cfg["vehicle_id"],
            store_settings=store_settings,
            snapshots_dir=snapshot_files.folder(config.core(cfg).recording.snapshots, beside),
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


USER_ACTIONS = ("add", "list", "role", "passwd", "disable", "enable", "delete")


def cmd_users(args: argparse.Namespace) -> int:
    if args.users not in USER_ACTIONS:
        raise CliError(
            "which action? try `ares users add NAME --role ROLE`, `ares users list`, or "
            "`ares users role|passwd|disable|enable|delete NAME`"
        )
    _, settings, store_settings, uri = _api_context(args)
    from blackbox.api.credentials import UserError, check_new_user, check_password
    from blackbox.register.store.record_store import StoreUnavailable

    password = ""
    if args.users in ("add", "passwd"):
        password = _read_new_password()
        try:  # before the store is opened: a bad name or password costs nothing
            if args.users == "add":
                check_new_user(args.name, args.role, password, settings.auth.min_password_length)
            else:
                check_password(password, settings.auth.min_password_length)
        except UserError as exc:
            raise CliError(str(exc)) from None
    store = _open_store(uri, store_settings)
    try:
        if args.users == "list":
            return _list_users(store, args.json)
        print(_change_user(store, args, settings.auth, password))
        return 0
    except UserError as exc:
        raise CliError(str(exc)) from None
    except StoreUnavailable as exc:
        raise CliError(f"black box store unavailable: {exc}") from None
    finally:
        store.close()


def _change_user(store, args: argparse.Namespace, auth, password: str) -> str:
    """Do `ares users add|role|passwd|disable|enable|delete` on the store; what to print."""
    from blackbox.api import credentials

    if args.users == "add":
        passwords = credentials.Passwords(auth.argon2)
        user = credentials.add_user(store, passwords, args.name, args.role, password, auth.min_password_length)
        return f"added {user.name} ({user.role})"
    if args.users == "role":
        user = credentials.set_role(store, args.name, args.role)
        return f"{user.name} is {user.role} now (the tokens it held are refused)"
    if args.users == "passwd":
        passwords = credentials.Passwords(auth.argon2)
        credentials.set_password(store, passwords, args.name, password, auth.min_password_length)
        return f"password of {args.name} changed (the tokens it held are refused)"
    if args.users == "delete":
        credentials.delete_user(store, args.name)
        return f"deleted {args.name} (the tokens it held are refused)"
    disabled = args.users == "disable"
    credentials.set_disabled(store, args.name, disabled)
    return f"{args.name} {'disabled (its tokens are refused)' if disabled else 'enabled'}"


def _list_users(store, as_json: bool) -> int:
    users = store.list_users()
    if as_json:
        rows = [
            {"name": u.name, "role": u.role, "created": u.created.isoformat(), "disabled": u.disabled} for u in users
        ]
        print(json.dumps({"users": rows}))
        return 0
    for u in users:
        print(f"{u.name:<32}  {u.role:<8}  {u.created.isoformat()}{'  disabled' if u.disabled else ''}")
    if not users:
        print("(no users: add one with `ares users add NAME --role admin`)", file=sys.stderr)
    return 0
