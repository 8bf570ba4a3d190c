"""An operator's commands as the vehicle's API or CLI sends them, signed (ares/core/signed_command.py)
with the key the managers of a run configuration check them with."""

from __future__ import annotations

import secrets
from pathlib import Path
from typing import TypeVar

from ares.core import config
from ares.core.schema import Msg
from ares.core.signed_command import load_command_key, sign

Command = TypeVar("Command", bound=Msg)


def with_command_key(cfg: dict, folder: Path) -> dict:
    """`cfg` with a command key of its own in `folder` (not the user's state directory's)."""
    path = Path(folder) / "command_key"
    path.write_text(secrets.token_hex(32) + "\n")
    path.chmod(0o600)
    return config.deep_merge(cfg, {"commands": {"key_file": str(path)}})


def signed(cfg: dict, service: str, request: Command, operator: str | None = None) -> Command:
    """`request` for `service` signed as by `operator` (default: the name the request gives)."""
    key = load_command_key(config.core(cfg).commands)
    return sign(key, service, request, operator or request.operator)


def call_signed(bus, cfg: dict, service: str, request: Msg, operator: str | None = None):
    """The reply of `service` to `request`, signed as by `operator` (default: the one it names)."""
    return bus.call(service, signed(cfg, service, request, operator))
