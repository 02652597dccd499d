"""`nod lab secure`: a lab network that only the rig can drive — mutual TLS and an ACL by identity.

Makes a certificate authority, the lab's identities (`services.lab.acl`: one per host role —
control station, camera box, arm controller, eyes controller —, one launcher per host role for
`nod up`, and the read-only monitor identity for monitors and lab screens; the common name is
the identity) and the Zenoh configurations: the control station's router listens on TLS at one
address, refuses any client without a certificate from this CA, and enforces an access-control
list by certificate name derived from the contract: each identity may publish only the keys its
services publish and declare only its own services' liveliness tokens; every host role may
engage the e-stop (`safety/estop`), only the control station release it (`safety/release`);
only the launchers publish rig events; the monitor publishes nothing but its heartbeat.

    out/ca.pem, out/ca.key             the CA (keep ca.key offline: it mints identities)
    out/<role>/cert.pem, key.pem       the host's identity (key readable by its owner only)
    out/<role>/ca.pem                  the CA certificate, to check the other side
    out/<role>/zenoh.json5             the host's client config (`--config` of its services)
    out/<role>/launcher/…              the same four files for the host's `nod up`
    out/monitor/…                      the read-only identity (monitors, `nod status`, screens)
    out/control/router.json5           the router's config (`nod router --config …`)
    out/dask/…                         the Dask cluster's own CA and its scheduler's, workers'
                                       and clients' identities (`services.lab.compute`)

A lab of several rigs on one router (`--rigs rig1,rig2`): each rig's identities in a folder of
its own (`out/<rig>/…`, the layout above: a rig file's `rig.tls = "out/<rig>"`), each touching
only its own rig's keys, and the lab's:

    out/lab/monitor/…                  read-only on every rig (`nod lab status`, lab screens)
    out/lab/estop/…                    `nod estop` on every rig: engages and releases any rig
    out/router/router.json5            the lab router's config, with its certificate

With `--router-per-rig` each rig has a router of its own on its host, linked to the lab router
(`services.lab.routers`: `out/<rig>/router/`, `--rig-router RIG=HOST:PORT` says where).

Where the router listens: `--listen tls/HOST:PORT`, by default the address the hosts reach it
by (`--router-host`, `--port`, or the rig file's `rig.router` with `--rig-file`), never every
interface unless `--listen` says so. Copy `out/<role>/` to the same path on each host, and
`out/monitor/` to the hosts and screens that run a monitor (the configs name their files by
absolute path under `--install-dir`, default the absolute `--out`).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from services.core.cli import PORT, Parser, fail, int_in
from services.core.keys import check_rig
from services.core.rigfile import WILDCARD_HOSTS, RigFileError, load_rig, split_endpoint
from services.lab.acl import HOSTS, LAB, ROUTER
from services.lab.compute import DASK, write_dask
from services.lab.compute import commands as dask_commands
from services.lab.configs import secure


def build_parser() -> argparse.ArgumentParser:
    """The command line of `nod lab secure`."""
    p = Parser(prog="nod lab secure", description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, required=True, help="folder to write into")
    p.add_argument(
        "--hosts",
        default=",".join(HOSTS),
        help=f"host roles to make identities for, comma separated (default {','.join(HOSTS)}; "
        "each gets its launcher's identity too, and the monitor's is always made)",
    )
    p.add_argument(
        "--rig-file",
        type=Path,
        default=None,
        metavar="RIG.toml",
        help="take the rig name, the router's address and port from this rig file (rig.name, "
        "rig.router) instead of --rig, --router-host and --port",
    )
    p.add_argument("--rig", type=check_rig, default=None, help="rig name scoping every key (rig1)")
    p.add_argument(
        "--rigs",
        default=None,
        metavar="RIG,RIG,…",
        help="a lab of several rigs on one router: each rig's identities in out/<rig>/, touching "
        "only its own keys, plus the lab's monitor and e-stop (out/lab/) and router (out/router/)",
    )
    p.add_argument(
        "--router-per-rig",
        action="store_true",
        help="with --rigs: a router on each rig's host (out/<rig>/router/, its rig's ACL) linked "
        "to the lab router (--router-host, --port), which admits each rig router for its own rig",
    )
    p.add_argument(
        "--rig-router",
        action="append",
        default=[],
        metavar="RIG=HOST:PORT",
        help="with --router-per-rig, once per rig: where its router listens and its hosts connect "
        "(HOST:PORT, tls/HOST:PORT, or a rig file of that rig whose rig.router says it)",
    )
    p.add_argument(
        "--router-host",
        default=None,
        help="name or address the hosts reach the control station by (in its certificate; the "
        "router listens there; default localhost)",
    )
    p.add_argument("--port", type=PORT, default=None, help="the router's TLS port (7447)")
    p.add_argument(
        "--listen",
        default=None,
        metavar="tls/ADDRESS:PORT",
        help="where the router listens, when not at --router-host (e.g. tls/192.168.10.1:7447; "
        "tls/0.0.0.0:PORT, every interface, only when said here)",
    )
    p.add_argument(
        "--dask-host",
        default=None,
        help="name or address of the Dask scheduler's machine, for the commands printed (default "
        "the router host)",
    )
    p.add_argument(
        "--days", type=int_in(1, 3650), default=825, help="validity of the certificates (825)"
    )
    p.add_argument(
        "--install-dir",
        type=Path,
        default=None,
        help="where the role folders will be on the hosts (default: the absolute --out)",
    )
    return p


def where(args: argparse.Namespace) -> tuple[str, str, int, str]:
    """The rig, the router's host and port, and its listen endpoint; ValueError in one line."""
    rig, host, port = args.rig, args.router_host, args.port
    if args.rig_file is not None:
        if (rig, host, port) != (None, None, None):
            raise ValueError(
                "--rig-file gives the rig, router host and port: leave out --rig, "
                "--router-host and --port"
            )
        try:
            loaded = load_rig(args.rig_file)
            _, host, port = split_endpoint(loaded.router)
        except (RigFileError, ValueError) as exc:
            raise ValueError(f"--rig-file: {exc}") from None
        rig = loaded.name
    rig, host, port = rig or "rig1", host or "localhost", 7447 if port is None else port
    if not 1 <= port <= 65535:
        raise ValueError(f"--port must be 1-65535, got {port}")
    if host in WILDCARD_HOSTS:
        raise ValueError(
            f"the router host {host!r} is every interface, not an address the "
            "hosts can reach: give its name or address (--listen for a wildcard)"
        )
    if args.listen is None:
        return rig, host, port, f"tls/{host}:{port}"
    try:
        scheme, _, listen_port = split_endpoint(args.listen)
    except ValueError as exc:
        raise ValueError(f"--listen: {exc}") from None
    if scheme != "tls":
        raise ValueError(
            f"--listen must be a tls/ endpoint (anything else bypasses the "
            f"certificates), got {args.listen!r}"
        )
    if listen_port != port:
        raise ValueError(
            f"--listen's port {listen_port} is not the port the hosts connect to ({port})"
        )
    return rig, host, port, args.listen


def lab_rigs(text: str | None, rig: str | None) -> list[str] | None:
    """The rigs of `--rigs` (None without it); ValueError in one line."""
    if text is None:
        return None
    if rig is not None:
        raise ValueError("--rigs names every rig of the lab: leave out --rig")
    rigs = [r for r in text.split(",") if r]
    for r in rigs:
        check_rig(r)
    if not rigs or len(set(rigs)) != len(rigs):
        raise ValueError(f"--rigs takes distinct rig names, comma separated; got {text!r}")
    if {LAB, ROUTER, DASK} & set(rigs):
        raise ValueError(
            f"a rig may not be called {LAB!r}, {ROUTER!r} or {DASK!r} (the lab's own "
            "identities, router and Dask cluster live in those folders): rename it"
        )
    return rigs


def main(argv: list[str] | None = None) -> int:
    """Generate a lab's identities and configs."""
    args = build_parser().parse_args(argv)
    names = [n for n in args.hosts.split(",") if n]
    unknown = [n for n in names if n not in HOSTS]
    if unknown or "control" not in names:
        print(
            f"nod lab secure: --hosts takes roles among {', '.join(HOSTS)} and needs control "
            f"(the router); got {args.hosts!r}",
            file=sys.stderr,
        )
        return 2
    if not 1 <= args.days <= 3650:
        return fail("nod lab secure", "--days must be 1-3650")
    try:
        rigs = lab_rigs(args.rigs, args.rig)
        rig, host, port, listen = where(args)
        if rigs is not None and args.rig_file is not None and rig not in rigs:
            raise ValueError(f"--rig-file's rig {rig!r} is not among --rigs {args.rigs!r}")
        per_rig = per_rig_routers(args, rigs)
    except ValueError as exc:
        return fail("nod lab secure", exc)
    install = (args.install_dir or args.out).absolute()
    if per_rig is not None:
        return _main_per_rig(args, names, rigs or [], per_rig, host, port, install, listen)
    try:
        written = secure(
            args.out, names, rig if rigs is None else rigs, host, port, args.days, install, listen
        )
        written += write_dask(args.out, install, args.days)
    except OSError as exc:
        return fail("nod lab secure", f"cannot write to {args.out}: {exc.strerror}")
    scope = f"rig {rig!r}" if rigs is None else f"rigs {', '.join(rigs)}"
    print(
        f"wrote {len(written)} files to {args.out}/ ({scope}; hosts connect to "
        f"tls/{host}:{port}; the router listens on {listen}):"
    )
    if split_endpoint(listen)[1] in WILDCARD_HOSTS:
        print(
            "  WARNING: the router listens on every interface of the control station "
            "(--listen): any network it is on can reach it"
        )
    if rigs is None:
        print(f"  control station: nod router --config {install}/control/router.json5")
        _print_rig(install, names)
    else:
        print(
            f"  the lab's router: nod router --config {install}/{ROUTER}/router.json5 (the "
            "rig files' control hosts: router = false)"
        )
        for r in rigs:
            print(f'  rig {r}: rig.tls = "{install}/{r}"')
            _print_rig(install / r, names)
        print(f"  the lab view, lab screens: --config {install}/{LAB}/monitor/zenoh.json5")
        print(
            f"  the lab e-stop (every rig): nod estop --rig RIG --config "
            f"{install}/{LAB}/estop/zenoh.json5"
        )
    print("\n".join(dask_commands(install, args.dask_host or host)))
    print(f"  keep {args.out}/ca.key offline: whoever holds it can mint identities")
    return 0


def per_rig_routers(args: argparse.Namespace, rigs: list[str] | None) -> dict | None:
    """Each rig router's address with `--router-per-rig` (None without); ValueError in one line."""
    if not args.router_per_rig:
        if args.rig_router:
            raise ValueError("--rig-router places a rig's router: it needs --router-per-rig")
        return None
    if rigs is None:
        raise ValueError("--router-per-rig needs --rigs: the rigs that get a router each")
    if args.rig_file is not None:
        raise ValueError(
            "with --router-per-rig, --rig-file is ambiguous: give each rig's file to "
            "--rig-router RIG=FILE and the lab router by --router-host and --port"
        )
    from services.lab.routers import rig_router_addresses

    return rig_router_addresses(args.rig_router, rigs)


def _main_per_rig(
    args: argparse.Namespace,
    names: list[str],
    rigs: list[str],
    per_rig: dict,
    host: str,
    port: int,
    install: Path,
    listen: str,
) -> int:
    from services.lab.routers import describe, secure_per_rig

    try:
        written = secure_per_rig(
            args.out, names, rigs, per_rig, host, port, args.days, install, listen
        )
        written += write_dask(args.out, install, args.days)
    except OSError as exc:
        return fail("nod lab secure", f"cannot write to {args.out}: {exc.strerror}")
    print(
        f"wrote {len(written)} files to {args.out}/ (rigs {', '.join(rigs)}, a router each, "
        f"linked to the lab router at tls/{host}:{port}; it listens on {listen}):"
    )
    print("\n".join(describe(install, rigs, per_rig)))
    for r in rigs:
        _print_rig(install / r, names)
    print(f"  the lab view, lab screens: --config {install}/{LAB}/monitor/zenoh.json5")
    print(
        f"  the lab e-stop (every rig): nod estop --rig RIG --config "
        f"{install}/{LAB}/estop/zenoh.json5 (with the lab router down: add --connect "
        "tls/RIG-ROUTER:PORT, that rig only)"
    )
    print("\n".join(dask_commands(install, args.dask_host or host)))
    print(f"  keep {args.out}/ca.key offline: whoever holds it can mint identities")
    return 0


def _print_rig(folder: Path, roles: list[str]) -> None:
    for n in roles:
        print(
            f"  {n:<8} services: --config {folder}/{n}/zenoh.json5; "
            f"nod up: {folder}/{n}/launcher/zenoh.json5"
        )
    print(f"  monitors, nod status, rig screens: --config {folder}/monitor/zenoh.json5")


if __name__ == "__main__":
    raise SystemExit(main())
