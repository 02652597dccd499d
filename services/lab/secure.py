"""`nod lab secure`: a lab network that only the rig can drive — mutual TLS and an ACL by host.

Makes a certificate authority, one certificate per host role (control station, camera box,
arm controller, eyes controller; the common name is the role), and the Zenoh configurations:
the control station's router listens on TLS, refuses any client without a certificate from this
CA, and enforces an access-control list by certificate name, derived from the contract
(`services.core.contract`): each role may publish only the keys its services publish and may
declare only its own services' liveliness tokens. Every authenticated host may engage the
e-stop (`safety/estop`); only the control station may release it (`safety/release`).

    out/ca.pem, out/ca.key           the CA (keep ca.key offline: it mints identities)
    out/<role>/cert.pem, key.pem     the host's identity (key readable by its owner only)
    out/<role>/ca.pem                the CA certificate, to check the other side
    out/<role>/zenoh.json5           the host's client config (`--config` of its services)
    out/control/router.json5         the router's config (`nod router --config …`)

Copy `out/<role>/` to the same path on each host (the configs name their files by absolute
path under `--install-dir`, default the absolute `--out`).
"""

from __future__ import annotations

import argparse
import datetime
import ipaddress
import json
import os
import sys
from dataclasses import dataclass
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from services.core.cli import Parser
from services.core.contract import TOPICS
from services.core.keys import check_rig
from services.core.session import MAX_MESSAGE_BYTES

ALL_MESSAGES = (
    "put", "delete", "declare_subscriber", "query", "reply", "declare_queryable",
    "liveliness_token", "declare_liveliness_subscriber", "liveliness_query",
)


@dataclass(frozen=True)
class Role:
    """A host of the lab and the services it runs (what its certificate may do)."""

    name: str
    services: tuple[str, ...]
    queryables: tuple[str, ...] = ()  # topics it answers queries on


ROLES: dict[str, Role] = {
    r.name: r
    for r in (
        # Every host runs a launcher (`nod up`): its heartbeats and events are the host's too.
        Role("control", ("experiment", "monitor", "estop", "run", "record", "launcher")),
        Role("camera", ("vision", "sim", "launcher"), queryables=("vision/layout",)),
        Role("arm", ("decision", "actuation", "launcher")),
        Role("eyes", ("eyes", "launcher")),
    )
}


def acl(rig: str, roles: list[Role]) -> dict:
    """The router's access_control section: deny by default, allow what each role needs."""
    ns = f"nod/{rig}"
    rules: list[dict] = [
        {  # what the router may forward to any authenticated host: everything of the rig
            "id": "deliver",
            "permission": "allow",
            "flows": ["egress"],
            "messages": list(ALL_MESSAGES),
            "key_exprs": [f"{ns}/**"],
        },
        {  # every host may listen, see who is alive, and query (the layout)
            "id": "observe",
            "permission": "allow",
            "flows": ["ingress"],
            "messages": [
                "declare_subscriber", "declare_liveliness_subscriber", "liveliness_query",
                "query",
            ],
            "key_exprs": [f"{ns}/**"],
        },
        {  # every host may stop the rig; releasing is the control station's (its role rule)
            "id": "engage-estop",
            "permission": "allow",
            "flows": ["ingress"],
            "messages": ["put"],
            "key_exprs": [f"{ns}/safety/estop"],
        },
    ]
    subjects, policies = [], []
    for role in roles:
        publishes = sorted(
            t.name for t in TOPICS.values() if set(t.publishers) & set(role.services)
        )
        rules.append({
            "id": f"{role.name}-publish",
            "permission": "allow",
            "flows": ["ingress"],
            "messages": ["put"],
            "key_exprs": [f"{ns}/{t}" for t in publishes] or [f"{ns}/-none-"],
        })
        rules.append({
            "id": f"{role.name}-alive",
            "permission": "allow",
            "flows": ["ingress"],
            "messages": ["liveliness_token"],
            "key_exprs": [f"{ns}/alive/{s}" for s in role.services],
        })
        names = [f"{role.name}-publish", f"{role.name}-alive", "deliver", "observe",
                 "engage-estop"]
        if role.queryables:
            rules.append({
                "id": f"{role.name}-answer",
                "permission": "allow",
                "flows": ["ingress"],
                "messages": ["declare_queryable", "reply"],
                "key_exprs": [f"{ns}/{t}" for t in role.queryables],
            })
            names.append(f"{role.name}-answer")
        subjects.append({"id": role.name, "cert_common_names": [role.name]})
        policies.append({"id": role.name, "rules": names, "subjects": [role.name]})
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }


def _key() -> ec.EllipticCurvePrivateKey:
    return ec.generate_private_key(ec.SECP256R1())


def _name(common: str) -> x509.Name:
    return x509.Name([
        x509.NameAttribute(NameOID.ORGANIZATION_NAME, "nod-hri lab"),
        x509.NameAttribute(NameOID.COMMON_NAME, common),
    ])


def _alt_names(hosts: list[str]) -> list[x509.GeneralName]:
    out: list[x509.GeneralName] = []
    for host in hosts:
        try:
            out.append(x509.IPAddress(ipaddress.ip_address(host)))
        except ValueError:
            out.append(x509.DNSName(host))
    return out


def make_ca(days: int) -> tuple[ec.EllipticCurvePrivateKey, x509.Certificate]:
    """A self-signed CA that may sign host certificates only."""
    key = _key()
    now = datetime.datetime.now(datetime.UTC)
    cert = (
        x509.CertificateBuilder()
        .subject_name(_name("nod-hri lab CA"))
        .issuer_name(_name("nod-hri lab CA"))
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=days))
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(
            x509.KeyUsage(
                digital_signature=False, content_commitment=False, key_encipherment=False,
                data_encipherment=False, key_agreement=False, key_cert_sign=True,
                crl_sign=True, encipher_only=False, decipher_only=False,
            ),
            critical=True,
        )
        .sign(key, hashes.SHA256())
    )
    return key, cert


def make_host(
    role: str, hosts: list[str], ca_key: ec.EllipticCurvePrivateKey, ca: x509.Certificate,
    days: int,
) -> tuple[ec.EllipticCurvePrivateKey, x509.Certificate]:
    """A host's certificate: common name = its role (what the ACL matches), both TLS sides."""
    key = _key()
    now = datetime.datetime.now(datetime.UTC)
    builder = (
        x509.CertificateBuilder()
        .subject_name(_name(role))
        .issuer_name(ca.subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=days))
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(
            x509.ExtendedKeyUsage(
                [ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]
            ),
            critical=False,
        )
        .add_extension(x509.SubjectAlternativeName(_alt_names([role, *hosts])), critical=False)
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


def _tls(folder: Path, listen: bool) -> dict:
    side = "listen" if listen else "connect"
    return {
        "root_ca_certificate": str(folder / "ca.pem"),
        f"{side}_private_key": str(folder / "key.pem"),
        f"{side}_certificate": str(folder / "cert.pem"),
        "enable_mtls": True,
        **({} if listen else {"verify_name_on_connect": True}),
    }


def _common(tls: dict) -> dict:
    return {
        "scouting": {"multicast": {"enabled": False}},
        "transport": {"link": {"tls": tls, "rx": {"max_message_size": MAX_MESSAGE_BYTES}}},
    }


def secure(
    out: Path, roles: list[Role], rig: str, router_host: str, port: int, days: int,
    install_dir: Path,
) -> list[Path]:
    """Write the CA, each role's identity and configs, and the router's config; return them."""
    out.mkdir(parents=True, exist_ok=True)
    ca_key, ca = make_ca(days)
    _write_pem(out / "ca.pem", _cert_pem(ca))
    _write_pem(out / "ca.key", _key_pem(ca_key), private=True)
    written = [out / "ca.pem", out / "ca.key"]
    for role in roles:
        folder = out / role.name
        folder.mkdir(exist_ok=True)
        hosts = [router_host, "localhost", "127.0.0.1"] if role.name == "control" else []
        key, cert = make_host(role.name, hosts, ca_key, ca, days)
        _write_pem(folder / "key.pem", _key_pem(key), private=True)
        _write_pem(folder / "cert.pem", _cert_pem(cert))
        _write_pem(folder / "ca.pem", _cert_pem(ca))
        installed = install_dir / role.name
        client = {
            "mode": "client",
            "connect": {"endpoints": [f"tls/{router_host}:{port}"]},
            **_common(_tls(installed, listen=False)),
        }
        (folder / "zenoh.json5").write_text(_json5(client, f"{role.name}: client of the router"))
        written += [folder / n for n in ("cert.pem", "key.pem", "ca.pem", "zenoh.json5")]
    control = install_dir / "control"
    router = {
        "mode": "router",
        "listen": {"endpoints": [f"tls/0.0.0.0:{port}"]},
        **_common(_tls(control, listen=True)),
        "access_control": acl(rig, roles),
    }
    (out / "control").mkdir(exist_ok=True)
    (out / "control" / "router.json5").write_text(
        _json5(router, "the control station's router: mutual TLS, access control by host")
    )
    written.append(out / "control" / "router.json5")
    return written


def _json5(data: dict, what: str) -> str:
    head = f"// {what}. Written by `nod lab secure`; regenerate rather than edit.\n"
    return head + json.dumps(data, indent=2) + "\n"


def build_parser() -> argparse.ArgumentParser:
    """The command line of `nod lab secure`."""
    p = Parser(prog="nod lab secure", description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, required=True, help="folder to write into")
    p.add_argument(
        "--hosts",
        default=",".join(ROLES),
        help=f"roles to make identities for, comma separated (default {','.join(ROLES)})",
    )
    p.add_argument("--rig", type=check_rig, default="rig1", help="rig name scoping every key")
    p.add_argument(
        "--router-host",
        default="localhost",
        help="name or address the hosts reach the control station by (in its certificate)",
    )
    p.add_argument("--port", type=int, default=7447, help="the router's TLS port (7447)")
    p.add_argument("--days", type=int, default=825, help="validity of the certificates (825)")
    p.add_argument(
        "--install-dir",
        type=Path,
        default=None,
        help="where the role folders will be on the hosts (default: the absolute --out)",
    )
    return p


def main(argv: list[str] | None = None) -> int:
    """Generate a lab's identities and configs."""
    args = build_parser().parse_args(argv)
    names = [n for n in args.hosts.split(",") if n]
    unknown = [n for n in names if n not in ROLES]
    if unknown or "control" not in names:
        print(
            f"nod lab secure: --hosts takes roles among {', '.join(ROLES)} and needs control "
            f"(the router); got {args.hosts!r}",
            file=sys.stderr,
        )
        return 2
    if not (1 <= args.port <= 65535 and 1 <= args.days <= 3650):
        print("nod lab secure: --port must be 1-65535 and --days 1-3650", file=sys.stderr)
        return 2
    install = (args.install_dir or args.out).absolute()
    try:
        written = secure(
            args.out, [ROLES[n] for n in names], args.rig, args.router_host, args.port,
            args.days, install,
        )
    except OSError as exc:
        print(f"nod lab secure: cannot write to {args.out}: {exc.strerror}", file=sys.stderr)
        return 2
    print(f"wrote {len(written)} files to {args.out}/ (rig {args.rig!r}, router "
          f"tls/{args.router_host}:{args.port}):")
    print(f"  control station: nod router --config {install}/control/router.json5")
    for n in names:
        print(f"  {n:<8} services: --config {install}/{n}/zenoh.json5")
    print(f"  keep {args.out}/ca.key offline: whoever holds it can mint identities")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
