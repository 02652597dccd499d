"""How fast actuation and eyes acknowledge an e-stop while their input keys are flooded.

Real processes on a free loopback port: a router (`nod router`), `nod actuation` and `nod eyes`
(simulated devices, their latch on this run's own folder), and this process as the operator's
console, which engages and releases the e-stop (alternately, every 150 ms, ids ordered as
`nod estop` orders them) and times each command from its put to the first state message of
each device that acknowledges it (`estop_id`).

- **Baseline**: the same commands with the rig quiet.
- **Candidate**: the same commands while `benchmarks/flood.py` (a process of its own) floods
  z_r, hand poses and gaze, valid and size-legal, as fast as it can.

Goal: p99 of the acknowledgement under the flood ≤ 50 ms for both devices, and every command
acknowledged. Before the e-stop had a path of its own (`Node.subscribe_urgent`) actuation took
0.4-3.5 s under such a flood.

    .venv/bin/python benchmarks/estop_flood.py [--commands 40] [--goal-ms 50] [--tree DIR]

`--tree DIR` runs the services of another checkout (e.g. an older commit, to see the before).
"""

from __future__ import annotations

import argparse
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from services.core import messages as m  # noqa: E402
from services.core.keys import Keys  # noqa: E402
from services.core.session import make_config, open_session  # noqa: E402
from services.model.latch import new_command_id  # noqa: E402

KEYS = Keys("rig1")
DEVICES = ("actuation", "eyes")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Acks:
    """Arrival times of each device's first state acknowledging each command id."""

    def __init__(self, session) -> None:
        self.first: dict[tuple[str, str], float] = {}
        self.lock = threading.Lock()
        self.seen: dict[str, int] = dict.fromkeys(DEVICES, 0)
        self.subs = [
            session.declare_subscriber(KEYS.topic(f"{d}/state"),
                                       lambda s, d=d: self._on(d, s)) for d in DEVICES
        ]

    def _on(self, device: str, sample) -> None:
        now = time.monotonic()
        cls = m.ArmStateMsg if device == "actuation" else m.EyesStateMsg
        try:
            state = m.decode(cls, sample.payload.to_bytes())
        except m.MessageError:
            return
        with self.lock:
            self.seen[device] += 1
            self.first.setdefault((device, state.estop_id), now)


def measure(session, acks: Acks, commands: int, wait_s: float) -> dict[str, list[float]]:
    """Engage and release alternately; per device, each command's acknowledgement in ms (inf:
    none within `wait_s`)."""
    pubs = {True: session.declare_publisher(KEYS.topic("safety/estop")),
            False: session.declare_publisher(KEYS.topic("safety/release"))}
    out: dict[str, list[float]] = {d: [] for d in DEVICES}
    for i in range(commands):
        engage = i % 2 == 0
        cid = new_command_id(time.time_ns())
        t0 = time.monotonic()
        pubs[engage].put(m.encode(m.Estop(seq=i, t_ns=time.time_ns(), engaged=engage,
                                          reason="bench", source="bench", id=cid)))
        deadline = t0 + wait_s
        while time.monotonic() < deadline:
            with acks.lock:
                if all((d, cid) in acks.first for d in DEVICES):
                    break
            time.sleep(0.001)
        with acks.lock:
            for d in DEVICES:
                at = acks.first.get((d, cid))
                out[d].append((at - t0) * 1e3 if at is not None else float("inf"))
        time.sleep(0.15)
    return out


def summary(ms: list[float]) -> str:
    a = np.array(ms)
    done = a[np.isfinite(a)]
    lost = len(a) - len(done)
    if not len(done):
        return f"none acknowledged ({lost} lost)"
    return (f"p50 {np.percentile(done, 50):7.1f} ms  p99 {np.percentile(a, 99):8.1f} ms  "
            f"max {a.max():8.1f} ms  unacknowledged {lost}")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--commands", type=int, default=40)
    p.add_argument("--goal-ms", type=float, default=50.0)
    p.add_argument("--wait-s", type=float, default=5.0, help="give up on an ack after this")
    p.add_argument("--tree", type=Path, default=ROOT, help="checkout whose services to run")
    args = p.parse_args(argv)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    procs: list[subprocess.Popen] = []
    state = tempfile.mkdtemp(prefix="nod-bench-state-")
    logs = Path(tempfile.mkdtemp(prefix="nod-bench-logs-"))
    env = {**os.environ, "NOD_STATE_DIR": state}

    def start(*cmd: str, cwd: Path = args.tree) -> subprocess.Popen:
        log = (logs / f"{cmd[0]}.log").open("w")
        proc = subprocess.Popen([sys.executable, "-m", "services.cli", *cmd], cwd=cwd, env=env,
                                stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
        procs.append(proc)
        return proc

    session = None
    try:
        start("router", "--listen", endpoint)
        deadline = time.monotonic() + 30
        while True:
            try:
                session = open_session(make_config(mode="client", connect=[endpoint]))
                break
            except ConnectionError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.05)
        for device in DEVICES:
            start(device, "--connect", endpoint)
        acks = Acks(session)
        deadline = time.monotonic() + 60
        while min(acks.seen.values()) < 50:  # both devices up and publishing
            if time.monotonic() > deadline:
                print(f"devices not up; logs in {logs}", file=sys.stderr)
                return 1
            time.sleep(0.05)
        quiet = measure(session, acks, args.commands, args.wait_s)
        flood = subprocess.Popen(
            [sys.executable, str(ROOT / "benchmarks" / "flood.py"), "--connect", endpoint,
             "--seconds", "600"], stdout=subprocess.PIPE, text=True)
        time.sleep(2.0)  # let the queues fill
        flooded = measure(session, acks, args.commands, args.wait_s)
        flood.terminate()
        sent = flood.communicate(timeout=20)[0].strip()
        print(f"e-stop acknowledgements, {args.commands} commands each (services of "
              f"{args.tree}); flood: {sent} messages")
        ok = True
        for d in DEVICES:
            print(f"  {d:9s} quiet:   {summary(quiet[d])}")
            print(f"  {d:9s} flooded: {summary(flooded[d])}")
            q99 = float(np.percentile(quiet[d], 99))
            f99 = float(np.percentile(flooded[d], 99))
            print(f"  {d:9s} ratio flooded/quiet p99: {f99 / q99 if q99 else float('nan'):.2f}")
            ok &= f99 <= args.goal_ms
        print(f"goal p99 under the flood <= {args.goal_ms:.0f} ms: {'met' if ok else 'MISSED'}")
        return 0 if ok else 1
    finally:
        if session is not None:
            session.close()
        for proc in procs:
            proc.terminate()
        for proc in procs:
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()


if __name__ == "__main__":
    raise SystemExit(main())
