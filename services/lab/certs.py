"""The lab's certificates: a CA that signs host identities only, and each identity's key and cert.

The common name of an identity's certificate is its name, which is what the routers' ACLs match
(`services.lab.acl`); a router's certificate also names the addresses its clients reach it by.
Private keys are written readable by their owner only.
"""

from __future__ import annotations

import datetime
import ipaddress
import os
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID


def _key() -> ec.EllipticCurvePrivateKey:
    return ec.generate_private_key(ec.SECP256R1())


def _name(common: str) -> x509.Name:
    return x509.Name(
        [
            x509.NameAttribute(NameOID.ORGANIZATION_NAME, "nod-hri lab"),
            x509.NameAttribute(NameOID.COMMON_NAME, common),
        ]
    )


def _alt_names(hosts: list[str]) -> list[x509.GeneralName]:
    out: list[x509.GeneralName] = []
    for host in hosts:
        try:
            out.append(x509.IPAddress(ipaddress.ip_address(host)))
        except ValueError:
            out.append(x509.DNSName(host))
    return out


def _builder(
    key: ec.EllipticCurvePrivateKey, subject: x509.Name, issuer: x509.Name, days: int
) -> x509.CertificateBuilder:
    """What every certificate of the lab has: names, key, a random serial, `days` of validity.

    It is valid from five minutes ago, so a host whose clock is a little behind the signer's
    accepts it at once.
    """
    now = datetime.datetime.now(datetime.UTC)
    return (
        x509.CertificateBuilder()
        .subject_name(subject)
        .issuer_name(issuer)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=days))
    )


def make_ca(
    days: int, common: str = "nod-hri lab CA"
) -> tuple[ec.EllipticCurvePrivateKey, x509.Certificate]:
    """A self-signed CA that may sign host certificates only."""
    key = _key()
    cert = (
        _builder(key, _name(common), _name(common), days)
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(
            x509.KeyUsage(
                digital_signature=False,
                content_commitment=False,
                key_encipherment=False,
                data_encipherment=False,
                key_agreement=False,
                key_cert_sign=True,
                crl_sign=True,
                encipher_only=False,
                decipher_only=False,
            ),
            critical=True,
        )
        .sign(key, hashes.SHA256())
    )
    return key, cert


def make_host(
    name: str,
    hosts: list[str],
    ca_key: ec.EllipticCurvePrivateKey,
    ca: x509.Certificate,
    days: int,
) -> tuple[ec.EllipticCurvePrivateKey, x509.Certificate]:
    """An identity's certificate: common name = its name (what the ACL matches), both TLS sides."""
    key = _key()
    builder = (
        _builder(key, _name(name), ca.subject, days)
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(
            x509.ExtendedKeyUsage(
                [ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]
            ),
            critical=False,
        )
        .add_extension(x509.SubjectAlternativeName(_alt_names([name, *hosts])), critical=False)
    )
    return key, builder.sign(ca_key, hashes.SHA256())


def _write_pem(path: Path, data: bytes, private: bool = False) -> None:
    path.write_bytes(data)
    if private:
        os.chmod(path, 0o600)


def _key_pem(key: ec.EllipticCurvePrivateKey) -> bytes:
    return key.private_bytes(
        serialization.Encoding.PEM,
        serialization.PrivateFormat.PKCS8,
        serialization.NoEncryption(),
    )


def _cert_pem(cert: x509.Certificate) -> bytes:
    return cert.public_bytes(serialization.Encoding.PEM)


def write_ca(
    out: Path, days: int, common: str = "nod-hri lab CA"
) -> tuple[ec.EllipticCurvePrivateKey, x509.Certificate, list[Path]]:
    """A new CA, written to out/ca.pem and out/ca.key (keep ca.key offline: it mints identities)."""
    ca_key, ca = make_ca(days, common)
    _write_pem(out / "ca.pem", _cert_pem(ca))
    _write_pem(out / "ca.key", _key_pem(ca_key), private=True)
    return ca_key, ca, [out / "ca.pem", out / "ca.key"]


def write_cert(
    folder: Path,
    name: str,
    router_host: str | None,
    ca_key: ec.EllipticCurvePrivateKey,
    ca: x509.Certificate,
    days: int,
) -> list[Path]:
    """An identity's key, certificate and the CA's certificate, in its folder."""
    folder.mkdir(parents=True, exist_ok=True)
    # The router's certificate names the router's address (the clients verify it).
    hosts = [] if router_host is None else [router_host, "localhost", "127.0.0.1"]
    key, cert = make_host(name, hosts, ca_key, ca, days)
    _write_pem(folder / "key.pem", _key_pem(key), private=True)
    _write_pem(folder / "cert.pem", _cert_pem(cert))
    _write_pem(folder / "ca.pem", _cert_pem(ca))
    return [folder / n for n in ("cert.pem", "key.pem", "ca.pem")]
