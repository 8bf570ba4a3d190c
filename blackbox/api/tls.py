"""HTTPS for the REST API: the configured certificate, or a self-signed one made once and kept.

ARES §3.8: the API is the vehicle's only service reachable from outside, over HTTPS. A
deployment configures its own certificate (`tls.certfile`/`tls.keyfile`). Without one, a
self-signed certificate for the configured host names (localhost, 127.0.0.1, ::1 by default)
is made (ares.core.certificates) into `tls.cert_dir` and reused on later starts while it stays
valid and covers those names; clients trust it by pinning that file (httpx `verify=<cert>`).
"""

from __future__ import annotations

import datetime as dt
import ipaddress
import os
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import serialization
from cryptography.x509.oid import ExtendedKeyUsageOID

from ares.core import certificates
from ares.core.config import Params, param

CERT_NAME = "api_cert.pem"
KEY_NAME = "api_key.pem"
RENEW_BEFORE = dt.timedelta(days=7)  # regenerate a self-signed certificate this close to expiry


class TlsSettings(Params):
    certfile: str | None = param(
        None, "a deployment's own certificate (PEM) ...; null: self-signed for `hosts`, made once, reused"
    )
    keyfile: str | None = param(None, "... and its key; both or neither")
    cert_dir: str | None = param(None, "where the self-signed pair is kept; null: <state_dir>/tls")
    hosts: list[str] = param(
        doc="names of the self-signed certificate", factory=lambda: ["localhost", "127.0.0.1", "::1"]
    )
    days: int = param(365, "validity of the self-signed certificate", unit="d", ge=1, le=3650)


def _covers(cert: x509.Certificate, hosts: list[str]) -> bool:
    try:
        names = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    except x509.ExtensionNotFound:
        return False
    have = {str(n) for n in names.get_values_for_type(x509.DNSName)}
    have |= {str(ip) for ip in names.get_values_for_type(x509.IPAddress)}
    return all(str(ipaddress.ip_address(h)) in have if _is_ip(h) else h in have for h in hosts)


def _is_ip(host: str) -> bool:
    try:
        ipaddress.ip_address(host)
        return True
    except ValueError:
        return False


def _reusable(cert_path: Path, key_path: Path, hosts: list[str]) -> bool:
    if not (cert_path.exists() and key_path.exists()):
        return False
    try:
        cert = x509.load_pem_x509_certificate(cert_path.read_bytes())
        key = serialization.load_pem_private_key(key_path.read_bytes(), password=None)
    except (ValueError, TypeError, OSError):
        return False
    if not certificates.matches_key(cert, key):
        return False
    now = dt.datetime.now(dt.UTC)
    return cert.not_valid_before_utc <= now and cert.not_valid_after_utc - RENEW_BEFORE > now and _covers(cert, hosts)


def self_signed(cert_dir: Path, hosts: list[str], days: int = 365) -> tuple[Path, Path]:
    """(certfile, keyfile) in cert_dir: the existing pair when still good, else a new one."""
    cert_dir = Path(cert_dir)
    cert_path, key_path = cert_dir / CERT_NAME, cert_dir / KEY_NAME
    if _reusable(cert_path, key_path, hosts):
        return cert_path, key_path
    cert_dir.mkdir(parents=True, exist_ok=True)
    key = certificates.new_key()
    cert = certificates.build(
        certificates.subject_name(hosts[0] if hosts else "localhost", "ARES black box (self-signed)"),
        key,
        days,
        hosts=hosts,
        usages=[ExtendedKeyUsageOID.SERVER_AUTH],
    )
    # write the key first, owner-only, then the certificate; a reader never sees a cert without its key
    tmp_key = key_path.with_suffix(".tmp")
    fd = os.open(tmp_key, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(certificates.private_key_pem(key))
    os.replace(tmp_key, key_path)
    tmp_cert = cert_path.with_suffix(".tmp")
    tmp_cert.write_bytes(certificates.certificate_pem(cert))
    os.replace(tmp_cert, cert_path)
    return cert_path, key_path


def certificate(cfg: TlsSettings, state_dir: Path) -> tuple[Path, Path]:
    """The pair uvicorn should serve: the configured one, else the (reused) self-signed one."""
    if bool(cfg.certfile) != bool(cfg.keyfile):
        raise ValueError("api.tls: give both certfile and keyfile, or neither")
    if cfg.certfile and cfg.keyfile:
        cert, key = Path(cfg.certfile).expanduser(), Path(cfg.keyfile).expanduser()
        for p in (cert, key):
            if not p.is_file():
                raise ValueError(f"api.tls: no such file {p}")
        return cert, key
    cert_dir = Path(cfg.cert_dir).expanduser() if cfg.cert_dir else Path(state_dir) / "tls"
    return self_signed(cert_dir, cfg.hosts, cfg.days)
