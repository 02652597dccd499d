"""`nod lab status` (`nod status --lab`): every rig on the lab's network, one line per rig.

It listens to every rig at once (`nod/*/…`) for `--duration` seconds (default 2): the liveliness
tokens say which services of each rig are alive; the heartbeats (rig/status, 1 Hz per service)
where each runs and its host's clock offset from ours, and the conductor's its session,
participant and trial; the conductor's events (experiment/trial: one key space, schema 3, for
any option set) the trial's phase and the session's options as it happens. A rig is on the
network when anything of it was heard. On a secured lab it speaks with the lab's read-only
identity (`--config <lab>/lab/monitor/zenoh.json5`): a rig's own identities see only their rig.
`--json` prints one object, `--watch` refreshes until Ctrl-C (keeping each rig's last event
between refreshes).
Exit 1 when no rig answered, 2 on bad input.
"""

from __future__ import annotations

import argparse
import json
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import zenoh

from services.core import messages as m
from services.core.cli import Parser, fail
from services.core.session import add_zenoh_args
from services.model.geometry import COLOURS
from services.tools.observe import CLOCK_WARN_MS, ToolError, Window, listen

PROG = "nod lab status"
CONDUCTOR = "experiment"


@dataclass
class LabObservation:
    """What one listening window heard of every rig (events outlive a window under --watch)."""

    alive: dict[str, set[str]] = field(default_factory=dict)  # rig -> services
    heartbeats: dict[tuple[str, str], tuple[m.NodeStatus, int]] = field(default_factory=dict)
    events: dict[str, m.TrialEvent] = field(default_factory=dict)  # rig -> its last event
    invalid: int = 0


def _rig_of(key: str) -> str:
    return key.split("/", 2)[1]


def observe(
    session: zenoh.Session, duration: float, stop: threading.Event,
    events: dict[str, m.TrialEvent] | None = None,
) -> LabObservation:
    """Listen to every rig for `duration` seconds (`events`: the last ones already known)."""
    obs = LabObservation(events=dict(events or {}))
    lock = threading.Lock()

    def on_alive(sample: zenoh.Sample) -> None:
        _, rig, _, service = str(sample.key_expr).split("/", 3)
        with lock:
            services = obs.alive.setdefault(rig, set())
            if sample.kind == zenoh.SampleKind.PUT:
                services.add(service)
            else:
                services.discard(service)

    keys = ["nod/*/rig/status", "nod/*/experiment/trial"]
    with Window(session, keys, "nod/*/alive/*", on_alive) as window:
        for item, msg in window.heard(time.monotonic() + duration, stop):
            if msg is None:
                obs.invalid += 1
                continue
            rig = _rig_of(item.key)
            if isinstance(msg, m.NodeStatus):
                obs.heartbeats[(rig, msg.service)] = (msg, item.wall_ns)
            elif isinstance(msg, m.TrialEvent):
                obs.events[rig] = msg
    with lock:
        obs.alive = {rig: set(s) for rig, s in obs.alive.items()}
    return obs


def report(obs: LabObservation, now_wall: int) -> dict[str, Any]:
    """The lab document (`--json` prints it): one entry per rig heard, by name."""
    rigs = sorted({*obs.alive, *(r for r, _ in obs.heartbeats), *obs.events})
    out = []
    for rig in rigs:
        alive = obs.alive.get(rig, set())
        beats = {s: hb for (r, s), hb in obs.heartbeats.items() if r == rig}
        services = []
        for name in sorted(alive | set(beats)):
            row: dict[str, Any] = {"service": name, "alive": name in alive}
            if name in beats:
                msg, arrival = beats[name]
                offset = (msg.wall_ns - arrival) / 1e6
                row |= {"host": msg.host, "version": msg.version, "restarts": msg.restarts,
                        "clock_offset_ms": round(offset, 2),
                        "clock_warning": abs(offset) > CLOCK_WARN_MS,
                        "heartbeat_age_s": round((now_wall - arrival) / 1e9, 2)}
            services.append(row)
        conductor = beats.get(CONDUCTOR, (None, 0))[0]
        event = obs.events.get(rig)
        # The heartbeat says what runs now; an event of the same session says it more freshly.
        session = conductor.session if conductor is not None else ""
        fresh = event is not None and (not session or event.session == session)
        offsets = [s["clock_offset_ms"] for s in services if "clock_offset_ms" in s]
        out.append({
            "rig": rig,
            "services": services,
            "alive": sorted(alive),
            "session": session or (event.session if fresh and event else "") or None,
            "participant": (conductor.participant or None) if conductor is not None else None,
            "trial": (event.trial if fresh and event else
                      conductor.trial if conductor is not None else 0) or None,
            "phase": event.phase if fresh and event else None,
            "options": list(event.options) if fresh and event else None,
            "max_clock_offset_ms": max(offsets, key=abs) if offsets else None,
            "clock_warning": any(s.get("clock_warning") for s in services),
        })
    return {"rigs": out, "invalid_messages": obs.invalid}


def text(doc: dict[str, Any]) -> str:
    """The document as plain text: one line per rig, then its services and their clocks."""
    if not doc["rigs"]:
        return ("no rig heard on this network (a secured lab: the lab's identity, --config "
                "<lab>/lab/monitor/zenoh.json5)")
    lines = []
    for r in doc["rigs"]:
        where = f"trial {r['trial']}" if r["trial"] else "no trial"
        if r["phase"]:
            where += f" ({r['phase']})"
        if r.get("options") and tuple(r["options"]) != COLOURS:  # the paper's go unsaid
            where += f", options {','.join(r['options'])}"
        who = (f"participant {r['participant']}, session {r['session']}" if r["participant"]
               else "no session" if not r["session"] else f"session {r['session']}")
        clock = ("" if r["max_clock_offset_ms"] is None
                 else f", clocks within {abs(r['max_clock_offset_ms']):.1f} ms"
                 + (" (!)" if r["clock_warning"] else ""))
        lines.append(f"{r['rig']}: {len(r['alive'])} alive, {where}, {who}{clock}")
        for s in r["services"]:
            state = "alive" if s["alive"] else "down"
            at = (f" on {s['host']}, clock {s['clock_offset_ms']:+.1f} ms"
                  if "host" in s else "")
            lines.append(f"  {s['service']:<11} {state}{at}")
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    """The command line of `nod lab status`."""
    p = Parser(prog=PROG, description=__doc__.splitlines()[0])
    add_zenoh_args(p, rig=False)
    p.add_argument("--duration", type=float, default=2.0, metavar="S", help="listen S seconds (2)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--watch", action="store_true", help="refresh until Ctrl-C")
    return p


def main(argv: list[str] | None = None) -> int:
    """Listen to every rig, report; exit 1 if none answered."""
    args = build_parser().parse_args(argv)
    if not 0.5 <= args.duration <= 600:
        return fail(PROG, "--duration must be in [0.5, 600] s")
    try:
        session, stop = listen(args)
    except ToolError as exc:
        return fail(PROG, exc)
    doc: dict[str, Any] = {"rigs": []}
    try:
        events: dict[str, m.TrialEvent] = {}
        while True:
            obs = observe(session, args.duration, stop, events)
            events = obs.events
            doc = report(obs, time.time_ns())
            if args.json:
                print(json.dumps(doc), flush=True)
            else:
                clear = "\x1b[H\x1b[2J" if args.watch else ""
                print(clear + text(doc), flush=True)
            if not args.watch or stop.is_set():
                break
    finally:
        session.close()
    return 0 if doc["rigs"] else 1


if __name__ == "__main__":
    raise SystemExit(main())
