"""Each node package's README holds its processes' contracts as `ares describe --package NAME
--markdown` prints them (as docs/nodes.md holds the stack's), the README's process table is the
process table, and the project's own pages link only inside the repository."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from ares.app import run_config
from ares.app.processes import FLEET_SERVER, PROCESSES
from ares.tools import package_docs

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def cfg():
    return run_config.build()


@pytest.mark.parametrize("package", package_docs.NODE_PACKAGES)
def test_each_package_readme_holds_its_generated_part_fresh(cfg, package):
    path = package_docs.readme_path(package)
    assert path == REPO / package / "README.md"
    part = package_docs.generated_part(path.read_text(), package)
    assert part is not None, f"{package}/README.md has no generated part (its markers)"
    assert part == package_docs.package_markdown(cfg, package), (
        f"{package}/README.md is stale: run `ares describe --package {package} --markdown --write`"
    )


@pytest.mark.parametrize("package", package_docs.NODE_PACKAGES)
def test_each_package_readme_says_its_design_limits_and_tuning(package):
    text = package_docs.readme_path(package).read_text()
    for heading in ("## Design", "## Processes", "## Assumptions and known limits", "## How to tune"):
        assert f"\n{heading}\n" in text, f"{package}/README.md lacks its section {heading!r}"


def test_every_process_is_in_a_node_package_readme():
    placed = [spec for package in package_docs.NODE_PACKAGES for spec in package_docs.package_processes(package)]
    assert sorted(placed, key=repr) == sorted([*PROCESSES, *FLEET_SERVER], key=repr)


def test_writing_a_part_keeps_the_hand_written_text(cfg, tmp_path):
    text = package_docs.readme_path("drivers").read_text()
    stale = text.replace("### gnss_driver\n", "### gnss_driver (old)\n", 1)
    assert package_docs.generated_part(stale, "drivers") != package_docs.package_markdown(cfg, "drivers")
    mended = package_docs.with_part(stale, "drivers", package_docs.package_markdown(cfg, "drivers"))
    assert mended == text
    with pytest.raises(ValueError, match="no generated part"):
        package_docs.with_part("# drivers\n\nno markers\n", "drivers", "part")


def test_the_readmes_process_table_is_the_process_table():
    readme = (REPO / "README.md").read_text()
    table = "\n".join(package_docs.process_table())
    assert table in readme, "README.md's process table is stale: paste `package_docs.process_table()` into it"


def _pages() -> list[Path]:
    return [
        REPO / "README.md",
        REPO / "docs" / "design.md",
        *(package_docs.readme_path(package) for package in package_docs.NODE_PACKAGES),
    ]


@pytest.mark.parametrize("page", _pages(), ids=lambda p: str(p.relative_to(REPO)))
def test_the_pages_link_only_inside_the_repository(page):
    text = page.read_text()
    assert "../shared" not in text and "DESIGN.md" not in text
    for target in re.findall(r"\]\(([^)\s]+)\)", text):
        if re.match(r"[a-z]+:", target) or target.startswith("#"):  # a web address or an anchor
            continue
        resolved = (page.parent / target.split("#")[0]).resolve()
        assert resolved.is_relative_to(REPO), f"{page.name}: {target} leads out of the repository"
        assert resolved.exists(), f"{page.name}: {target} does not exist"


def test_ares_describe_prints_a_packages_part_and_refuses_what_is_not_one(cfg, capsys):
    from ares.cli import main

    assert main(["describe", "--package", "drivers", "--markdown"]) == 0
    assert capsys.readouterr().out == package_docs.package_markdown(cfg, "drivers")
    assert main(["describe", "--package", "ares"]) == 1
    assert "not a node package" in capsys.readouterr().err
    assert main(["describe", "--write"]) == 1
    assert "name the package" in capsys.readouterr().err
    assert main(["describe", "mpc", "--package", "control"]) == 1
