"""First logins: a stack started on a black box without users makes one per page's role.

`ares run` on a fresh store would otherwise serve pages nobody can log in to. The passwords are
random (never a default a fleet would forget to change) and written only to `first_logins.txt`
beside the store, its owner's only (0600): never printed, so they do not end up in a container's
logs (the banner says where the file is). The file is made new each time, never written through
what stood at its place: a stale file (whatever its mode) or a symlink there is replaced, not
followed. `ares users` changes or removes these users and makes more. A store that has any user
is left as it is.
"""

from __future__ import annotations

import os
import secrets
from pathlib import Path

from blackbox.api.credentials import AuthSettings, Passwords, add_user
from blackbox.register.store.record_store import RecordStore

FIRST_USERS = ("operator", "auditor", "fleet")  # a user per page, named after its role
FILE = "first_logins.txt"
FILE_MODE = 0o600


def ensure_first_logins(store: RecordStore, auth: AuthSettings, folder: Path) -> Path | None:
    """Make the first users if the store has none; the file that lists them, else None."""
    if store.list_users():
        return None
    logins = {role: secrets.token_urlsafe(12) for role in FIRST_USERS}
    lines = [
        "# ARES first logins: one user per page (https://<api>/operator, /blackbox, /fleet).",
        "# Made because the black box had no user; change them with `ares users`.",
        *(f"{role:<9} {password}   (role {role})" for role, password in logins.items()),
    ]
    path = folder / FILE
    # the file first: users whose passwords nobody could read would be no logins at all
    write_owner_only(path, "\n".join(lines) + "\n")
    passwords = Passwords(auth.argon2)
    for role, password in logins.items():
        add_user(store, passwords, role, role, password, auth.min_password_length)
    return path


def write_owner_only(path: Path, text: str) -> None:
    """`text` in a new file at `path`, mode 0600 whatever the umask: written to a fresh file made
    with O_EXCL and O_NOFOLLOW beside it (no one else's file or link is ever opened), then renamed
    over `path` (a rename replaces a symlink there, it does not follow it)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fresh = path.with_name(f".{path.name}.{secrets.token_hex(8)}")
    fd = os.open(fresh, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, FILE_MODE)
    try:
        os.fchmod(fd, FILE_MODE)  # the umask could have narrowed it; nothing may widen it
        with os.fdopen(fd, "w") as out:
            out.write(text)
            out.flush()
            os.fsync(out.fileno())
        os.replace(fresh, path)
    except BaseException:
        fresh.unlink(missing_ok=True)
        raise
