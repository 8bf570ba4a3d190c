"""The command key (ares/core/signed_command.py): a configured secret, or one file of the user's
state directory that every process of a developer's machine shares."""

from __future__ import annotations

import stat

import pytest

from ares.core.config import CommandSettings
from ares.core.messages import MissionRequest
from ares.core.signed_command import CommandVerifier, load_command_key, sign


def test_the_state_directorys_key_is_made_once_owner_only_and_shared(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path))
    first = load_command_key(CommandSettings())
    path = tmp_path / "ares" / "command_key"
    assert stat.S_IMODE(path.stat().st_mode) == 0o600 and len(first) == 64
    assert load_command_key(CommandSettings()) == first  # the next process reads the same


def test_a_configured_key_is_read_and_a_short_one_refused(tmp_path):
    good, short = tmp_path / "good", tmp_path / "short"
    good.write_text("k" * 40 + "\n")
    short.write_text("k" * 8)
    assert load_command_key(CommandSettings(key_file=str(good))) == b"k" * 40
    with pytest.raises(ValueError, match="too short"):
        load_command_key(CommandSettings(key_file=str(short)))
    with pytest.raises(ValueError, match="commands.key_file"):
        load_command_key(CommandSettings(key_file=str(tmp_path / "absent")))


def test_a_nonce_is_forgotten_only_once_its_command_is_stale():
    wall = [1000.0]
    verifier = CommandVerifier(b"k" * 32, max_age_s=10.0, wall=lambda: wall[0])
    pause = sign(b"k" * 32, "mission/pause", MissionRequest(operator="ana"), "ana", wall=lambda: 1000.0)
    assert verifier.check("mission/pause", pause) == ("ana", "")
    wall[0] = 1009.0
    assert "replayed" in verifier.check("mission/pause", pause)[1]
    wall[0] = 1011.0
    assert "stale" in verifier.check("mission/pause", pause)[1]


def test_a_command_captured_before_a_managers_restart_is_not_obeyed_after_it():
    """The nonces live in memory: a restarted manager has forgotten them, so it obeys only what was
    signed after it started (the replay of a fresh command captured just before is refused)."""
    key, wall = b"k" * 32, [1000.0]
    pause = sign(key, "mission/pause", MissionRequest(operator="ana"), "ana", wall=lambda: 1000.0)
    assert CommandVerifier(key, max_age_s=10.0, wall=lambda: wall[0]).check("mission/pause", pause)[0] == "ana"
    wall[0] = 1002.0  # the manager restarted 2 s later: the command is still fresh
    restarted = CommandVerifier(key, max_age_s=10.0, wall=lambda: wall[0])
    assert "before this manager started" in restarted.check("mission/pause", pause)[1]
    again = sign(key, "mission/pause", MissionRequest(operator="ana"), "ana", wall=lambda: 1002.5)
    assert restarted.check("mission/pause", again) == ("ana", "")
