"""The rig file: one TOML file that says what a lab's rig is made of and where each part runs.

    [rig]
    name = "rig1"                          # scopes every key: nod/rig1/...
    router = "tcp/192.168.10.1:7447"       # the endpoint every service connects to
    params = "params.toml"                 # experiment parameters (optional)
    tls = "/etc/nod/tls"                   # `nod lab secure` output (optional): mutual TLS + ACL

    [hosts.control]                        # one table per host; the name is the --host of `nod up`
    router = true                          # this host runs the router (listening on rig.router)
    role = "control"                       # its certificate under rig.tls (default: the name)
    services = ["monitor"]

    [hosts.arm]
    services = ["decision", "actuation", "eyes"]

    [vision]   source = "0"; tracker = "aruco"; calibration = "table.toml"
    [actuation] driver = "feetech"; port = "/dev/ttyUSB0"; config = "arm.toml"
    [eyes]     driver = "maestro"; port = "/dev/ttyACM0"; config = "eyes.toml"
               # state_dir = "/var/lib/nod/state": the e-stop latch (default $NOD_STATE_DIR)
    [speaker]  driver = "sounddevice"       # the participant's countdown (sim, wav + out = FILE)
    [display]  http = "127.0.0.1:8090"      # the participant's screen, a page for a kiosk browser
    (and "lsl" among a host's services: the signals and markers for LabRecorder, no section)
    [monitor]  args = ["--serve-web"]

Relative paths are relative to the rig file (every key of FILE_KEYS and FOLDER_KEYS, and
`vision.source` when it names a video file), made absolute here: a rig file moves with the
files it names (`nod up RIG.toml --init-rig DIR` copies them together). `load_rig` validates
everything that can be checked without touching a device (unknown keys, a service on two hosts
or none, one router, drivers, endpoints, the safety bound and the seed the services will be
given) and raises `RigFileError` with one line naming the file and the key; what the services
will open (files, ports, cameras) is `nod up --dry-run`'s preflight (`services.launch.
preflight`). The command line that starts a service from it is `services.launch.commands.
command(rig, service)`.

With `rig.tls`, every process speaks with its identity from `nod lab secure`
(`services.lab.acl`): a service with its host's role (`<tls>/<role>/`), the monitor with the
read-only `<tls>/monitor/`, `nod up` itself with its host's launcher (`<tls>/<role>/launcher/`,
the only identity that may publish rig/event).
"""

from __future__ import annotations

import re
import tomllib
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from services.core.cli import MAX_SEED, host_port
from services.core.keys import check_rig
from services.model.safety import SafetyParams

# Services a rig file may place on a host. The conductor (`nod experiment`) is not one: the
# operator starts it per participant; `sim` stands in for vision (a rig without a camera).
SERVICES = (
    "decision", "actuation", "eyes", "vision", "sim", "speaker", "display", "lsl", "monitor",
    "estimate",
)
# What a rig cannot run a trial without (vision or the sim that stands in for it).
REQUIRED = ("decision", "actuation", "eyes", "vision")
# The choices each service accepts. The rig file is read below the services (on any host, by
# any tool), so it cannot import them; tests/unit/test_rigfile.py holds these equal to theirs.
ARM_DRIVERS = ("sim", "feetech")
EYES_DRIVERS = ("sim", "maestro", "arduino")
TRACKERS = ("aruco", "mediapipe", "sim")
SPEAKER_DRIVERS = ("sim", "wav", "sounddevice")
WILDCARD_HOSTS = ("0.0.0.0", "::", "")  # "every interface": never where a router listens unasked
_PORTED = ("tcp", "tls", "udp", "quic", "ws")  # endpoint schemes that take host:port


class RigFileError(ValueError):
    """The rig file is unusable; the text names the file and the key."""


def split_endpoint(endpoint: str) -> tuple[str, str, int]:
    """A zenoh endpoint `proto/host:port[?…|#…]` as (proto, host, port); ValueError if not one."""
    proto, slash, rest = endpoint.partition("/")
    address = re.split(r"[?#]", rest, maxsplit=1)[0]
    host, colon, port = address.rpartition(":")
    if not (slash and proto and colon) or not port.isdigit() or not 1 <= int(port) <= 65535:
        raise ValueError(f"{endpoint!r} is not an endpoint such as tcp/192.168.10.1:7447")
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    return proto, host, int(port)


@dataclass(frozen=True)
class Host:
    """One machine of the rig."""

    name: str
    services: tuple[str, ...]
    router: bool = False
    role: str = ""  # certificate identity under rig.tls (default: the host's name)
    address: str = ""  # informational (docs, status)


@dataclass(frozen=True)
class Rig:
    """A validated rig file."""

    path: Path
    name: str
    router: str
    hosts: dict[str, Host]
    params: Path | None = None
    tls: Path | None = None
    sections: dict[str, dict[str, Any]] = field(default_factory=dict)  # per-service settings

    def host_of(self, service: str) -> Host:
        """The host that runs a service."""
        for host in self.hosts.values():
            if service in host.services:
                return host
        raise KeyError(service)

    @property
    def services(self) -> tuple[str, ...]:
        """Every service of the rig, in host order."""
        return tuple(s for h in self.hosts.values() for s in h.services)

    @property
    def required(self) -> tuple[str, ...]:
        """The services a trial needs (the sim counts as vision)."""
        return REQUIRED

    def router_host(self) -> Host | None:
        """The host that runs the router, if the rig runs its own."""
        return next((h for h in self.hosts.values() if h.router), None)


# Every key whose value is a path; a relative one is relative to the rig file (`vision.source`
# too, when it names a video file: `is_file_source`). Files, then folders.
FILE_KEYS = (
    ("rig", "params"), ("actuation", "config"), ("eyes", "config"), ("eyes", "trims"),
    ("vision", "calibration"),
)
FOLDER_KEYS = (("rig", "tls"), ("actuation", "state_dir"), ("eyes", "state_dir"))


def is_file_source(source: str) -> bool:
    """Whether a `vision.source` names a file (not an index, `sim`, `zenoh:KEY` or a URL).

    The same rule as `services.vision.capture.parse_source` (tests/unit/test_rigfile.py holds
    them equal): the rig file is read below the services and cannot import it.
    """
    text = source.strip()
    return bool(text) and not (
        text.isdigit() or text == "sim" or text.startswith("zenoh:") or "://" in text
    )


_RIG_KEYS = {"name", "router", "params", "tls"}
_HOST_KEYS = {"services", "router", "role", "address"}
_SECTION_KEYS: dict[str, set[str]] = {
    "decision": {"args"},
    "actuation": {"driver", "port", "config", "stale_ms", "state_dir", "args"},
    "eyes": {"driver", "port", "config", "trims", "stale_ms", "state_dir", "args"},
    "vision": {"source", "tracker", "calibration", "args"},
    "sim": {"seed", "args"},
    "speaker": {"driver", "out", "args"},  # out: the wav driver's file
    "display": {"http", "args"},  # http: HOST:PORT the page is served on
    "lsl": {"args"},  # LSL's own settings: lsl_api.cfg ($LSLAPICFG)
    "monitor": {"args"},
    "estimate": {"args"},  # `nod estimate`: --table K, --prior, --person
}


def load_rig(path: str | Path) -> Rig:
    """Read and validate a rig file (see the module doc)."""
    path = Path(path)
    try:
        doc = tomllib.loads(path.read_text())
    except OSError as exc:
        raise RigFileError(f"cannot read the rig file {path}: {exc.strerror or exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise RigFileError(f"{path}: not valid TOML: {exc}") from None
    where = str(path)

    def fail(key: str, why: str) -> RigFileError:
        return RigFileError(f"{where}: {key}: {why}")

    def known_keys(table: dict[str, Any], at: str, known: Iterable[str]) -> None:
        """A misspelt key fails by name, with the known ones, rather than being ignored."""
        extra = set(table) - set(known)
        if extra:
            names = ", ".join(sorted(known))
            raise fail(f"{at}.{sorted(extra)[0]}", f"unknown key; known: {names}")

    def strings(value: Any, key: str, what: str) -> list[str]:
        """`value` if it is a list of strings (service names, command-line arguments)."""
        if not isinstance(value, list) or not all(isinstance(s, str) for s in value):
            raise fail(key, f"must be a list of {what}")
        return value

    unknown = set(doc) - {"rig", "hosts", *_SECTION_KEYS}
    if unknown:
        raise fail(sorted(unknown)[0], f"unknown table; known: rig, hosts, {', '.join(SERVICES)}")
    rig = doc.get("rig")
    if not isinstance(rig, dict):
        raise fail("[rig]", "missing")
    known_keys(rig, "rig", _RIG_KEYS)
    name = rig.get("name", "rig1")
    try:
        check_rig(name if isinstance(name, str) else "")
    except ValueError as exc:
        raise fail("rig.name", str(exc)) from None
    router = rig.get("router")
    if not isinstance(router, str) or "/" not in router:
        raise fail("rig.router", "an endpoint such as tcp/192.168.10.1:7447 is required")
    if router.partition("/")[0] in _PORTED:
        try:
            split_endpoint(router)
        except ValueError as exc:
            raise fail("rig.router", f"{exc} (port 1-65535)") from None
    base = path.absolute().parent  # the services may run elsewhere than where this was read

    def file(value: Any, key: str) -> Path:
        if not isinstance(value, str) or not value:
            raise fail(key, "must be a path")
        p = Path(value).expanduser()
        return p if p.is_absolute() else (base / p)

    hosts_doc = doc.get("hosts")
    if not isinstance(hosts_doc, dict) or not hosts_doc:
        raise fail("[hosts]", "at least one host is required")
    hosts: dict[str, Host] = {}
    placed: dict[str, str] = {}
    for hname, h in hosts_doc.items():
        key = f"hosts.{hname}"
        if not isinstance(h, dict):
            raise fail(key, "must be a table")
        known_keys(h, key, _HOST_KEYS)
        services = strings(h.get("services", []), f"{key}.services", "service names")
        for s in services:
            if s not in SERVICES:
                known = ", ".join(SERVICES)
                raise fail(f"{key}.services", f"unknown service {s!r}; known: {known}")
            if s in placed:
                raise fail(f"{key}.services", f"{s} already runs on host {placed[s]!r}")
            placed[s] = hname
        is_router = h.get("router", False)
        if not isinstance(is_router, bool):
            raise fail(f"{key}.router", "must be true or false")
        role, address = h.get("role", hname), h.get("address", "")
        if not isinstance(role, str) or not isinstance(address, str):
            raise fail(key, "role and address must be strings")
        hosts[hname] = Host(hname, tuple(services), is_router, role, address)
    routers = [h.name for h in hosts.values() if h.router]
    if len(routers) > 1:
        raise fail("hosts", f"only one host may run the router, not {', '.join(routers)}")
    if "vision" in placed and "sim" in placed:
        raise fail("hosts", "vision and sim both publish the hand: a rig runs one of them")
    sections: dict[str, dict[str, Any]] = {}
    for service, allowed in _SECTION_KEYS.items():
        sec = doc.get(service, {})
        if not isinstance(sec, dict):
            raise fail(f"[{service}]", "must be a table")
        known_keys(sec, service, allowed)
        strings(sec.get("args", []), f"{service}.args", "strings")
        sections[service] = dict(sec)
    for service, key, choices in (
        ("actuation", "driver", ARM_DRIVERS), ("eyes", "driver", EYES_DRIVERS),
        ("vision", "tracker", TRACKERS), ("speaker", "driver", SPEAKER_DRIVERS),
    ):
        value = sections[service].get(key)
        if value is not None and value not in choices:
            raise fail(f"{service}.{key}", f"{value!r} is not one of {', '.join(choices)}")
    for service, key in (*FILE_KEYS, *FOLDER_KEYS):
        if service != "rig" and key in sections[service]:
            sections[service][key] = file(sections[service][key], f"{service}.{key}")
    if "out" in sections["speaker"]:  # a file to write, not one that must exist
        sections["speaker"]["out"] = file(sections["speaker"]["out"], "speaker.out")
    if sections["speaker"].get("driver") == "wav" and "out" not in sections["speaker"]:
        raise fail("speaker.out", "the wav driver needs a file to write (out = \"cues.wav\")")
    http = sections["display"].get("http")
    if http is not None:
        try:
            host_port(http if isinstance(http, str) else "")
        except ValueError:
            raise fail("display.http", f"{http!r} is not HOST:PORT, e.g. 127.0.0.1:8090") from None
    source = sections["vision"].get("source")
    if source is not None and not isinstance(source, str):
        raise fail("vision.source", "must be a string: a camera index, a video file or a URL")
    if source is not None and is_file_source(source):
        sections["vision"]["source"] = str(file(source, "vision.source"))
    for service in ("actuation", "eyes"):
        if sections[service].get("driver", "sim") != "sim" and "port" not in sections[service]:
            raise fail(f"{service}.port", f"the {sections[service]['driver']} driver needs a port")
        if not isinstance(sections[service].get("port", ""), str):
            raise fail(f"{service}.port", "must be a string such as /dev/ttyUSB0")
        if "stale_ms" in sections[service]:
            # The service checks its --stale-ms only when it starts: checked here, the preflight
            # (`nod up --dry-run`, deploy/setup-host) refuses it before anything runs.
            try:
                SafetyParams(stale_ms=sections[service]["stale_ms"])
            except ValueError as exc:
                why = str(exc).removeprefix("safety.stale_ms ")
                raise fail(f"{service}.stale_ms", why) from None
    seed = sections["sim"].get("seed")
    if seed is not None and (
        isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= MAX_SEED
    ):
        raise fail("sim.seed", f"must be an integer in [0, 2^63 - 1], got {seed!r}")
    return Rig(
        path=path,
        name=name,
        router=router,
        hosts=hosts,
        params=file(rig["params"], "rig.params") if "params" in rig else None,
        tls=file(rig["tls"], "rig.tls") if "tls" in rig else None,
        sections=sections,
    )


LAUNCHER = "launcher"  # the contract's name of `nod up` (services.lab.acl: its identity)
MONITOR = "monitor"
CONTROL = "control"  # the control station's role: the router's config, the conductor's identity


def session_flags(
    rig: Rig, host: Host, connect: str | None = None, service: str = ""
) -> list[str]:
    """The session flags of `service` on `host`: its rig and how it reaches the router.

    The one builder of them: every service `nod up` starts (`services.launch.commands`) and the
    conductor given `--rig-file` (on the control station: `Host(CONTROL, ())`).
    """
    if rig.tls is not None:
        return ["--config", str(identity(rig, service, host)), "--rig", rig.name]
    return ["--connect", connect or rig.router, "--rig", rig.name]


def router_config(tls: Path) -> Path:
    """The router's config in a `nod lab secure` folder: a rig router's, else the control's.

    A rig router of its own (`--router-per-rig`: `router/`, linked to the lab router) is the
    rig's router when the folder has one; otherwise the control station's (`control/`).
    """
    rig_router = tls / "router" / "router.json5"
    return rig_router if rig_router.is_file() else tls / CONTROL / "router.json5"


def identity(rig: Rig, process: str, host: Host | None = None) -> Path:
    """The zenoh config `process` (a service, `launcher`) of `host` speaks with under rig.tls.

    The monitor's is the read-only identity, whatever the host (`nod status` uses it too).
    """
    if rig.tls is None:
        raise ValueError(f"{rig.path}: rig.tls is not set: no identities")
    if process == MONITOR:
        return rig.tls / MONITOR / "zenoh.json5"
    if host is None:
        raise ValueError(f"the identity of {process} depends on its host")
    role = host.role or host.name
    if process == LAUNCHER:
        return rig.tls / role / LAUNCHER / "zenoh.json5"
    return rig.tls / role / "zenoh.json5"
