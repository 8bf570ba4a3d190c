"""First logins: a stack started on a black box without users makes one per page's role.

`ares run` on a fresh store would otherwise serve pages nobody can log in to. The passwords are
random (never a default a fleet would forget to change), printed once and written to
`first_logins.txt` beside the store (readable by its owner only); `ares users add` makes more,
and an admin can remove these. A store that has any user is left as it is.
"""

from __future__ import annotations

import os
import secrets
from pathlib import Path

from blackbox.api.credentials import AuthSettings, Passwords, add_user
from blackbox.register.store.record_store import RecordStore

FIRST_USERS = ("operator", "auditor", "fleet")  # a user per page, named after its role
FILE = "first_logins.txt"


def ensure_first_logins(store: RecordStore, auth: AuthSettings, folder: Path) -> Path | None:
    """Make the first users if the store has none; the file that lists them, else None."""
    if store.list_users():
        return None
    passwords = Passwords(auth.argon2)
    lines = [
        "# ARES first logins: one user per page (https://<api>/operator, /blackbox, /fleet).",
        "# Made because the black box had no user; change them with `ares users`.",
    ]
    for role in FIRST_USERS:
        password = secrets.token_urlsafe(12)
        add_user(store, passwords, role, role, password, auth.min_password_length)
        lines.append(f"{role:<9} {password}   (role {role})")
    path = folder / FILE
    path.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as out:
        out.write("\n".join(lines) + "\n")
    return path
