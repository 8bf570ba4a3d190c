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


# What the papers number, read from the papers (not from the table under test): the ARES paper's
# eqs. 1-17 and Algorithms 1-2; the DBW paper's eqs. 1-25, of which 1-3 (the steering-angle sensor's
# gears and magnets) and 15-20 (the uncertainty analysis of v and kappa) are not modelled
PAPER_EQUATIONS = {"ARES": set(range(1, 18)), "DBW": set(range(1, 26))}
PAPER_ALGORITHMS = {"ARES": {"Algorithm 1", "Algorithm 2"}, "DBW": set()}
NOT_MODELLED_EQUATIONS = {"ARES": set(), "DBW": {1, 2, 3} | set(range(15, 21))}


def test_every_equation_the_papers_number_is_placed_or_said_not_modelled():
    from ares.tools.architecture import NOT_MODELLED, numbers

    for paper, expected in PAPER_EQUATIONS.items():
        placed = set().union(*(numbers(eq.label) for eq in EQUATIONS if eq.paper == paper))
        not_modelled = set().union(*(numbers(label) for p, label, _ in NOT_MODELLED if p == paper))
        assert not_modelled == NOT_MODELLED_EQUATIONS[paper], paper
        modelled = expected - not_modelled  # each placed, and nothing else
        assert placed == modelled, (
            f"{paper}: nowhere {sorted(modelled - placed)}, not theirs {sorted(placed - modelled)}"
        )
        algorithms = {eq.label for eq in EQUATIONS if eq.paper == paper and eq.label.startswith("Algorithm")}
        assert algorithms == PAPER_ALGORITHMS[paper], paper
    assert numbers("eqs. 1-3") == {1, 2, 3} and numbers("eq. 6") == {6} and numbers("Algorithm 1") == set()
