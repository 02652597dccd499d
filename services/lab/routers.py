"""`nod lab secure --rigs … --router-per-rig`: a router on each rig's host, linked to a lab router.

The layout docs/scale.md prefers past three or four rigs: each rig's hot path stays on its own
router (rig host → its router → rig host, on loopback when the rig is one machine), and only
what crosses rigs (heartbeats, tokens, the lab e-stop, what a lab screen asks for) crosses the
lab router. Every link is mutual TLS with a certificate of the lab's CA, and each router enforces
its own ACL (`services.lab.acl`: `rig_router_acl`, `lab_router_acl`):

    out/<rig>/router/router.json5      the rig router's config: listens at --rig-router, connects
    out/<rig>/router/cert.pem, key.pem   to the lab router as `<rig>.router`
    out/<rig>/<role>/…                 the rig's identities, clients of the rig router
    out/router/router.json5            the lab router's config, with its certificate (`lab.router`)
    out/lab/monitor/…, out/lab/estop/… the lab's identities, clients of the lab router (a rig
                                       router admits them too, with rights on its rig only)

Where each rig router listens: `--rig-router RIG=HOST:PORT` (or `tls/HOST:PORT`, or a rig file
whose `rig.router` is the rig router's TLS endpoint), one per rig.
"""

from __future__ import annotations

from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives.asymmetric import ec

from services.core.rigfile import WILDCARD_HOSTS, RigFileError, load_rig, split_endpoint
from services.lab.acl import (
    LAB,
    ROUTER,
    host_identity,
    lab_identities,
    lab_router_acl,
    launcher_identity,
    monitor_identity,
    rig_router_acl,
)
from services.lab.certs import write_ca, write_cert
from services.lab.configs import common_config, json5_text, write_identity

Address = tuple[str, int]  # a router's host and TLS port


def rig_router_addresses(given: list[str], rigs: list[str]) -> dict[str, Address]:
    """Each rig's router address from `--rig-router RIG=WHERE`; ValueError in one line.

    WHERE is `HOST:PORT`, `tls/HOST:PORT`, or a rig file of that rig whose `rig.router` is one.
    """
    out: dict[str, Address] = {}
    for item in given:
        rig, eq, where = item.partition("=")
        if not eq or rig not in rigs:
            raise ValueError(
                f"--rig-router takes RIG=HOST:PORT for a rig of --rigs "
                f"({', '.join(rigs)}); got {item!r}"
            )
        if rig in out:
            raise ValueError(f"--rig-router gives {rig}'s router twice")
        if where.endswith(".toml"):
            try:
                loaded = load_rig(Path(where))
            except RigFileError as exc:
                raise ValueError(f"--rig-router {rig}: {exc}") from None
            if loaded.name != rig:
                raise ValueError(f"--rig-router {rig}: {where} is rig {loaded.name!r}")
            where = loaded.router
        endpoint = where if "/" in where else f"tls/{where}"
        try:
            scheme, host, port = split_endpoint(endpoint)
        except ValueError as exc:
            raise ValueError(f"--rig-router {rig}: {exc}") from None
        if scheme != "tls":
            raise ValueError(f"--rig-router {rig}: a rig router speaks TLS only, got {where!r}")
        if host in WILDCARD_HOSTS:
            raise ValueError(
                f"--rig-router {rig}: {host!r} is every interface, not an address "
                "the rig's hosts can reach: give its name or address"
            )
        out[rig] = (host, port)
    missing = [r for r in rigs if r not in out]
    if missing:
        raise ValueError(
            f"--router-per-rig needs --rig-router RIG=HOST:PORT for every rig; "
            f"missing: {', '.join(missing)}"
        )
    if len(set(out.values())) != len(out):
        raise ValueError("--rig-router: two rigs' routers at one address")
    return out


def _router_tls(folder: Path) -> dict:
    """A router that listens and connects with one certificate, checking the other side's."""
    return {
        "root_ca_certificate": str(folder / "ca.pem"),
        **{
            f"{side}_{what}": str(folder / f"{f}.pem")
            for side in ("listen", "connect")
            for what, f in (("private_key", "key"), ("certificate", "cert"))
        },
        "enable_mtls": True,
        "verify_name_on_connect": True,
    }


def _router(listen: str, tls: dict, access: dict, connect: str | None = None) -> dict:
    doc = {
        "mode": "router",
        "listen": {"endpoints": [listen]},
        **({"connect": {"endpoints": [connect]}} if connect else {}),
        **common_config(tls),
        "access_control": access,
    }
    # The routers are named in each other's configs: nothing to discover, nobody to tell.
    doc["scouting"]["gossip"] = {"enabled": False}
    return doc


def secure_per_rig(
    out: Path,
    roles: list[str],
    rigs: list[str],
    rig_routers: dict[str, Address],
    lab_host: str,
    lab_port: int,
    days: int,
    install_dir: Path,
    listen: str | None = None,
) -> list[Path]:
    """Write the CA, every identity, each rig's router and the lab router; return the files.

    The lab router listens on `listen` (default `tls/<lab_host>:<lab_port>`); the rig routers
    and the lab's identities connect to `tls/<lab_host>:<lab_port>`, each rig's identities to
    its router.
    """
    out.mkdir(parents=True, exist_ok=True)
    ca_key, ca, written = write_ca(out, days)
    for ident in lab_identities(roles, rigs)[-2:]:
        written += write_identity(out, install_dir, ident, lab_host, lab_port, ca_key, ca, days)
    lab = f"tls/{lab_host}:{lab_port}"
    for rig in rigs:
        host, port = rig_routers[rig]
        own = [f(r, rig, True) for r in roles for f in (host_identity, launcher_identity)]
        for ident in [*own, monitor_identity(rig, True)]:
            written += write_identity(out, install_dir, ident, host, port, ca_key, ca, days)
        doc = _router(
            f"tls/{host}:{port}",
            _router_tls(install_dir / rig / ROUTER),
            rig_router_acl(roles, rig),
            connect=lab,
        )
        written += _write_router(
            out / rig / ROUTER,
            f"{rig}.{ROUTER}",
            host,
            ca_key,
            ca,
            days,
            doc,
            f"rig {rig}'s router: its rig's ACL, linked to the lab's",
        )
    doc = _router(listen or lab, _router_tls(install_dir / ROUTER), lab_router_acl(roles, rigs))
    written += _write_router(
        out / ROUTER,
        f"{LAB}.{ROUTER}",
        lab_host,
        ca_key,
        ca,
        days,
        doc,
        "the lab router: the rig routers and the lab's identities",
    )
    return written


def _write_router(
    folder: Path,
    name: str,
    host: str,
    ca_key: ec.EllipticCurvePrivateKey,
    ca: x509.Certificate,
    days: int,
    doc: dict,
    what: str,
) -> list[Path]:
    """A router's certificate (naming its address) and config, in its folder."""
    written = write_cert(folder, name, host, ca_key, ca, days)
    (folder / "router.json5").write_text(json5_text(doc, what))
    return [*written, folder / "router.json5"]


def describe(install: Path, rigs: list[str], rig_routers: dict[str, Address]) -> list[str]:
    """What to run where, for `nod lab secure`'s summary."""
    lines = [f"  the lab router: nod router --config {install}/{ROUTER}/router.json5"]
    for rig in rigs:
        host, port = rig_routers[rig]
        lines.append(
            f"  rig {rig}: its router on {host} (tls/{host}:{port}): nod router --config "
            f"{install}/{rig}/{ROUTER}/router.json5, or in its rig file rig.tls = "
            f'"{install}/{rig}", router = "tls/{host}:{port}" and router = true on '
            "that host (`nod up` starts it)"
        )
    return lines
