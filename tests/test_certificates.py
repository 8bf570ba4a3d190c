"""The one X.509 builder (ares.core.certificates) that the fleet's CA (ares.deploy.pki) and the black
box API's self-signed certificate (blackbox.api.tls) both use: what it writes into a certificate,
and real TLS handshakes (Python's ssl, OpenSSL's verifier) with what it makes: mutual TLS under a
CA as the routers use it, and a self-signed server pinned by its client as the API's are."""

from __future__ import annotations

import datetime as dt
import socket
import ssl
import threading
from pathlib import Path

import pytest
from cryptography import x509
from cryptography.x509.oid import ExtendedKeyUsageOID

from ares.core import certificates


def _save(folder: Path, name: str, key, cert: x509.Certificate) -> tuple[Path, Path]:
    cert_path, key_path = folder / f"{name}.pem", folder / f"{name}.key"
    cert_path.write_bytes(certificates.certificate_pem(cert))
    key_path.write_bytes(certificates.private_key_pem(key))
    return cert_path, key_path


def _handshake(server: ssl.SSLContext, client: ssl.SSLContext, server_hostname: str) -> tuple[dict, dict | None]:
    """One TLS connection over loopback: (the server's certificate as the client saw it, the
    client's as the server saw it, None if it sent none)."""
    listener = socket.create_server(("127.0.0.1", 0))
    seen: dict = {}

    def serve() -> None:
        conn, _ = listener.accept()
        try:
            with server.wrap_socket(conn, server_side=True) as tls:
                seen["client"] = tls.getpeercert()
                tls.sendall(b"ok")
        except (ssl.SSLError, OSError) as exc:
            seen["error"] = exc

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        with socket.create_connection(listener.getsockname(), timeout=5) as raw:
            with client.wrap_socket(raw, server_hostname=server_hostname) as tls:
                assert tls.recv(2) == b"ok"
                server_cert = tls.getpeercert()
    finally:
        thread.join(5)
        listener.close()
    assert "error" not in seen, seen.get("error")
    return server_cert, seen["client"] or None


def test_a_ca_and_its_leaf_carry_what_verifiers_look_for():
    ca_key = certificates.new_key()
    ca = certificates.build(certificates.subject_name("test CA"), ca_key, 30, ca=True)
    key = certificates.new_key()
    leaf = certificates.build(
        certificates.subject_name("shuttle01"),
        key,
        3650,  # longer than the CA's: cut to the CA's end
        issuer=certificates.Issuer(ca_key, ca),
        hosts=["shuttle01", "10.0.0.7", "::1"],
        usages=[ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH],
    )
    leaf.verify_directly_issued_by(ca)
    assert ca.extensions.get_extension_for_class(x509.BasicConstraints).value == x509.BasicConstraints(True, 0)
    assert not leaf.extensions.get_extension_for_class(x509.BasicConstraints).value.ca
    assert ca.extensions.get_extension_for_class(x509.KeyUsage).value.key_cert_sign
    assert not leaf.extensions.get_extension_for_class(x509.KeyUsage).value.key_cert_sign
    names = leaf.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert names.get_values_for_type(x509.DNSName) == ["shuttle01"]
    assert [str(ip) for ip in names.get_values_for_type(x509.IPAddress)] == ["10.0.0.7", "::1"]
    ca_identifier = ca.extensions.get_extension_for_class(x509.SubjectKeyIdentifier).value.digest
    leaf_authority = leaf.extensions.get_extension_for_class(x509.AuthorityKeyIdentifier).value
    assert leaf_authority.key_identifier == ca_identifier
    assert leaf.not_valid_after_utc == ca.not_valid_after_utc
    assert leaf.not_valid_before_utc <= dt.datetime.now(dt.UTC) - dt.timedelta(minutes=4)
    assert certificates.matches_key(leaf, key) and not certificates.matches_key(leaf, ca_key)


def test_mutual_tls_under_one_ca_and_a_stranger_refused(tmp_path):
    ca_key = certificates.new_key()
    ca = certificates.build(certificates.subject_name("test CA"), ca_key, 30, ca=True)
    ca_path = tmp_path / "ca.pem"
    ca_path.write_bytes(certificates.certificate_pem(ca))
    both = [ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]

    def leaf(name: str, issuer: certificates.Issuer) -> tuple[Path, Path]:
        key = certificates.new_key()
        cert = certificates.build(
            certificates.subject_name(name), key, 30, issuer=issuer, hosts=[name, "127.0.0.1"], usages=both
        )
        return _save(tmp_path, name, key, cert)

    def contexts(server_pair, client_pair) -> tuple[ssl.SSLContext, ssl.SSLContext]:
        server = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
        server.load_cert_chain(*server_pair)
        server.load_verify_locations(ca_path)
        server.verify_mode = ssl.CERT_REQUIRED
        client = ssl.create_default_context(cafile=ca_path)
        client.load_cert_chain(*client_pair)
        return server, client

    issuer = certificates.Issuer(ca_key, ca)
    server_cert, client_cert = _handshake(*contexts(leaf("fleet", issuer), leaf("shuttle01", issuer)), "127.0.0.1")
    assert dict(x[0] for x in server_cert["subject"])["commonName"] == "fleet"
    assert dict(x[0] for x in client_cert["subject"])["commonName"] == "shuttle01"

    other_key = certificates.new_key()
    other_ca = certificates.build(certificates.subject_name("another CA"), other_key, 30, ca=True)
    stranger = leaf("stranger", certificates.Issuer(other_key, other_ca))
    with pytest.raises((ssl.SSLError, OSError)):
        _handshake(*contexts(leaf("fleet", issuer), stranger), "127.0.0.1")


def test_a_self_signed_server_certificate_pinned_by_its_client(tmp_path):
    key = certificates.new_key()
    cert = certificates.build(
        certificates.subject_name("localhost", "ARES black box (self-signed)"),
        key,
        365,
        hosts=["localhost", "127.0.0.1"],
        usages=[ExtendedKeyUsageOID.SERVER_AUTH],
    )
    cert.verify_directly_issued_by(cert)
    identifier = cert.extensions.get_extension_for_class(x509.SubjectKeyIdentifier).value.digest
    assert cert.extensions.get_extension_for_class(x509.AuthorityKeyIdentifier).value.key_identifier == identifier
    cert_path, key_path = _save(tmp_path, "api", key, cert)
    server = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    server.load_cert_chain(cert_path, key_path)
    for host in ("localhost", "127.0.0.1"):
        seen, _ = _handshake(server, ssl.create_default_context(cafile=cert_path), host)
        assert ("DNS", "localhost") in seen["subjectAltName"]
    with pytest.raises(ssl.SSLCertVerificationError):
        _handshake(server, ssl.create_default_context(cafile=cert_path), "shuttle.local")  # a name it lacks
