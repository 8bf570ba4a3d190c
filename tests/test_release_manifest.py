"""The release manifest (ARES §3.8.3: the software's version verified, the vehicle prevented from
starting on any anomaly): `ares deploy manifest` hashes and signs the installed stack; the check
at start passes the release and refuses, in one line naming the first differing file, a changed
byte, an added or a removed file, and a manifest unsigned or signed by another key. Small package
trees stand for the installation where a file must change; the installed packages themselves are
hashed by the command and checked by `ares run`."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from ares.app import run_config
from ares.core import config
from ares.core.manifest import (
    PACKAGES,
    ReleaseRefused,
    ReleaseSettings,
    check_release,
    file_hashes,
    load_public_key,
    package_roots,
    signed_manifest,
    verified_files,
)
from ares.deploy.manifest import make_manifest, public_key_path, release_key

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture
def release(tmp_path):
    """Two packages with code, bytecode and data, their signed manifest and the fleet's key."""
    roots = {}
    for name in ("ares", "simulator"):
        root = tmp_path / "site" / name
        (root / "__pycache__").mkdir(parents=True)
        (root / "__init__.py").write_text(f'"""{name}"""\n')
        (root / "__pycache__" / "__init__.cpython-311.pyc").write_bytes(b"\xa7\r\r\n" + bytes(12))
        roots[name] = root
    (roots["simulator"] / "scenarios").mkdir()
    (roots["simulator"] / "scenarios" / "rain.yaml").write_text("faults: []\n")
    key = tmp_path / "fleet" / "release_key"
    made = make_manifest(key, tmp_path / "release.json", roots)
    settings = ReleaseSettings(manifest=str(made.manifest), public_key=str(made.public_key))
    return roots, settings, key


def refusal(settings: ReleaseSettings, roots) -> str:
    with pytest.raises(ReleaseRefused) as caught:
        check_release(settings, roots)
    message = str(caught.value)
    assert "\n" not in message
    return message


def test_the_release_passes(release):
    roots, settings, key = release
    check_release(settings, roots)
    assert key.stat().st_mode & 0o077 == 0  # the private half is its owner's alone
    files = json.loads(Path(settings.manifest).read_text())["files"]
    assert set(files) == {
        "ares/__init__.py",
        "ares/__pycache__/__init__.cpython-311.pyc",
        "simulator/__init__.py",
        "simulator/__pycache__/__init__.cpython-311.pyc",
        "simulator/scenarios/rain.yaml",
    }


def test_no_manifest_checks_nothing(release):
    roots, _, _ = release
    shutil.rmtree(roots["ares"])
    check_release(ReleaseSettings(), roots)  # a developer's checkout: off


def test_one_byte_changed_is_refused_naming_the_file(release):
    roots, settings, _ = release
    data = roots["simulator"] / "scenarios" / "rain.yaml"
    data.write_bytes(data.read_bytes().replace(b"[]", b"[["))
    assert refusal(settings, roots).endswith("simulator/scenarios/rain.yaml: differs from the release")


def test_a_planted_bytecode_file_is_refused(release):
    roots, settings, _ = release
    (roots["ares"] / "__pycache__" / "bus.cpython-311.pyc").write_bytes(b"\xa7\r\r\n" + bytes(12))
    assert refusal(settings, roots).endswith("ares/__pycache__/bus.cpython-311.pyc: installed, not in the release")


def test_an_added_and_a_removed_file_are_refused(release):
    roots, settings, _ = release
    (roots["ares"] / "backdoor.py").write_text("import os\n")
    assert refusal(settings, roots).endswith("ares/backdoor.py: installed, not in the release")
    (roots["ares"] / "backdoor.py").unlink()
    (roots["simulator"] / "scenarios" / "rain.yaml").unlink()
    assert refusal(settings, roots).endswith(
        "simulator/scenarios/rain.yaml: in the release, missing from the installation"
    )


def test_a_manifest_signed_by_another_key_is_refused(release, tmp_path):
    roots, settings, _ = release
    files = json.loads(Path(settings.manifest).read_text())["files"]
    forged = tmp_path / "forged.json"
    forged.write_text(json.dumps(signed_manifest(files, Ed25519PrivateKey.generate())))
    message = refusal(settings.model_copy(update={"manifest": str(forged)}), roots)
    assert message.endswith("its signature is not the fleet's release key's")
    # a signed manifest edited afterwards (a file's hash put right after a change) is refused too
    edited = json.loads(Path(settings.manifest).read_text())
    edited["files"]["ares/backdoor.py"] = "0" * 64
    forged.write_text(json.dumps(edited))
    assert "its signature is not the fleet's" in refusal(settings.model_copy(update={"manifest": str(forged)}), roots)


def test_an_unsigned_manifest_is_refused(release, tmp_path):
    roots, settings, _ = release
    unsigned = json.loads(Path(settings.manifest).read_text())
    del unsigned["signature"]
    path = tmp_path / "unsigned.json"
    path.write_text(json.dumps(unsigned))
    assert refusal(settings.model_copy(update={"manifest": str(path)}), roots).endswith("unsigned")


def test_the_section_takes_both_paths_or_neither(tmp_path):
    with pytest.raises(config.ConfigError, match="release: give both manifest and public_key"):
        run_config.build((), {"release": {"manifest": str(tmp_path / "m.json")}})


def test_ares_deploy_manifest_hashes_every_installed_package_and_its_data(tmp_path):
    key, out = tmp_path / "fleet" / "release_key", tmp_path / "release.json"
    from tests.test_deploy_check import ares

    result = ares("deploy", "manifest", "--key", str(key), "--out", str(out))
    assert result.returncode == 0, result.stderr
    line = json.loads(result.stdout)
    assert line["created_key"] and line["public_key"] == str(public_key_path(key))
    files = verified_files(out, load_public_key(public_key_path(key)))
    assert line["files"] == len(files)
    assert {path.split("/")[0] for path in files} == set(PACKAGES)
    for data in ("simulator/scenarios/", "ares/core/wire/ares.dbc", "blackbox/web/pages/", "ares/core/config/tours/"):
        assert any(path.startswith(data) for path in files), data
    again = ares("deploy", "manifest", "--key", str(key), "--out", str(out))
    assert again.returncode == 0 and not json.loads(again.stdout)["created_key"]  # the fleet's key, kept


def _run_refused(tmp_path: Path, manifest: dict, public_key: Path) -> subprocess.CompletedProcess:
    path = tmp_path / "release.json"
    path.write_text(json.dumps(manifest))
    cfg = tmp_path / "vehicle.yaml"
    cfg.write_text(yaml.safe_dump({"release": {"manifest": str(path), "public_key": str(public_key)}}))
    return subprocess.run(
        [sys.executable, "-m", "ares.cli", "run", "--headless", "--seconds", "1", "--config", str(cfg)],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        timeout=120,
    )


def test_ares_run_refuses_a_stack_that_is_not_the_release(tmp_path):
    """The real installation, a real `ares run`: refused before any process starts, exit 2, one line."""
    key = tmp_path / "release_key"
    signing_key, _ = release_key(key)
    # the installed files as they are, and one file of the release the installation lacks
    files = {**file_hashes(package_roots()), "ares/__absent__.py": "0" * 64}
    result = _run_refused(tmp_path, signed_manifest(files, signing_key), public_key_path(key))
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    refused = f"not the signed release ({tmp_path / 'release.json'})"
    assert lines == [f"ares run: {refused}: ares/__absent__.py: in the release, missing from the installation"]
    assert not (tmp_path / "runs").exists()  # no run folder: nothing started

    forged = _run_refused(tmp_path, signed_manifest(files, Ed25519PrivateKey.generate()), public_key_path(key))
    assert forged.returncode == 2
    assert forged.stderr.strip().endswith("its signature is not the fleet's release key's")
