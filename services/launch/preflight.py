"""`nod up --dry-run`'s preflight: every file, serial port and camera this host's services need.

`load_rig` has already checked what needs no device and no other file (keys, values, bounds) and
`nod up` has loaded the params file. This looks at what the services will open, exactly as the
commands `services.launch.commands.command` builds would (`--sim-hardware` needs no port, no
camera and no trims): each file exists, is readable and parses as what it is, with the
services' own loaders (the arm file with the arm's, the eyes file and the trims with the eyes',
the vision calibration with vision's, each zenoh identity of rig.tls with zenoh's, and the
certificates it names with `cryptography`); each serial port is a character device this user
may read and write; each camera is there (an index N is /dev/videoN); the speaker's WAV folder
is writable, or its sound library installed; the display's address can be served on (bound
for an instant: the one socket this opens); the LSL outlet's library is installed. Every
problem is one line that starts with the rig file's key (`actuation.port: …`); `nod up
--dry-run` prints them all and exits 2. Nothing is opened for I/O: a device in use by a
running service stays untouched.
"""

from __future__ import annotations

import datetime
import errno
import getpass
import importlib.util
import json
import os
import socket
import stat
from collections.abc import Callable
from pathlib import Path
from typing import Any

from services.core.cli import host_port, one_line
from services.core.rigfile import LAUNCHER, Rig, identity, router_config

# The TLS files a zenoh config may name, and what each must hold.
_TLS_FILES = {
    "root_ca_certificate": "cert", "connect_certificate": "cert", "listen_certificate": "cert",
    "connect_private_key": "key", "listen_private_key": "key",
}


def problems(
    rig: Rig, services: list[str], *, host: str | None, with_router: bool, sim_hardware: bool
) -> list[str]:
    """One line per problem with what `services` (of `host`, None: all here) would open."""
    out: list[str] = []
    if rig.tls is not None:
        out += _identities(rig, services, host, with_router)
    for service in services:
        sec = rig.sections.get(service, {})
        if service in ("actuation", "eyes"):
            out += _device_service(service, sec, sim_hardware)
        elif service == "vision" and not sim_hardware:
            out += _camera("vision.source", str(sec.get("source", "0")))
            if "calibration" in sec:
                out += _parsed("vision.calibration", sec["calibration"], _calibration_file)
        elif service == "speaker":
            out += _speaker(sec, sim_hardware)
        elif service == "display" and "http" in sec:
            out += _http("display.http", sec["http"])
        elif service == "lsl" and importlib.util.find_spec("pylsl") is None:
            out.append("lsl: the LSL outlet needs the lsl extra: pip install 'nod-hri[lsl]'")
    return out


def _speaker(sec: dict[str, Any], sim_hardware: bool) -> list[str]:
    """The speaker's WAV file's folder, or its sound library (found, not loaded: PortAudio)."""
    driver = "sim" if sim_hardware else sec.get("driver", "sim")
    if driver == "wav":
        folder = Path(sec["out"]).parent
        if not folder.is_dir():
            return [f"speaker.out: the folder {folder} does not exist: create it"]
        return _folder("speaker.out", folder)
    if driver == "sounddevice" and importlib.util.find_spec("sounddevice") is None:
        return ["speaker.driver: the sounddevice driver needs the audio extra: pip install "
                "'nod-hri[audio]' (and PortAudio: apt install libportaudio2)"]
    return []


def _http(key: str, address: str) -> list[str]:
    """An address a service will serve on: this host can bind it now (bound, then let go)."""
    host, port = host_port(address)
    if port == 0:
        return []
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as the server will
        try:
            probe.bind((host, port))
        except OSError as exc:
            why = exc.strerror or str(exc)
            hint = " (a display already running, or another server)" \
                if exc.errno == errno.EADDRINUSE else ""
            return [f"{key}: cannot serve on {address}: {why}{hint}"]
    return []


def _device_service(service: str, sec: dict[str, Any], sim_hardware: bool) -> list[str]:
    """Actuation's or the eyes' port, hardware files and state folder."""
    out: list[str] = []
    driver = "sim" if sim_hardware else sec.get("driver", "sim")
    if driver != "sim":
        out += _serial(f"{service}.port", sec["port"])
    if service == "actuation" and driver == "feetech":
        if "config" not in sec:
            out.append("actuation.config: the feetech driver needs an arm file with its poses: "
                       "record one with `nod actuation calibrate --out arm.toml`")
        else:
            out += _parsed("actuation.config", sec["config"], _arm_file)
    if service == "eyes" and "config" in sec:  # the eyes service reads it whatever the driver
        out += _parsed("eyes.config", sec["config"], _eyes_file)
    if service == "eyes" and "trims" in sec and not sim_hardware:
        out += _parsed("eyes.trims", sec["trims"], _trims_file)
    if "state_dir" in sec:
        out += _folder(f"{service}.state_dir", Path(sec["state_dir"]))
    return out


# -- files ---------------------------------------------------------------------------------------


def _readable(key: str, path: Path) -> list[str]:
    if not path.exists():
        return [f"{key}: {path} does not exist"]
    if not path.is_file():
        return [f"{key}: {path} is not a file"]
    if not os.access(path, os.R_OK):
        return [f"{key}: {path} is not readable by {getpass.getuser()}"]
    return []


def _parsed(key: str, path: Path, load: Callable[[Path], object]) -> list[str]:
    """The file is there and its service's loader accepts it."""
    found = _readable(key, path)
    if found:
        return found
    try:
        load(path)
    except (ValueError, OSError) as exc:  # ConfigError is a ValueError
        text = one_line(str(exc))
        return [f"{key}: {text if str(path) in text else f'{path}: {text}'}"]
    return []


def _arm_file(path: Path) -> object:
    from services.actuation.drivers import load_arm_config

    return load_arm_config(path)


def _eyes_file(path: Path) -> object:
    from services.eyes.drivers import load_eyes_config

    return load_eyes_config(path)


def _trims_file(path: Path) -> object:
    from services.eyes.trims import load_trims

    return load_trims(path)


def _calibration_file(path: Path) -> object:
    from services.vision.calibration import load_table

    return load_table(path)  # the paper's two boxes, or N by option name


def _folder(key: str, path: Path) -> list[str]:
    """A folder a service writes to: there and writable, or creatable (its parent writable)."""
    if path.exists():
        if not path.is_dir():
            return [f"{key}: {path} is not a folder"]
        if not os.access(path, os.W_OK | os.X_OK):
            return [f"{key}: {path} is not writable by {getpass.getuser()}"]
        return []
    parent = next((p for p in path.parents if p.exists()), None)
    if parent is None or not os.access(parent, os.W_OK | os.X_OK):
        return [f"{key}: {path} does not exist and {parent} is not writable: create it"]
    return []


# -- identities ----------------------------------------------------------------------------------


def _identities(
    rig: Rig, services: list[str], host: str | None, with_router: bool
) -> list[str]:
    assert rig.tls is not None
    wanted: dict[Path, str] = {}
    for service in services:
        wanted.setdefault(identity(rig, service, rig.host_of(service)), f"{service}'s identity")
    if with_router:
        wanted[router_config(rig.tls)] = "the router's config"
    elif host is not None:
        wanted[identity(rig, LAUNCHER, rig.hosts[host])] = "nod up's identity"
    out: list[str] = []
    for path, what in wanted.items():
        out += _identity(path, what)
    return out


def _identity(path: Path, what: str) -> list[str]:
    """A zenoh config of `nod lab secure`: it loads, and the certificates it names are good."""
    key = f"rig.tls ({what})"
    found = _readable(key, path)
    if found:
        hint = "copy its folder from the control station, where `nod lab secure` wrote it"
        return [f"{found[0]}: {hint}"]
    import zenoh

    try:
        conf = zenoh.Config.from_file(str(path))
        tls: dict[str, Any] = json.loads(conf.get_json("transport/link/tls")) or {}
    except Exception as exc:  # zenoh raises its own ZError for a file it cannot parse
        return [f"{key}: {path} is not a zenoh config: {one_line(str(exc))}"]
    out: list[str] = []
    for name, kind in _TLS_FILES.items():
        if tls.get(name):
            out += _pem(key, Path(tls[name]), kind, f"{path}: {name}")
    return out


def _pem(key: str, path: Path, kind: str, where: str) -> list[str]:
    """A PEM certificate (not expired) or private key named by a zenoh config."""
    from cryptography import x509
    from cryptography.hazmat.primitives import serialization

    found = _readable(key, path)
    if found:
        return [f"{found[0]} (named by {where})"]
    data = path.read_bytes()
    try:
        if kind == "key":
            serialization.load_pem_private_key(data, password=None)
            return []
        cert = x509.load_pem_x509_certificate(data)
    except (ValueError, TypeError) as exc:
        return [f"{key}: {path} is not a PEM {'private key' if kind == 'key' else 'certificate'}"
                f": {one_line(str(exc))}"]
    expires = cert.not_valid_after_utc
    if expires < datetime.datetime.now(datetime.UTC):
        return [f"{key}: {path} expired on {expires:%Y-%m-%d}: run `nod lab secure` again"]
    return []


# -- devices -------------------------------------------------------------------------------------


def _device(key: str, path: Path, group: str, example: str, hint: str) -> list[str]:
    """A character device this user may open for reading and writing."""
    try:
        mode = path.stat().st_mode
    except FileNotFoundError:
        return [f"{key}: {path} does not exist (is it plugged in? {hint})"]
    except OSError as exc:
        return [f"{key}: {path}: {exc.strerror or exc}"]
    if not stat.S_ISCHR(mode):
        return [f"{key}: {path} is not a device (a character device such as {example})"]
    if not os.access(path, os.R_OK | os.W_OK):
        user = getpass.getuser()
        return [f"{key}: {path} is not readable and writable by {user}: add {user} to the "
                f"{group} group (`sudo usermod -aG {group} {user}`, then log in again)"]
    return []


def _serial(key: str, port: str) -> list[str]:
    return _device(key, Path(port), "dialout", "/dev/ttyUSB0", "`nod ports` lists them")


def _camera(key: str, source: str) -> list[str]:
    from services.vision.capture import parse_source

    try:
        src = parse_source(source)
    except ValueError as exc:
        return [f"{key}: {exc}"]
    hint = "`v4l2-ctl --list-devices` lists the cameras"
    if src.kind == "device":  # OpenCV's camera N on Linux (V4L2) is /dev/videoN
        return _device(f"{key} (camera {src.target})", Path(f"/dev/video{src.target}"), "video",
                       "/dev/video0", hint)
    if src.kind != "file":
        return []  # a URL, the rendered scene, a zenoh key: nothing to look at before it runs
    path = Path(str(src.target))
    if str(path).startswith("/dev/"):
        return _device(key, path, "video", "/dev/video0", hint)
    found = _readable(key, path)
    if found:
        return found
    import cv2

    capture = cv2.VideoCapture(str(path))
    try:
        if not capture.isOpened():
            return [f"{key}: {path} is not a video OpenCV can read"]
    finally:
        capture.release()
    return []
