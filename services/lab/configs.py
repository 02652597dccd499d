"""The lab's Zenoh configuration files: each host's client config and the router's, with TLS.

What `nod lab secure` writes (`services.lab.secure` is its command line), and the per-rig
routers of `services.lab.routers` write with the same pieces: the TLS block of a side, the
intake bounds every file carries, one identity's certificate and client config, the JSON5 text.
"""

from __future__ import annotations

import json
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives.asymmetric import ec

from services.core.limits import low_pass_filters
from services.core.session import MAX_MESSAGE_BYTES, SHARED_MEMORY
from services.lab.acl import LAB, ROUTER, Identity, acl, identities, lab_identities
from services.lab.certs import write_ca, write_cert


def tls_block(folder: Path, listen: bool) -> dict:
    """The TLS block of a listening (router) or connecting (client) side, mutual."""
    side = "listen" if listen else "connect"
    return {
        "root_ca_certificate": str(folder / "ca.pem"),
        f"{side}_private_key": str(folder / "key.pem"),
        f"{side}_certificate": str(folder / "cert.pem"),
        "enable_mtls": True,
        **({} if listen else {"verify_name_on_connect": True}),
    }


def common_config(tls: dict) -> dict:
    """What every file of the lab holds: no scouting, TLS, the intake bounds."""
    # The intake bounds go into the files themselves (not only into what `nod` adds when it
    # loads them), so a stock `zenohd -c router.json5` refuses oversized messages too and keeps
    # shared memory off (docs/safety.md "Bounded intake").
    return {
        "scouting": {"multicast": {"enabled": False}},
        "transport": {
            "link": {"tls": tls, "rx": {"max_message_size": MAX_MESSAGE_BYTES}},
            "shared_memory": {"enabled": SHARED_MEMORY},
        },
        "low_pass_filter": low_pass_filters(),
    }


def secure(
    out: Path,
    roles: list[str],
    rig: str | list[str],
    router_host: str,
    port: int,
    days: int,
    install_dir: Path,
    listen: str | None = None,
) -> list[Path]:
    """Write the CA, every identity with its client config, and the router's; return the files.

    `rig` is one rig's name (the single-rig layout) or the rigs of a lab (`--rigs`: each rig's
    identities under its name, the lab's own, and a router of its own). The router listens on
    `listen` (default `tls/<router_host>:<port>`); clients connect to `tls/<router_host>:<port>`.
    """
    out.mkdir(parents=True, exist_ok=True)
    ca_key, ca, written = write_ca(out, days)
    lab = not isinstance(rig, str)
    ids = lab_identities(roles, list(rig)) if lab else identities(roles, str(rig))
    for ident in ids:
        written += write_identity(out, install_dir, ident, router_host, port, ca_key, ca, days)
    # The router speaks with a certificate that names its address: in a lab one of its own (no
    # rig's control station is the lab's), on a single rig the control station's.
    where = ROUTER if lab else "control"
    if lab:
        written += write_cert(out / ROUTER, f"{LAB}.{ROUTER}", router_host, ca_key, ca, days)
    router = {
        "mode": "router",
        "listen": {"endpoints": [listen or f"tls/{router_host}:{port}"]},
        **common_config(tls_block(install_dir / where, listen=True)),
        "access_control": acl(ids),
    }
    what = "the lab's router" if lab else "the control station's router"
    (out / where / "router.json5").write_text(
        json5_text(router, f"{what}: mutual TLS, access control by identity")
    )
    written.append(out / where / "router.json5")
    return written


def write_identity(
    out: Path,
    install_dir: Path,
    ident: Identity,
    router_host: str,
    port: int,
    ca_key: ec.EllipticCurvePrivateKey,
    ca: x509.Certificate,
    days: int,
) -> list[Path]:
    """One identity's certificate and its client config (the router at router_host:port)."""
    folder = out / ident.folder
    # On a single rig the router speaks with the control station's certificate.
    serves = router_host if ident.name == "control" else None
    written = write_cert(folder, ident.name, serves, ca_key, ca, days)
    client = {
        "mode": "client",
        "connect": {"endpoints": [f"tls/{router_host}:{port}"]},
        **common_config(tls_block(install_dir / ident.folder, listen=False)),
    }
    (folder / "zenoh.json5").write_text(json5_text(client, f"{ident.name}: client of the router"))
    return [*written, folder / "zenoh.json5"]


def json5_text(data: dict, what: str) -> str:
    """A config file's text: what it is for, then the JSON."""
    head = f"// {what}. Written by `nod lab secure`; regenerate rather than edit.\n"
    return head + json.dumps(data, indent=2) + "\n"
