"""What the image gets: deploy/Dockerfile installs the project's wheel, so the wheel must carry the
pages, the libraries they load and the packaged configuration; and the Dockerfile keeps its
promises (pinned bases, the Python the tests run, a non-root user, no build tools at the end)."""

from __future__ import annotations

import platform
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DOCKERFILE = REPO / "deploy" / "Dockerfile"


def test_the_wheel_carries_the_pages_their_libraries_and_the_configuration(tmp_path):
    # built from a copy of what the Dockerfile copies: the build leaves nothing in the checkout
    source = tmp_path / "src"
    source.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(REPO / name, source / name)
    for package in ("ares", "managers", "perception", "control", "blackbox"):
        shutil.copytree(REPO / package, source / package, ignore=shutil.ignore_patterns("__pycache__"))
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(tmp_path), str(source)],
        check=True,
        capture_output=True,
        timeout=300,
    )
    (wheel,) = tmp_path.glob("ares-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    for page in ("operator", "blackbox", "fleet"):
        assert f"blackbox/web/pages/{page}.main.html" in names
        assert f"blackbox/web/static/{page}.js" in names
    assert "blackbox/web/node_modules/leaflet/dist/leaflet.js" in names
    assert "blackbox/web/node_modules/uplot/dist/uPlot.iife.min.js" in names
    assert any(n.startswith("ares/core/config/vehicles/") and n.endswith(".yaml") for n in names)
    assert any(n.startswith("ares/core/config/tours/") for n in names)
    assert not any(n.startswith(("tests/", "deploy/")) for n in names)


def _stages() -> dict[str, str]:
    """The Dockerfile's stages by name (the last, unnamed: 'final'), each its text after FROM."""
    stages = {}
    for chunk in DOCKERFILE.read_text().split("\nFROM ")[1:]:
        head = chunk.splitlines()[0].split()
        stages[head[2] if len(head) == 3 and head[1] == "AS" else "final"] = chunk
    return stages


def test_the_dockerfile_keeps_its_promises():
    text = DOCKERFILE.read_text()
    python_image = re.search(r"ARG BASE_IMAGE=python:(\S+)-slim-bookworm", text)
    assert python_image and python_image[1] == platform.python_version()  # the Python the tests ran on
    assert "# syntax=" not in text  # the engine's own frontend: nothing pulled for it, offline too
    stages = _stages()
    assert set(stages) == {"base", "web", "build", "final"}
    assert stages["base"].startswith("${BASE_IMAGE} AS base")
    assert all(stages[name].startswith("base") for name in ("web", "build", "final"))  # one base for all
    final = stages["final"]
    assert "USER ares" in final and "useradd --system --uid 10001" in final
    assert not re.search(r"build-essential|gcc|\bnpm\b|pip install", final)
    assert "COPY --from=build /opt/ares /opt/ares" in final
    # the CA bundle a re-signing network needs is a build secret, never a layer
    assert "--mount=type=secret,id=ca" in stages["build"] and "--mount=type=secret,id=ca" in stages["web"]
    assert "ca-certificates.crt" not in text


def test_the_image_copies_every_package_the_wheel_installs():
    """The build stage installs from what it copied: a package of pyproject.toml left out of its
    COPY lines is silently missing from the image (as drivers/ and simulator/ once were)."""
    import tomllib

    find = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]["find"]
    packages = {pattern.rstrip("*") for pattern in find["include"]}
    build = _stages()["build"]
    copied = {
        source
        for line in build.splitlines()
        if line.startswith("COPY ") and "--from=" not in line
        for source in line.split()[1:-1]
    }
    assert copied - {"pyproject.toml", "README.md"} == packages
    assert all((REPO / package / "__init__.py").is_file() for package in packages)
