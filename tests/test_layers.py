"""docs/design.md §1: the layers hold and there is no import cycle (import-linter's contracts in
pyproject.toml); `ares` is its layers, one folder each, with no module beside them but its
package marker; every module of the project sits in a layer of the contract."""

from __future__ import annotations

import pkgutil
import subprocess
import sys
import tomllib
from pathlib import Path

import ares

REPO = Path(__file__).resolve().parents[1]
CONTRACTS = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["importlinter"]


def test_the_import_contracts_are_kept():
    lint = Path(sys.executable).with_name("lint-imports")
    result = subprocess.run([str(lint), "--no-cache"], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-2000:]
    assert "0 broken" in result.stdout


def test_ares_is_one_folder_per_layer():
    layers = next(c for c in CONTRACTS["contracts"] if c["type"] == "layers")["layers"]
    placed = {name.strip() for layer in layers for name in layer.split("|")}
    children = list(pkgutil.iter_modules(ares.__path__))
    assert all(child.ispkg for child in children), f"modules beside the layers: {[c.name for c in children]}"
    assert {f"ares.{c.name}" for c in children} == {p for p in placed if p.startswith("ares.")}
    assert len(list(Path(ares.__file__).parent.glob("*.py"))) <= 8


def test_every_top_level_package_is_in_a_layer():
    layers = next(c for c in CONTRACTS["contracts"] if c["type"] == "layers")["layers"]
    placed = {name.strip().split(".")[0] for layer in layers for name in layer.split("|")}
    assert placed == set(CONTRACTS["root_packages"])
