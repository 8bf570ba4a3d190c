"""The usage text at the top of ares/cli/__init__.py lists every command the parsers register, each
subcommand and choice of action, and every option of each: a command added without its line fails here."""

from __future__ import annotations

import argparse
import re
from dataclasses import dataclass

import pytest

import ares.cli
from ares.cli import build_parser

USAGE = ares.cli.__doc__ or ""


@dataclass(frozen=True)
class Command:
    path: tuple[str, ...]  # ("bench", "mpc")
    parser: argparse.ArgumentParser


def _subparsers(parser: argparse.ArgumentParser) -> argparse._SubParsersAction | None:
    return next((a for a in parser._actions if isinstance(a, argparse._SubParsersAction)), None)


def leaf_commands(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()) -> list[Command]:
    """Every command that runs something: a subparser without subparsers of its own."""
    subs = _subparsers(parser)
    if subs is None:
        return [Command(path, parser)]
    return [found for name, sub in subs.choices.items() for found in leaf_commands(sub, (*path, name))]


COMMANDS = leaf_commands(build_parser())


def entries(usage: str) -> list[str]:
    """The usage text's entries: a line `    ares ...` and the lines indented under it."""
    found: list[list[str]] = []
    current: list[str] | None = None
    for line in usage.splitlines():
        if line.startswith("    ares "):
            current = [line]
            found.append(current)
        elif current is not None and line.startswith("     ") and line.strip():
            current.append(line)
        else:  # a blank or unindented line ends the entry
            current = None
    return ["\n".join(lines) for lines in found]


def _words(text: str) -> set[str]:
    """The words of a synopsis, alternatives apart: `[--mode peer|client]` -> --mode, peer, client."""
    return set(re.split(r"[\s\[\]|,]+", text)) - {""}


def entries_of(path: tuple[str, ...], usage: str = USAGE) -> list[str]:
    """The entries whose first words name the command: `ares bench mpc ...`, `ares config check ...`."""
    matching = []
    for entry in entries(usage):
        words = entry.split()[1:]
        if len(words) >= len(path) and all(part in words[i].split("|") for i, part in enumerate(path)):
            matching.append(entry)
    return matching


def test_the_usage_text_reads_as_entries():
    assert len(entries(USAGE)) >= len(COMMANDS) - 3  # mission's and driver's actions share one entry
    assert entries_of(("bench", "mpc")) and not entries_of(("bench", "no-such-bench"))


@pytest.mark.parametrize("command", COMMANDS, ids=lambda c: " ".join(c.path))
def test_every_command_has_its_entry(command):
    assert entries_of(command.path), f"`ares {' '.join(command.path)}` is missing from ares/cli/__init__.py's usage"


@pytest.mark.parametrize("command", COMMANDS, ids=lambda c: " ".join(c.path))
def test_every_option_and_action_of_a_command_is_in_its_entry(command):
    text = "\n".join(entries_of(command.path))
    words = _words(text)
    for action in command.parser._actions:
        if isinstance(action, argparse._HelpAction):
            continue
        if action.option_strings:
            assert words & set(action.option_strings), (
                f"`ares {' '.join(command.path)}`: {'/'.join(action.option_strings)} is missing from its usage entry"
            )
        elif action.choices:  # an action chosen by name: `ares mission pause`, `ares calibrate road`
            missing = [str(choice) for choice in action.choices if str(choice) not in words]
            assert not missing, f"`ares {' '.join(command.path)}`: {missing} missing from its usage entry"
