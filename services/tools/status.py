"""`nod status`: is the rig up? Services, keys, devices and clocks, from any host.

It listens for `--duration` seconds (default 2). The liveliness tokens say who is alive; the
heartbeats on rig/status (1 Hz per service, from `Node`) say where each service runs, its
version, since when, how often its launcher restarted it, and the host's wall clock, compared
with ours at arrival: the clock offset, which matters because the safety bounds compare
timestamps across hosts (above `CLOCK_WARN_MS` it is flagged). The state keys of the arm and
eyes give their safe stop and why; rig/event lines say what the launchers did; every key gets
its rate and age. Exit 1 when a required service is down (the rig file's services, or decision,
actuation, eyes and vision: the sim counts as vision), 2 on bad input. `--watch` repeats until
Ctrl-C.
"""

from __future__ import annotations

import argparse
import io
import json
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zenoh

from services.core import messages as m
from services.core.cli import fabric_parser, fail
from services.core.rigfile import MONITOR, REQUIRED, RigFileError, identity, load_rig
from services.tools.observe import CLOCK_WARN_MS, Rate, ToolError, Window, listen

PROG = "nod status"
# The sim participant stands in for the camera: it also holds vision's liveliness token.
STANDS_IN = {"vision": "sim"}


@dataclass
class Observation:
    """What one listening window saw."""

    alive: set[str] = field(default_factory=set)
    heartbeats: dict[str, tuple[m.NodeStatus, int]] = field(default_factory=dict)  # + arrival ns
    # Per service, its clock minus ours (ms) from the least-delayed heartbeat of the window: each
    # sent − arrived is the offset less that heartbeat's one-way delay (≥ 0), so the largest is
    # the nearest (the NTP filter). The last heartbeat alone read 21 ms on one host under load.
    offsets: dict[str, float] = field(default_factory=dict)
    keys: dict[str, Rate] = field(default_factory=dict)
    last_wall: dict[str, int] = field(default_factory=dict)  # key -> arrival wall ns
    devices: dict[str, m.ArmStateMsg | m.EyesStateMsg] = field(default_factory=dict)
    events: list[m.RigEvent] = field(default_factory=list)
    invalid: int = 0

    def heartbeat(self, msg: m.NodeStatus, arrival_wall: int) -> None:
        """A service's heartbeat arrived (wall ns): the latest kept, the nearest offset too."""
        self.heartbeats[msg.service] = (msg, arrival_wall)
        offset = (msg.wall_ns - arrival_wall) / 1e6
        self.offsets[msg.service] = max(offset, self.offsets.get(msg.service, offset))


def observe(
    session: zenoh.Session, rig: str, duration: float, stop: threading.Event
) -> Observation:
    """Listen to the rig for `duration` seconds."""
    obs = Observation()
    prefix = f"nod/{rig}/alive/"
    lock = threading.Lock()

    def on_alive(sample: zenoh.Sample) -> None:
        name = str(sample.key_expr)[len(prefix):]
        with lock:
            if sample.kind == zenoh.SampleKind.PUT:
                obs.alive.add(name)
            else:
                obs.alive.discard(name)

    with Window(session, f"nod/{rig}/**", f"{prefix}*", on_alive) as window:
        for item, msg in window.heard(time.monotonic() + duration, stop):
            obs.keys.setdefault(item.key, Rate()).add(item.t)
            obs.last_wall[item.key] = item.wall_ns
            if msg is None:
                obs.invalid += 1
                continue
            if isinstance(msg, m.NodeStatus):
                obs.heartbeat(msg, item.wall_ns)
            elif isinstance(msg, m.ArmStateMsg):
                obs.devices["actuation"] = msg
            elif isinstance(msg, m.EyesStateMsg):
                obs.devices["eyes"] = msg
            elif isinstance(msg, m.RigEvent):
                obs.events.append(msg)
    with lock:
        obs.alive = set(obs.alive)
    return obs


def report(obs: Observation, rig: str, required: tuple[str, ...], now_wall: int) -> dict[str, Any]:
    """The status document (`--json` prints it)."""
    names = sorted(set(obs.alive) | set(obs.heartbeats) | set(required))
    services = []
    for name in names:
        hb = obs.heartbeats.get(name)
        alive = name in obs.alive
        row: dict[str, Any] = {"service": name, "alive": alive, "required": name in required}
        if name in STANDS_IN and alive and name not in obs.heartbeats:
            stand_in = obs.heartbeats.get(STANDS_IN[name])
            if stand_in is not None:
                row["stands_in"] = STANDS_IN[name]
        if hb is not None:
            msg, arrival = hb
            offset_ms = obs.offsets.get(name, (msg.wall_ns - arrival) / 1e6)
            row |= {
                "host": msg.host, "pid": msg.pid, "version": msg.version,
                "uptime_s": round(max(0.0, (msg.wall_ns - msg.started_ns) / 1e9), 1),
                "restarts": msg.restarts, "received": msg.received, "dropped": msg.dropped,
                "clock_offset_ms": round(offset_ms, 2),
                "clock_warning": abs(offset_ms) > CLOCK_WARN_MS,
                "heartbeat_age_s": round((now_wall - arrival) / 1e9, 2),
            }
        services.append(row)
    keys = []
    for key in sorted(obs.keys):
        stats = obs.keys[key].total()
        keys.append({
            "key": key,
            "count": obs.keys[key].count,
            "rate_hz": round(stats.rate_hz, 2) if stats else None,
            "age_s": round((now_wall - obs.last_wall[key]) / 1e9, 2),
        })
    devices = {
        name: {
            "safe_stop": d.safe_stop, "reason": d.safety_reason, "estop": d.estop,
            "fault": d.fault,
        }
        for name, d in sorted(obs.devices.items())
    }
    down = [s["service"] for s in services if s["required"] and not s["alive"]]
    return {
        "rig": rig,
        "ok": not down,
        "down": down,
        "services": services,
        "keys": keys,
        "devices": devices,
        "events": [
            {"host": e.host, "service": e.service, "kind": e.kind, "code": e.code,
             "restarts": e.restarts, "text": e.text}
            for e in obs.events
        ],
        "invalid_messages": obs.invalid,
    }


def render(doc: dict[str, Any]) -> Any:
    """The document as rich renderables (a table of services, keys, devices)."""
    from rich.console import Group
    from rich.table import Table
    from rich.text import Text

    svc = Table(title=f"rig {doc['rig']}: services", title_justify="left", expand=False)
    for col in ("service", "state", "host", "version", "uptime", "restarts", "clock", "msgs"):
        svc.add_column(col)
    for s in doc["services"]:
        state = Text("alive", style="green") if s["alive"] else Text(
            "DOWN" if s["required"] else "down", style="bold red" if s["required"] else "yellow"
        )
        if s.get("stands_in"):
            state.append(f" (as {s['stands_in']})", style="dim")
        clock = ""
        if "clock_offset_ms" in s:
            clock = f"{s['clock_offset_ms']:+.1f} ms"
            if s["clock_warning"]:
                clock += " !"
        svc.add_row(
            s["service"], state, s.get("host", ""), s.get("version", ""),
            f"{s['uptime_s']:.0f} s" if "uptime_s" in s else "",
            str(s.get("restarts", "")), Text(clock, style="red" if s.get("clock_warning") else ""),
            f"{s['received']}/{s['dropped']} bad" if "received" in s else "",
        )
    keys = Table(title="keys", title_justify="left")
    for col in ("key", "rate", "age"):
        keys.add_column(col)
    for k in doc["keys"]:
        rate = f"{k['rate_hz']:.1f} Hz" if k["rate_hz"] is not None else f"{k['count']} msg"
        keys.add_row(k["key"], rate, f"{k['age_s']:.1f} s")
    parts: list[Any] = [svc, keys]
    if doc["devices"]:
        dev = Table(title="devices", title_justify="left")
        for col in ("device", "safety", "reason"):
            dev.add_column(col)
        for name, d in doc["devices"].items():
            safety = "E-STOP" if d["estop"] else ("safe stop" if d["safe_stop"] else "running")
            style = "bold red" if d["estop"] else ("yellow" if d["safe_stop"] else "green")
            dev.add_row(name, Text(safety, style=style), d["reason"] or d["fault"])
        parts.append(dev)
    for e in doc["events"][-10:]:
        parts.append(Text(f"[{e['host']}] {e['service']} {e['kind']}: {e['text']}", style="dim"))
    if doc["down"]:
        parts.append(Text(f"required service(s) down: {', '.join(doc['down'])}", style="bold red"))
    return Group(*parts)


def build_parser() -> argparse.ArgumentParser:
    """The command line of `nod status`."""
    p = fabric_parser(PROG, __doc__.splitlines()[0])
    p.add_argument("--rig-file", type=Path, default=None,
                   help="take the rig name, router and required services from a rig file")
    p.add_argument("--duration", type=float, default=2.0, metavar="S", help="listen S seconds (2)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--watch", action="store_true", help="refresh until Ctrl-C")
    p.add_argument("--lab", action="store_true",
                   help="every rig on the network instead of one: `nod lab status` (its flags)")
    return p


def main(argv: list[str] | None = None) -> int:
    """Listen, report; exit 1 if a required service is down."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if "--lab" in argv:
        from services.tools.lab_status import main as lab

        return lab([a for a in argv if a != "--lab"])
    args = build_parser().parse_args(argv)
    if not 0.5 <= args.duration <= 600:
        return fail(PROG, "--duration must be in [0.5, 600] s")
    required: tuple[str, ...] = REQUIRED
    if args.rig_file is not None:
        try:
            rig = load_rig(args.rig_file)
        except RigFileError as exc:
            return fail(PROG, exc)
        args.rig = rig.name
        if not (args.connect or args.config) and rig.tls is not None:
            args.config = identity(rig, MONITOR)  # read-only: a status never drives the rig
        elif not (args.connect or args.config):
            args.connect = [rig.router]
        placed = {"vision" if s == "sim" else s for s in rig.services}
        required = tuple(sorted(placed - {"monitor"}))
    try:
        session, stop = listen(args)
    except ToolError as exc:
        return fail(PROG, exc)
    try:
        if not args.watch:
            doc = report(observe(session, args.rig, args.duration, stop), args.rig, required,
                         time.time_ns())
            _print(doc, args.json)
            return 0 if doc["ok"] else 1
        from rich.live import Live

        last: dict[str, Any] | None = None
        with Live(auto_refresh=False) as live:
            while not stop.is_set():
                last = report(observe(session, args.rig, args.duration, stop), args.rig, required,
                              time.time_ns())
                live.update(render(last), refresh=True)
        return 0 if last is None or last["ok"] else 1
    finally:
        session.close()


def _print(doc: dict[str, Any], as_json: bool, out: Any = None) -> None:
    out = out if out is not None else sys.stdout
    if as_json:
        print(json.dumps(doc), file=out, flush=True)
        return
    from rich.console import Console
    from rich.measure import Measurement

    view = render(doc)
    if out.isatty():  # the terminal's width
        Console(file=out).print(view)
        return
    # Piped (a log, grep, a ticket): no name cut at 80 columns; as wide as the widest row.
    wide = Console(file=out, width=10_000)
    width = Measurement.get(wide, wide.options, view).maximum
    text = io.StringIO()
    Console(file=text, width=max(40, width), no_color=True).print(view)
    out.write("".join(line.rstrip() + "\n" for line in text.getvalue().splitlines()))
    out.flush()


if __name__ == "__main__":
    raise SystemExit(main())
