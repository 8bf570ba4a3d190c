"""First logins (blackbox/api/first_logins.py): written to a fresh 0600 file, never through what
stood at its place (a stale 0644 file, a symlink), and never printed by `ares run`'s banner."""

from __future__ import annotations

import os
import stat

from blackbox.api.first_logins import FILE, FIRST_USERS, ensure_first_logins
from tests.helpers.api import api_settings, open_test_store, token_for


def make_first_logins(tmp_path):
    store = open_test_store(tmp_path / "blackbox.sqlite")
    try:
        return store, ensure_first_logins(store, api_settings().auth, tmp_path)
    except BaseException:
        store.close()
        raise


def logins(path) -> dict[str, str]:
    return {
        line.split()[0]: line.split()[1] for line in path.read_text().splitlines() if line and not line.startswith("#")
    }


def test_the_first_logins_file_is_new_and_its_owners_only(tmp_path):
    old_umask = os.umask(0)  # the most permissive: the file's mode must not come from it
    try:
        store, path = make_first_logins(tmp_path)
    finally:
        os.umask(old_umask)
    try:
        assert path == tmp_path / FILE and stat.S_IMODE(path.stat().st_mode) == 0o600
        assert set(logins(path)) == set(FIRST_USERS)
        # the passwords in the file are the users' own
        from fastapi.testclient import TestClient

        from blackbox.api import create_app

        client = TestClient(create_app(store, api_settings(state_dir=str(tmp_path / "state")), "shuttle01"))
        for name, password in logins(path).items():
            assert token_for(client, name, password)
        assert ensure_first_logins(store, api_settings().auth, tmp_path) is None  # users exist: nothing made
        assert [p.name for p in tmp_path.iterdir() if p.name.startswith(f".{FILE}")] == []  # no temporary left
    finally:
        store.close()


def test_a_stale_world_readable_file_is_replaced_not_reused(tmp_path):
    stale = tmp_path / FILE
    stale.write_text("old passwords of another store\n")
    os.chmod(stale, 0o644)
    reader = stale.open()  # someone who had it open keeps only the old text
    store, path = make_first_logins(tmp_path)
    try:
        assert stat.S_IMODE(path.stat().st_mode) == 0o600
        assert set(logins(path)) == set(FIRST_USERS)
        assert reader.read() == "old passwords of another store\n"
    finally:
        reader.close()
        store.close()


def test_a_symlink_in_its_place_is_not_followed(tmp_path):
    elsewhere = tmp_path / "elsewhere.txt"
    elsewhere.write_text("not to be touched\n")
    os.chmod(elsewhere, 0o644)
    (tmp_path / FILE).symlink_to(elsewhere)
    store, path = make_first_logins(tmp_path)
    try:
        assert elsewhere.read_text() == "not to be touched\n" and stat.S_IMODE(elsewhere.stat().st_mode) == 0o644
        assert not path.is_symlink() and stat.S_IMODE(path.stat().st_mode) == 0o600
        assert set(logins(path)) == set(FIRST_USERS)
    finally:
        store.close()


def test_the_banner_says_where_the_passwords_are_not_what_they_are(tmp_path):
    from ares.app.stack import first_logins

    db = tmp_path / "blackbox.sqlite"
    cfg = {
        "api": {"state_dir": str(tmp_path), "auth": api_settings().auth.model_dump()},
        "blackbox_store": {"uri": str(db)},
    }
    banner = first_logins(cfg)
    path = tmp_path / FILE
    assert str(path) in banner
    for password in logins(path).values():
        assert password not in banner
    assert "first users made" not in first_logins(cfg)  # a second start: the users exist, nothing is made
