"""docs/architecture.md is what `ares describe --architecture` prints, its layers are import-linter's,
and every equation it places lives where it says and names itself there."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from ares.app import run_config
from ares.app.architecture import EQUATIONS, LAYERS, architecture_markdown, names_its_equation, resolve, source_file

REPO = Path(__file__).resolve().parents[1]


def test_docs_architecture_md_is_what_ares_describe_prints():
    actual = (REPO / "docs" / "architecture.md").read_text()
    expected = architecture_markdown(run_config.build())
    assert actual == expected, (
        "docs/architecture.md is stale: run `ares describe --architecture > docs/architecture.md`"
    )


def test_the_layers_are_import_linters():
    contracts = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"]
    layers = next(c for c in contracts if c["type"] == "layers")["layers"]
    assert [tuple(name.strip() for name in row.split("|")) for row in layers] == [layer.packages for layer in LAYERS]


@pytest.mark.parametrize("eq", EQUATIONS, ids=lambda eq: f"{eq.paper} {eq.label}")
def test_each_equation_lives_where_the_page_says_and_names_itself_there(eq):
    assert callable(resolve(eq.target)), eq.target
    assert (REPO / source_file(eq.target)).is_file()
    assert names_its_equation(eq), f"{eq.target}: neither it nor its module names {eq.paper} {eq.label}"
