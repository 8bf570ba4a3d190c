"""The fleet's certificate authority, and each vehicle's certificate and Zenoh credentials.

One CA per fleet signs the fleet router's certificate and every vehicle's: the routers accept a
TLS link only from a certificate of that CA (mutual TLS), and the fleet router's access control
knows a vehicle by its certificate's common name, which is its vehicle id. A vehicle also has a
Zenoh user (its id) and a random password; the fleet router checks it against its dictionary.

Layout of the CA folder (`ares deploy certs --fleet-ca DIR`):

    DIR/ca.pem, ca.key                 the CA (the key never leaves this folder)
    DIR/fleet/                         the fleet server's secrets, each file named as compose's secret
        zenoh_ca                       the CA's certificate
        zenoh_router_cert, _key        the fleet router's certificate (CN fleet; names: --fleet-host)
        zenoh_users                    user:password per vehicle and for the fleet's own services
        zenoh_fleet_password           the fleet services' password (user `fleet`) on their router
    DIR/vehicles/<id>/                 one vehicle's secrets, copied to that vehicle only
        zenoh_ca                       the CA's certificate
        zenoh_router_cert, _key        its router's certificate (CN = <id>)
        zenoh_user, zenoh_password     its router's Zenoh credentials on the fleet router
        zenoh_local_users              its router's dictionary: `user:password` per process of the table
                                       (its name), the supervisor and the read-only observer; the stack
                                       reads its own lines from it (bus.credentials_file)
        zenoh_router.json5             its router's config with the credentials (router_config.py)
    and in both folders the black box's:
        api_tls_cert, api_tls_key      the REST API's HTTPS certificate (names: the id or `fleet`, --api-host)
        api_signing_key                the key that signs the API's tokens
        mongo_password                 the password of MongoDB's user `ares` (the stack's: its database only)
        mongo_root_password            MongoDB's root user's, for its first start and an administrator alone

Keys are written owner-only, each file atomically (a reader never sees half a key). The certificates
are made by ares.core.certificates (the black box's self-signed one too).
"""

from __future__ import annotations

import os
import re
import secrets
from dataclasses import dataclass
from pathlib import Path

from cryptography import x509
from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from ares.core import certificates
from ares.core.certificates import matches_key  # also the deployment check's (pki.matches_key)
from ares.core.config.run import OBSERVER_USER

VEHICLE_ID_RE = re.compile(r"^[a-z0-9][a-z0-9_-]{0,62}$")  # a key-expression chunk, a CN, a user name
CA_DAYS = 3650
LEAF_DAYS = 825  # the longest validity clients commonly accept; rotate before (docs/deploy.md)
FLEET_USER = "fleet"
OBSERVER = OBSERVER_USER  # `ares topics` / `ares echo` on the vehicle's computer: subscribe only


class PkiError(ValueError):
    """A CA folder or a certificate that cannot serve: the message says which file and why."""


@dataclass(frozen=True)
class Issued:
    """What one `certs` call wrote (paths), for the command's report."""

    ca: Path
    fleet_dir: Path
    vehicle_dir: Path | None
    created_ca: bool


def check_vehicle_id(vehicle_id: str) -> str:
    if not VEHICLE_ID_RE.match(vehicle_id):
        raise PkiError(
            f"vehicle id {vehicle_id!r}: use lower-case letters, digits, '-' and '_' (it names the "
            "vehicle's keys ares/<id>/**, its certificate and its Zenoh user)"
        )
    if vehicle_id == FLEET_USER:
        raise PkiError(f"vehicle id {vehicle_id!r} is the fleet router's own name")
    return vehicle_id


def _write(path: Path, data: bytes, private: bool) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600 if private else 0o644)
    with os.fdopen(fd, "wb") as f:
        f.write(data)
    os.replace(tmp, path)


def write_private(path: Path, text: str) -> None:
    _write(path, text.encode(), private=True)


def make_ca(
    common_name: str = "ARES fleet CA", days: int = CA_DAYS
) -> tuple[ec.EllipticCurvePrivateKey, x509.Certificate]:
    key = certificates.new_key()
    return key, certificates.build(certificates.subject_name(common_name), key, days, ca=True)


def make_leaf(
    ca_key: ec.EllipticCurvePrivateKey,
    ca_cert: x509.Certificate,
    common_name: str,
    names: list[str],
    days: int = LEAF_DAYS,
) -> tuple[ec.EllipticCurvePrivateKey, x509.Certificate]:
    """A router's certificate: it both listens and connects, so it serves as server and client."""
    key = certificates.new_key()
    cert = certificates.build(
        certificates.subject_name(common_name),
        key,
        days,
        issuer=certificates.Issuer(ca_key, ca_cert),
        hosts=names,
        usages=[ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH],
    )
    return key, cert


def load_cert(path: Path) -> x509.Certificate:
    try:
        return x509.load_pem_x509_certificate(Path(path).read_bytes())
    except FileNotFoundError:
        raise PkiError(f"{path}: no such file") from None
    except ValueError as exc:
        raise PkiError(f"{path}: not a PEM certificate ({exc})") from None


def load_key(path: Path) -> ec.EllipticCurvePrivateKey:
    try:
        key = serialization.load_pem_private_key(Path(path).read_bytes(), password=None)
    except FileNotFoundError:
        raise PkiError(f"{path}: no such file") from None
    except (ValueError, TypeError) as exc:
        raise PkiError(f"{path}: not an unencrypted PEM private key ({exc})") from None
    if not isinstance(key, ec.EllipticCurvePrivateKey):
        raise PkiError(f"{path}: expected an EC key")
    return key


def common_name(cert: x509.Certificate) -> str:
    attrs = cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)
    return str(attrs[0].value) if attrs else ""


def signed_by(cert: x509.Certificate, ca: x509.Certificate) -> bool:
    try:
        cert.verify_directly_issued_by(ca)
        return True
    except (ValueError, TypeError, InvalidSignature):
        return False


def read_users(path: Path) -> dict[str, str]:
    """The router's dictionary, as zenoh reads it: `user:password`, one per line."""
    users: dict[str, str] = {}
    if not path.exists():
        return users
    for n, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip():
            continue
        user, sep, password = line.partition(":")
        if not sep or not user.strip() or not password.strip():
            raise PkiError(f"{path}:{n}: expected user:password")
        users[user.strip()] = password.strip()
    return users


def write_users(path: Path, users: dict[str, str]) -> None:
    _write(path, "".join(f"{u}:{p}\n" for u, p in sorted(users.items())).encode(), private=True)


def ensure_ca(ca_dir: Path, fleet_hosts: list[str]) -> tuple[ec.EllipticCurvePrivateKey, x509.Certificate, bool]:
    """The CA of the folder, made (with the fleet router's certificate) when the folder has none."""
    ca_dir = Path(ca_dir)
    ca_pem, ca_key = ca_dir / "ca.pem", ca_dir / "ca.key"
    if ca_pem.exists() != ca_key.exists():
        raise PkiError(f"{ca_dir}: ca.pem and ca.key must both be there, or neither (to make a new CA)")
    created = not ca_pem.exists()
    if created:
        key, cert = make_ca()
        _write(ca_key, certificates.private_key_pem(key), private=True)
        _write(ca_pem, certificates.certificate_pem(cert), private=False)
    key, cert = load_key(ca_key), load_cert(ca_pem)
    if not matches_key(cert, key):
        raise PkiError(f"{ca_pem} and {ca_key} are not a pair")
    fleet = ca_dir / "fleet"
    if created or not (fleet / "zenoh_router_cert").exists():
        issue_router(key, cert, fleet, FLEET_USER, fleet_hosts)
    if not (fleet / "api_tls_cert").exists():
        issue_blackbox(key, cert, fleet, FLEET_USER, fleet_hosts)
    users_path = fleet / "zenoh_users"
    users = read_users(users_path)
    if FLEET_USER not in users:  # a router with a dictionary asks every link for credentials
        users[FLEET_USER] = secrets.token_urlsafe(24)
        _write(fleet / "zenoh_fleet_password", users[FLEET_USER].encode(), private=True)
        write_users(users_path, users)
    return key, cert, created


def issue_router(
    ca_key: ec.EllipticCurvePrivateKey, ca_cert: x509.Certificate, out: Path, name: str, hosts: list[str]
) -> None:
    key, cert = make_leaf(ca_key, ca_cert, name, [name, *hosts])
    _write(out / "zenoh_router_key", certificates.private_key_pem(key), private=True)
    _write(out / "zenoh_router_cert", certificates.certificate_pem(cert), private=False)
    _write(out / "zenoh_ca", certificates.certificate_pem(ca_cert), private=False)


def issue_blackbox(
    ca_key: ec.EllipticCurvePrivateKey, ca_cert: x509.Certificate, out: Path, name: str, hosts: list[str]
) -> None:
    """The API's HTTPS certificate (renewed), its token-signing key and the store's password (made once)."""
    key, cert = make_leaf(ca_key, ca_cert, name, [name, *hosts, "localhost", "127.0.0.1"])
    _write(out / "api_tls_key", certificates.private_key_pem(key), private=True)
    _write(out / "api_tls_cert", certificates.certificate_pem(cert), private=False)
    # kept when present: MongoDB sets its user's password once, at its first start (docs/deploy.md: rotation)
    if not (out / "api_signing_key").exists():
        _write(out / "api_signing_key", secrets.token_hex(32).encode(), private=True)
    for password in ("mongo_password", "mongo_root_password"):
        if not (out / password).exists():
            _write(out / password, secrets.token_urlsafe(24).encode(), private=True)


def local_users_of_the_table() -> list[str]:
    """The vehicle router's users: one per process of the table (its name), the supervisor, the observer."""
    from ares.app.contracts import SUPERVISOR
    from ares.app.processes import PROCESSES

    return sorted({p.name for p in PROCESSES} | {SUPERVISOR, OBSERVER})


def issue_vehicle(
    ca_dir: Path, vehicle_id: str, fleet_hosts: list[str] | None = None, api_hosts: list[str] | None = None
) -> Issued:
    """A vehicle's router certificate and Zenoh credentials, and its line in the fleet's dictionary.
    Issuing again for the same id rotates both (the old certificate stays valid until it expires:
    docs/deploy.md says how to retire one)."""
    check_vehicle_id(vehicle_id)
    ca_dir = Path(ca_dir)
    ca_key, ca_cert, created = ensure_ca(ca_dir, fleet_hosts or ["fleet-router", "localhost"])
    out = ca_dir / "vehicles" / vehicle_id
    issue_router(ca_key, ca_cert, out, vehicle_id, [])
    issue_blackbox(ca_key, ca_cert, out, vehicle_id, api_hosts or [])
    password = secrets.token_urlsafe(24)
    _write(out / "zenoh_user", vehicle_id.encode(), private=True)
    _write(out / "zenoh_password", password.encode(), private=True)
    local_users = {user: secrets.token_urlsafe(24) for user in local_users_of_the_table()}
    write_users(out / "zenoh_local_users", local_users)
    (out / "zenoh_local_password").unlink(missing_ok=True)  # one user for every process: retired
    users_path = ca_dir / "fleet" / "zenoh_users"
    users = read_users(users_path)
    users[vehicle_id] = password
    write_users(users_path, users)
    return Issued(ca=ca_dir / "ca.pem", fleet_dir=ca_dir / "fleet", vehicle_dir=out, created_ca=created)
