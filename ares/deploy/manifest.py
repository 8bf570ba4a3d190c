"""`ares deploy manifest`: the release manifest of the installed stack, signed with the fleet's
Ed25519 release key (ares.core.manifest checks it at start). The key is made on first use, its
private half readable by its owner only, its public half beside it (`KEY.pub`), which the
vehicles' configurations name (`release.public_key`)."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from ares.core.manifest import file_hashes, package_roots, signed_manifest


class ReleaseKeyError(Exception):
    """The release key cannot be read or made."""


@dataclass(frozen=True)
class MadeManifest:
    manifest: Path
    files: int
    public_key: Path
    created_key: bool


def public_key_path(key_path: Path) -> Path:
    return key_path.with_name(key_path.name + ".pub")


def release_key(key_path: Path) -> tuple[Ed25519PrivateKey, bool]:
    """The fleet's release key from `key_path`, made there (and its public half) when absent."""
    if key_path.exists():
        try:
            key = serialization.load_pem_private_key(key_path.read_bytes(), password=None)
        except (OSError, ValueError, TypeError) as exc:
            raise ReleaseKeyError(f"{key_path}: cannot be read as an unencrypted PEM private key ({exc})") from None
        if not isinstance(key, Ed25519PrivateKey):
            raise ReleaseKeyError(f"{key_path}: not an Ed25519 key")
        _write_public_half(key, key_path)
        return key, False
    key = Ed25519PrivateKey.generate()
    private = key.private_bytes(
        serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
    )
    key_path.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(key_path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)  # never readable by others
    with os.fdopen(fd, "wb") as out:
        out.write(private)
    _write_public_half(key, key_path)
    return key, True


def _write_public_half(key: Ed25519PrivateKey, key_path: Path) -> None:
    public = key.public_key().public_bytes(serialization.Encoding.PEM, serialization.PublicFormat.SubjectPublicKeyInfo)
    public_key_path(key_path).write_bytes(public)


def make_manifest(key_path: Path, out: Path, roots: dict[str, Path] | None = None) -> MadeManifest:
    """Hash every installed file of the project's packages (or of `roots`) and sign the list."""
    key, created = release_key(key_path)
    files = file_hashes(roots if roots is not None else package_roots())
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(signed_manifest(files, key), indent=1) + "\n")
    return MadeManifest(out, len(files), public_key_path(key_path), created)
