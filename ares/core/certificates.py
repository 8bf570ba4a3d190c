"""X.509 certificates: the one builder behind the fleet's CA and its routers' and APIs' certificates
(ares.deploy.pki) and the black box API's self-signed one (blackbox.api.tls).

Every key is EC P-256: fast handshakes, fast to make. Every certificate is valid from five minutes
before it was made, so that a clock a little behind still accepts it, and never beyond its
issuer's; it names its key (subject key identifier) and its issuer's (authority key identifier:
its own when self-signed), so that a verifier finds the issuer's certificate among several. Its
host names go into the subject alternative names, an IP address as an IP address and anything
else as a DNS name: clients match those, not the common name.
"""

from __future__ import annotations

import datetime as dt
import ipaddress
from collections.abc import Sequence
from dataclasses import dataclass

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.hazmat.primitives.asymmetric.types import PrivateKeyTypes
from cryptography.x509.oid import NameOID

CLOCK_SLACK = dt.timedelta(minutes=5)


@dataclass(frozen=True)
class Issuer:
    """A CA's key and certificate: what signs a certificate it issues."""

    key: ec.EllipticCurvePrivateKey
    certificate: x509.Certificate


def new_key() -> ec.EllipticCurvePrivateKey:
    return ec.generate_private_key(ec.SECP256R1())


def subject_name(common_name: str, organization: str | None = None) -> x509.Name:
    attributes = [x509.NameAttribute(NameOID.COMMON_NAME, common_name)]
    if organization is not None:
        attributes.append(x509.NameAttribute(NameOID.ORGANIZATION_NAME, organization))
    return x509.Name(attributes)


def alternative_name(host: str) -> x509.GeneralName:
    try:
        return x509.IPAddress(ipaddress.ip_address(host))
    except ValueError:
        return x509.DNSName(host)


def build(
    subject: x509.Name,
    key: ec.EllipticCurvePrivateKey,
    days: int,
    *,
    issuer: Issuer | None = None,
    ca: bool = False,
    hosts: Sequence[str] = (),
    usages: Sequence[x509.ObjectIdentifier] = (),
) -> x509.Certificate:
    """The certificate of `key` for `subject`, valid `days` (at most as long as its issuer's), signed
    by `issuer`, or self-signed without one. `ca`: it may sign certificates (not CAs); `hosts`: its
    subject alternative names; `usages`: its extended key usages (server, client authentication)."""
    now = dt.datetime.now(dt.UTC)
    own_identifier = x509.SubjectKeyIdentifier.from_public_key(key.public_key())
    if issuer is None:
        issuer_name, signing_key, issuer_identifier = subject, key, own_identifier
        not_after = now + dt.timedelta(days=days)
    else:
        issuer_name, signing_key = issuer.certificate.subject, issuer.key
        issuer_identifier = issuer.certificate.extensions.get_extension_for_class(x509.SubjectKeyIdentifier).value
        not_after = min(now + dt.timedelta(days=days), issuer.certificate.not_valid_after_utc)
    builder = (
        x509.CertificateBuilder()
        .subject_name(subject)
        .issuer_name(issuer_name)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - CLOCK_SLACK)
        .not_valid_after(not_after)
        .add_extension(x509.BasicConstraints(ca=ca, path_length=0 if ca else None), critical=True)
        .add_extension(_key_usage(ca), critical=True)
        .add_extension(own_identifier, critical=False)
        .add_extension(
            x509.AuthorityKeyIdentifier.from_issuer_subject_key_identifier(issuer_identifier), critical=False
        )
    )
    if hosts:
        builder = builder.add_extension(
            x509.SubjectAlternativeName([alternative_name(h) for h in hosts]), critical=False
        )
    if usages:
        builder = builder.add_extension(x509.ExtendedKeyUsage(list(usages)), critical=False)
    return builder.sign(signing_key, hashes.SHA256())


def _key_usage(ca: bool) -> x509.KeyUsage:
    return x509.KeyUsage(
        digital_signature=True,
        content_commitment=False,
        key_encipherment=False,
        data_encipherment=False,
        key_agreement=False,
        key_cert_sign=ca,
        crl_sign=ca,
        encipher_only=False,
        decipher_only=False,
    )


def private_key_pem(key: ec.EllipticCurvePrivateKey) -> bytes:
    """PKCS #8, unencrypted: the file's owner-only permissions protect it."""
    return key.private_bytes(
        serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
    )


def certificate_pem(certificate: x509.Certificate) -> bytes:
    return certificate.public_bytes(serialization.Encoding.PEM)


def matches_key(certificate: x509.Certificate, key: PrivateKeyTypes) -> bool:
    """Whether the certificate is that key's (a pair that belongs together)."""
    spki, der = serialization.PublicFormat.SubjectPublicKeyInfo, serialization.Encoding.DER
    return certificate.public_key().public_bytes(der, spki) == key.public_key().public_bytes(der, spki)
