"""No function on the vehicle's path is longer than a screen (80 lines, its decorators aside, its
docstring in): a longer one is several steps that want their own names. The vehicle's path is the
node packages that run on the shuttle and the core and application layers under them (the
supervisor and the stack run there); the simulator plays the shuttle and is not on it, the tools
and the command line run beside it."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
VEHICLE_PATH = ("managers", "perception", "control", "drivers", "blackbox", "ares/core", "ares/app")
MAX_LINES = 80

# Functions still over the limit, "path::name" -> why they are let be for now. The list may only
# shrink: a listed function that is gone or within the limit fails the test, so that it is struck off.
STILL_LONG: dict[str, str] = {}


def function_lengths(root: Path = REPO) -> dict[str, int]:
    """'path::name' -> lines from `def` to the last line, for every function and method (nested ones
    too, by their own name) of the vehicle's path."""
    lengths: dict[str, int] = {}
    for package in VEHICLE_PATH:
        for path in sorted((root / package).rglob("*.py")):
            tree = ast.parse(path.read_text(), str(path))
            for node in ast.walk(tree):
                if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    assert node.end_lineno is not None
                    key = f"{path.relative_to(root).as_posix()}::{node.name}"
                    lengths[key] = max(lengths.get(key, 0), node.end_lineno - node.lineno + 1)
    return lengths


@pytest.fixture(scope="module")
def lengths() -> dict[str, int]:
    return function_lengths()


def test_every_package_of_the_vehicles_path_is_read(lengths):
    read = {key.split("::")[0] for key in lengths}
    for package in VEHICLE_PATH:
        assert any(path.startswith(package + "/") for path in read), f"no function found under {package}/"


def test_no_function_on_the_vehicles_path_is_longer_than_a_screen(lengths):
    too_long = {key: n for key, n in lengths.items() if n > MAX_LINES and key not in STILL_LONG}
    assert not too_long, "split into named steps: " + ", ".join(
        f"{key} ({n} lines)" for key, n in sorted(too_long.items(), key=lambda kv: -kv[1])
    )


def test_the_list_of_long_functions_only_shrinks(lengths):
    stale = [key for key in STILL_LONG if lengths.get(key, 0) <= MAX_LINES]
    assert not stale, f"within {MAX_LINES} lines now (or gone): strike them off STILL_LONG: {stale}"


def test_the_count_is_from_def_to_the_last_line(tmp_path):
    package = tmp_path / "managers"
    package.mkdir()
    body = "\n".join(f"    x{i} = {i}" for i in range(MAX_LINES - 1))
    (package / "m.py").write_text(f"def fits():\n{body}\n\n\nasync def over():\n{body}\n    return 1\n")
    assert function_lengths(tmp_path) == {"managers/m.py::fits": MAX_LINES, "managers/m.py::over": MAX_LINES + 1}
