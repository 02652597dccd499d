"""`nod ports`: the serial devices of this host, with their USB ids and the rig's driver for each.

Lists what pyserial's `serial.tools.list_ports` finds (device path, description, USB VID:PID,
serial number, manufacturer) and, when the VID:PID is one the rig uses, which `--driver` of the
project it probably is. Pseudo-terminals (the protocol emulators of the tests, `socat` pairs) are
never listed: pass their path to `--port` directly.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from serial.tools import list_ports
from serial.tools.list_ports_common import ListPortInfo

from services.core.cli import Parser, print_report

PTY_NOTE = "pseudo-terminals (test emulators, socat pairs) are not listed; pass them to --port"

_FEETECH = "the arm's servo bus adapter (`nod actuation --driver feetech --port {device}`)"
_MAESTROS = {
    0x0089: "Micro Maestro 6",
    0x008A: "Mini Maestro 12",
    0x008B: "Mini Maestro 18",
    0x008C: "Mini Maestro 24",
}


def driver_hint(vid: int | None, pid: int | None, device: str = "PORT", interface: str = "",
                location: str = "") -> str | None:
    """Which driver of the rig a USB serial device probably is, or None if unknown."""
    if vid is None or pid is None:
        return None
    if (vid, pid) == (0x1A86, 0x7523):
        return "CH340: " + _FEETECH.format(device=device) + ", or an Arduino clone"
    if (vid, pid) == (0x1A86, 0x55D3):
        return "CH343/CH9102: " + _FEETECH.format(device=device)
    if vid == 0x1FFB and pid in _MAESTROS:
        text = (
            f"Pololu {_MAESTROS[pid]}: the eyes' servo controller "
            f"(`nod eyes --driver maestro --port {device}`)"
        )
        port = _maestro_port(interface, location)
        if port == "command":
            return text + "; its Command Port, the right one"
        if port == "ttl":
            return (
                f"Pololu {_MAESTROS[pid]}: its TTL Port, NOT the one for `nod eyes` "
                "(use the Command Port, the other ttyACM of the pair)"
            )
        return text + "; use its Command Port (the first ttyACM of the pair)"
    if vid in (0x2341, 0x2A03):
        return f"Arduino: the eyes' servo board (`nod eyes --driver arduino --port {device}`)"
    return None


def _maestro_port(interface: str, location: str) -> str | None:
    """A Maestro's two virtual ports: the Command Port (USB interface 0) or the TTL Port (2)."""
    text = interface.lower()
    if "command" in text:
        return "command"
    if "ttl" in text:
        return "ttl"
    # pyserial's location of one interface of a multi-interface device: "1-1.2:1.0"
    interface_number = location.rpartition(":")[2] if ":" in location else ""
    return {"1.0": "command", "1.2": "ttl"}.get(interface_number)


def describe(info: ListPortInfo) -> dict[str, Any]:
    """One serial device as a JSON object."""
    usb = info.vid is not None and info.pid is not None
    return {
        "device": info.device,
        "description": None if info.description in (None, "n/a") else info.description,
        "usb": f"{info.vid:04x}:{info.pid:04x}" if usb else None,
        "serial_number": info.serial_number,
        "manufacturer": info.manufacturer,
        "product": info.product,
        "interface": info.interface,
        "location": info.location,
        "driver": driver_hint(
            info.vid, info.pid, info.device, info.interface or "", info.location or ""
        ),
    }


def ports() -> list[dict[str, Any]]:
    """Every serial device pyserial finds, USB ones first, each sorted by path."""
    found = [describe(p) for p in list_ports.comports()]
    return sorted(found, key=lambda p: (p["usb"] is None, p["device"]))


def lines(found: list[dict[str, Any]]) -> list[str]:
    """The text form: one line per device, an indented line for a known driver."""
    if not found:
        return ["no serial ports found", f"({PTY_NOTE})"]
    out = []
    for p in found:
        extra = [
            p["usb"] or "not USB",
            p["description"] or "",
            f"serial {p['serial_number']}" if p["serial_number"] else "",
            p["manufacturer"] or "",
        ]
        out.append("  ".join([p["device"], *[e for e in extra if e]]))
        if p["driver"]:
            out.append(f"    probably {p['driver']}")
    out.append(f"({PTY_NOTE})")
    return out


def build_parser() -> argparse.ArgumentParser:
    """The command line of `nod ports`."""
    p = Parser(
        prog="nod ports",
        description="List this host's serial devices with their USB ids, and the rig's driver "
        "each probably is (Feetech arm adapter, Pololu Maestro, Arduino). " + PTY_NOTE + ".",
    )
    p.add_argument("--json", action="store_true", help="print a JSON list")
    return p


def main(argv: list[str] | None = None) -> int:
    """Print the serial devices; 0 even when there are none."""
    args = build_parser().parse_args(argv)
    found = ports()
    print_report(found, lines(found), args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
