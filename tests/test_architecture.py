"""docs/architecture.md is what `ares describe --architecture` prints, its layers are import-linter's,
and every equation it places lives where it says and names itself there."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from ares.app import run_config
from ares.tools.architecture import EQUATIONS, LAYERS, architecture_markdown, names_its_equation, resolve, source_file

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


def test_every_equation_the_papers_number_is_placed():
    from ares.tools.architecture import NOT_MODELLED, PAPER_ALGORITHMS, PAPER_EQUATIONS, numbers

    for paper, expected in PAPER_EQUATIONS.items():
        placed = set().union(*(numbers(eq.label) for eq in EQUATIONS if eq.paper == paper))
        assert expected <= placed, f"{paper} equations nowhere in the table: {sorted(expected - placed)}"
    for paper, algorithms in PAPER_ALGORITHMS.items():
        assert algorithms <= {eq.label for eq in EQUATIONS if eq.paper == paper}
    assert numbers("eqs. 1-3") == {1, 2, 3} and numbers("eq. 6") == {6} and numbers("Algorithm 1") == set()
    assert all(paper == "DBW" for paper, _, _ in NOT_MODELLED)
