"""The release manifest (ARES §3.8.3): "the version of [software and drivers] is verified and the
vehicle is prevented from starting in case of detecting any anomaly".

A manifest is the SHA-256 of every file of the project's installed packages (code, bytecode and
package data), each named by its path from the packages' parent (`ares/core/bus.py`), signed
with the fleet's Ed25519 release key (`ares deploy manifest`, ares.deploy.manifest). At start,
when the configuration's `release` section names a manifest and the fleet's public key,
`ares run` checks the installed files against it and refuses to start on the first anomaly: an
unsigned manifest, a signature that is not the fleet's, a file changed, added or gone. Off by
default, as a developer's checkout changes under its developer; on in a deployment's config.

Bytecode is hashed too: Python runs a `.pyc` whose header matches its source's size and time,
so a planted one is code. The deployment's image writes none after its install
(PYTHONDONTWRITEBYTECODE), so the installed files stay what the release's were.
"""

from __future__ import annotations

import base64
import hashlib
import importlib.util
import json
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey, Ed25519PublicKey
from pydantic import model_validator

from ares.core.config import Params, param

# the packages a release installs (pyproject.toml's [tool.setuptools.packages.find])
PACKAGES = ("ares", "managers", "perception", "control", "blackbox", "drivers", "simulator")
FORMAT = 1


class ReleaseRefused(Exception):
    """The installed stack is not the release the fleet signed; the message is one line."""


class ReleaseSettings(Params):
    """The release manifest checked before the stack starts (ARES §3.8.3; off: a developer's checkout)"""

    manifest: str | None = param(
        None, "the release's signed manifest (`ares deploy manifest`); null: the installed files are not checked"
    )
    public_key: str | None = param(None, "the fleet's Ed25519 release key, public half (PEM), that signed it")

    @model_validator(mode="after")
    def _both_or_neither(self) -> ReleaseSettings:
        if (self.manifest is None) != (self.public_key is None):
            raise ValueError("release: give both manifest and public_key, or neither")
        return self


def package_roots(packages: Iterable[str] = PACKAGES) -> dict[str, Path]:
    """Each installed package's folder, found without importing it."""
    roots: dict[str, Path] = {}
    for name in packages:
        spec = importlib.util.find_spec(name)
        if spec is None or not spec.submodule_search_locations:
            raise ReleaseRefused(f"the package {name!r} of the release is not installed")
        roots[name] = Path(next(iter(spec.submodule_search_locations)))
    return roots


def file_hashes(roots: Mapping[str, Path]) -> dict[str, str]:
    """SHA-256 (hex) of every file under each root, by its path `<package>/<inside>`."""
    hashes: dict[str, str] = {}
    for name, root in roots.items():
        for path in sorted(p for p in root.rglob("*") if p.is_file()):
            hashes[f"{name}/{path.relative_to(root).as_posix()}"] = hashlib.sha256(path.read_bytes()).hexdigest()
    return hashes


def signed_bytes(files: Mapping[str, str]) -> bytes:
    """What the signature covers: the format and the files, as canonical JSON."""
    return json.dumps({"format": FORMAT, "files": dict(files)}, sort_keys=True, separators=(",", ":")).encode()


def signed_manifest(files: Mapping[str, str], key: Ed25519PrivateKey) -> dict[str, Any]:
    signature = base64.b64encode(key.sign(signed_bytes(files))).decode()
    return {"format": FORMAT, "files": dict(sorted(files.items())), "signature": signature}


def load_public_key(path: Path) -> Ed25519PublicKey:
    try:
        key = serialization.load_pem_public_key(path.read_bytes())
    except (OSError, ValueError) as exc:
        raise ReleaseRefused(f"release key {path}: cannot be read as a PEM public key ({exc})") from None
    if not isinstance(key, Ed25519PublicKey):
        raise ReleaseRefused(f"release key {path}: not an Ed25519 key")
    return key


def verified_files(manifest_path: Path, key: Ed25519PublicKey) -> dict[str, str]:
    """The manifest's files, once its signature is the key's (ReleaseRefused otherwise)."""
    try:
        manifest = json.loads(manifest_path.read_text())
    except (OSError, ValueError) as exc:
        raise ReleaseRefused(f"release manifest {manifest_path}: cannot be read ({exc})") from None
    files = manifest.get("files") if isinstance(manifest, dict) else None
    if not isinstance(files, dict) or manifest.get("format") != FORMAT:
        raise ReleaseRefused(f"release manifest {manifest_path}: not a format {FORMAT} manifest")
    if not manifest.get("signature"):
        raise ReleaseRefused(f"release manifest {manifest_path}: unsigned")
    try:
        key.verify(base64.b64decode(manifest["signature"], validate=True), signed_bytes(files))
    except (InvalidSignature, ValueError):
        raise ReleaseRefused(
            f"release manifest {manifest_path}: its signature is not the fleet's release key's"
        ) from None
    return files


def first_difference(released: Mapping[str, str], installed: Mapping[str, str]) -> str | None:
    """The first file (by path) where the installation differs from the release, as a sentence."""
    for path in sorted(released.keys() | installed.keys()):
        if path not in installed:
            return f"{path}: in the release, missing from the installation"
        if path not in released:
            return f"{path}: installed, not in the release"
        if released[path] != installed[path]:
            return f"{path}: differs from the release"
    return None


def check_release(settings: ReleaseSettings, roots: Mapping[str, Path] | None = None) -> None:
    """Refuse (ReleaseRefused, one line) an installation that is not the signed release; nothing
    when the settings name no manifest. `roots`: the packages' folders (default: the installed ones)."""
    if settings.manifest is None or settings.public_key is None:
        return
    released = verified_files(Path(settings.manifest), load_public_key(Path(settings.public_key)))
    difference = first_difference(released, file_hashes(roots if roots is not None else package_roots()))
    if difference is not None:
        raise ReleaseRefused(f"not the signed release ({settings.manifest}): {difference}")
