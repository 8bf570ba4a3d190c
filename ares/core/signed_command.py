"""An operator's command carries who gave it, signed; the manager that obeys it checks the signature.

A bus password is no identity: every process holding it may call a manager's service and write any
name into the request. So the vehicle's command services (a mission's goal, pause, resume, cancel and
body, the re-arm) obey only a request signed with the vehicle's command key, which the vehicle's own
API (for the operator its token names) and the local CLI (for the user running it) hold, and the
managers hold to check it:

    mac = HMAC-SHA256(key, canonical JSON of {service, payload, operator, issued_at, nonce})

The payload is the request without its `t` and its signature, so a signature made for a drive does
not start a tour, and one made for `mission/pause` does not cancel. The manager records the signed
operator, never a name of the payload. A command older than `max_age_s` (wall clock: the API and the
managers run on one vehicle) is stale; a nonce seen before is a replay. The nonces are kept as long
as they could still be fresh, in memory; what a restarted manager no longer remembers it need not:
it obeys only commands signed after it started, so a command captured before a restart cannot be
replayed after it (an operator whose command met the restart sends it again).

The key: `commands.key_file` (a compose secret on a vehicle), else the file `command_key` in the
user's state directory, made at first use by whichever process needs it first, so that on a
developer's machine the stack, its API and `ares mission` agree on it with nothing to set up.
"""

from __future__ import annotations

import hashlib
import hmac
import json
import os
import secrets
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

from pydantic import BaseModel, ConfigDict, Field

from ares.core.config import CommandSettings, read_secret
from ares.core.schema import Msg

KEY_FILE = "command_key"
MIN_KEY_CHARS = 32
NONCE_BYTES = 16


class CommandSignature(BaseModel):
    model_config = ConfigDict(extra="forbid")

    operator: str = Field(min_length=1, max_length=64)  # the authenticated name the manager records
    issued_at: float  # wall clock, Unix seconds
    nonce: str = Field(pattern=rf"^[0-9a-f]{{{2 * NONCE_BYTES}}}$")
    mac: str = Field(pattern=r"^[0-9a-f]{64}$")


def default_key_path() -> Path:
    base = os.environ.get("XDG_STATE_HOME") or os.path.expanduser("~/.local/state")
    return Path(base) / "ares" / KEY_FILE


def load_command_key(settings: CommandSettings) -> bytes:
    """The configured key file's key, else the state directory's (made when absent, mode 0600)."""
    if settings.key_file:
        text = read_secret(settings.key_file, "commands.key_file")
        if len(text) < MIN_KEY_CHARS:
            raise ValueError(f"commands.key_file {settings.key_file} is too short: at least {MIN_KEY_CHARS} characters")
        return text.encode()
    path = default_key_path()
    if not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        try:
            # O_EXCL: the API and the managers starting together must not each write a key of their own
            fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        except FileExistsError:
            pass
        else:
            with os.fdopen(fd, "w") as f:
                f.write(secrets.token_hex(32) + "\n")
    text = path.read_text().strip()
    while not text:  # another process made the file and is writing its key this very moment
        time.sleep(0.01)
        text = path.read_text().strip()
    return text.encode()


def _mac(key: bytes, service: str, request: Msg, operator: str, issued_at: float, nonce: str) -> str:
    payload = request.model_dump(mode="json", exclude={"t", "signature"})
    signed = {"service": service, "payload": payload, "operator": operator, "issued_at": issued_at, "nonce": nonce}
    text = json.dumps(signed, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hmac.new(key, text.encode(), hashlib.sha256).hexdigest()


Command = TypeVar("Command", bound=Msg)


def sign(key: bytes, service: str, request: Command, operator: str, wall: Callable[[], float] = time.time) -> Command:
    """`request` for `service`, signed as given by `operator` (an authenticated name)."""
    issued_at, nonce = wall(), secrets.token_hex(NONCE_BYTES)
    mac = _mac(key, service, request, operator, issued_at, nonce)
    signature = CommandSignature(operator=operator, issued_at=issued_at, nonce=nonce, mac=mac)
    return request.model_copy(update={"signature": signature})


class CommandVerifier:
    """Checks each command's signature, age and nonce for a manager."""

    def __init__(self, key: bytes, max_age_s: float, wall: Callable[[], float] = time.time):
        self.key = key
        self.max_age_s = max_age_s
        self.wall = wall
        self._seen: dict[str, float] = {}  # nonce -> when issued, while it could still be fresh
        self.started_at = wall()  # the nonces seen before this are not remembered: nor obeyed

    def check(self, service: str, request: Any) -> tuple[str | None, str]:
        """(the signed operator, "") for a command to obey, else (None, why it is refused)."""
        signature: CommandSignature | None = getattr(request, "signature", None)
        if signature is None:
            return None, "refused: an unsigned command (only the vehicle's API or CLI may command it)"
        expected = _mac(self.key, service, request, signature.operator, signature.issued_at, signature.nonce)
        if not hmac.compare_digest(expected, signature.mac):
            return None, "refused: the command's signature does not match (forged, altered or for another service)"
        now = self.wall()
        age = now - signature.issued_at
        if not -self.max_age_s <= age <= self.max_age_s:
            return None, f"refused: a stale command (signed {age:.0f} s ago; at most {self.max_age_s:g} s)"
        if signature.issued_at < self.started_at:
            return None, "refused: a command signed before this manager started (sent again if it is meant)"
        self._seen = {n: at for n, at in self._seen.items() if now - at <= self.max_age_s}
        if signature.nonce in self._seen:
            return None, "refused: a replayed command (its nonce was used already)"
        self._seen[signature.nonce] = signature.issued_at
        return signature.operator, ""
