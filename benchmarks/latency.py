"""Hand pose → z_r round trip through a standalone decision process, against a raw Zenoh echo.

Both legs are paced at 120 Hz (a camera's rate, not a ping-pong loop: wake-ups count) through the
same router in this run, alternately in rounds so the host's drift hurts neither. Prints p50/p99
of each, the p50 ratio, and lost messages; exits 1 when a goal is missed.

`--loaded` measures inside a running `nod run --sim --render` (its router, every service of a
simulated rig, the sim camera at 30 Hz and `nod vision` tracking it), as a rig runs a study:
the benchmark's echo and decision (rig "bench") meet on that run's router. Goals: decision
p50 ≤ 1.5 × echo p50 and p99 ≤ 1 ms loaded; ≤ 1.2 × unloaded; nothing lost.

What the tail is made of: `--priority nice|fifo` runs the router (loaded: the top `nod run`'s
threads once its rig is up, not the rig's services), the echo, the decision under test and this
process at nice −10 or SCHED_FIFO (needs CAP_SYS_NICE); `--gc freeze|off` freezes (and turns
off) the garbage collector in this process, the echo and the decision once they are up. Every
collection in the three is recorded and the samples over 1 ms that overlap one are counted;
each process's run-queue wait per timeslice and the host's steal time are printed too.
`--lowlatency` (unloaded) puts every session on zenoh's low-latency transport: no batching.

    .venv/bin/python benchmarks/latency.py [--seconds 10] [--rate 120] [--loaded]
        [--priority none|nice|fifo] [--gc default|freeze|off] [--lowlatency]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import zenoh

from services.core import messages as m
from services.core.keys import Keys
from services.core.session import make_config, open_session

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)  # the tests' helpers
from benchmarks.rig_probe import (  # noqa: E402
    PRIORITIES,
    gc_probe,
    overlapping,
    prioritize,
    run_queue,
    set_priority,
    steal_ticks,
)
from tests.processes import free_port  # noqa: E402

# zenoh's low-latency transport: a put is written to the socket on the caller's thread, no
# transmission queue, batching or tx thread in between (both ends of a link must have it, and it
# has no QoS priorities). The rest is what make_config sets without a file.
LOWLATENCY = """{
  scouting: { multicast: { enabled: false } },
  transport: {
    unicast: { lowlatency: true, qos: { enabled: false } },
    link: { rx: { max_message_size: 1048576 } },
  },
}
"""
KEYS = Keys("bench")
LOAD_RIG = Keys("rig1")
TAIL_US = 1000.0  # the goal: samples above it are the tail
# `nod decision` with its garbage collections recorded (rig_probe.gc_probe): argv MODE LOG ARGS…
DECISION = """import runpy, sys
from benchmarks.rig_probe import gc_probe
gc_probe(sys.argv[1], sys.argv[2])
sys.argv = ["nod", *sys.argv[3:]]
runpy.run_module("services.cli", run_name="__main__", alter_sys=True)
"""


def pose(seq: int, i: int) -> bytes:
    """A detected hand pose (21 landmarks) stamped now."""
    x, y = 0.5 + 0.002 * (i % 100), 0.85 - 0.003 * (i % 100)
    lm = tuple((x + 0.01 * math.cos(k), y + 0.01 * math.sin(k)) for k in range(21))
    return m.encode(
        m.HandPose(
            seq=seq, t_ns=time.time_ns(), detected=True, center=(x, y), landmarks=lm, source="bench"
        )
    )


class Leg:
    """One round trip: a publisher and the subscriber of its answers, declared once."""

    def __init__(
        self, session: zenoh.Session, send: str, recv: str, seq_of: Callable[[bytes], int]
    ) -> None:
        self.got: dict[int, int] = {}
        self.pub = session.declare_publisher(send, express=True)

        def on(sample: zenoh.Sample) -> None:
            t = time.perf_counter_ns()
            self.got.setdefault(seq_of(sample.payload.to_bytes()), t)

        self.sub = session.declare_subscriber(recv, zenoh.handlers.Callback(on, indirect=False))

    def run(self, base: int, n: int, rate: float) -> tuple[np.ndarray, int, list[tuple[int, int]]]:
        """Send n poses (seq base..base+n-1) paced at `rate`; latencies in µs, the lost, and
        the (sent, answered) perf_counter_ns spans of the answers over `TAIL_US`."""
        sent: dict[int, int] = {}
        period = 1.0 / rate
        start = time.perf_counter()
        for i in range(n):
            target = start + i * period
            while (now := time.perf_counter()) < target:
                time.sleep(min(0.001, target - now))
            payload = pose(base + i, i)
            sent[base + i] = time.perf_counter_ns()
            self.pub.put(payload)
        time.sleep(0.3)  # the last answers
        lat = np.array([(self.got[s] - t) / 1e3 for s, t in sent.items() if s in self.got])
        tail = [
            (t, self.got[s])
            for s, t in sent.items()
            if s in self.got and self.got[s] - t > TAIL_US * 1e3
        ]
        return lat, len(sent) - len(lat), tail

    def close(self) -> None:
        """Undeclare both ends."""
        self.sub.undeclare()
        self.pub.undeclare()


def wait_alive(session: zenoh.Session, key: str, timeout: float = 30.0) -> None:
    """Block until some process holds the liveliness token `key`."""
    ok = threading.Event()
    sub = session.liveliness().declare_subscriber(key, lambda s: ok.set(), history=True)
    try:
        if not ok.wait(timeout):
            raise SystemExit(f"no liveliness on {key} after {timeout} s")
    finally:
        sub.undeclare()


def wait_trial(session: zenoh.Session, timeout: float = 60.0) -> None:
    """Block until the loading rig's conductor says "go" (a trial runs: the arm moves too)."""
    go = threading.Event()

    def on(sample: zenoh.Sample) -> None:
        if m.decode(m.TrialEvent, sample.payload.to_bytes()).phase == "go":
            go.set()

    sub = session.declare_subscriber(LOAD_RIG.topic("experiment/trial"), on)
    try:
        if not go.wait(timeout):
            raise SystemExit(f"the loading rig started no trial within {timeout} s")
    finally:
        sub.undeclare()


def start_load(endpoint: str, folder: str) -> subprocess.Popen:
    """A `nod run --sim --render` hosting the router at `endpoint`, with a long study."""
    return subprocess.Popen(
        [
            sys.executable,
            "-m",
            "services.cli",
            "run",
            "--sim",
            "--render",
            "--participants",
            "1000",
            "--listen",
            endpoint,
            "--db",
            os.path.join(folder, "load.sqlite"),
            "--logs",
            os.path.join(folder, "logs"),
        ],
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )


def start_far_ends(
    endpoint: str, folder: str, priority: str, gc_mode: str, conf: str | None = None
) -> list[subprocess.Popen]:
    """The echo and the decision service under test, clients of the router at `endpoint`, at
    `priority` from their first thread on, their collections logged to `folder`/{echo,decision}
    .gc.json and `gc_mode` applied on SIGUSR1; their sessions from the zenoh file `conf` if
    given."""
    echo = [
        sys.executable,
        os.path.join(ROOT, "benchmarks", "echo_node.py"),
        endpoint,
        "bench/ping",
        "bench/pong",
        gc_mode,
        os.path.join(folder, "echo.gc.json"),
        *([conf] if conf else []),
    ]
    decision = [
        sys.executable,
        "-c",
        DECISION,
        gc_mode,
        os.path.join(folder, "decision.gc.json"),
        "decision",
        "--connect",
        endpoint,
        "--rig",
        "bench",
        *(["--config", conf] if conf else []),
    ]
    return [
        subprocess.Popen(
            cmd,
            cwd=ROOT,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            preexec_fn=lambda: set_priority(priority),
        )
        for cmd in (echo, decision)
    ]


def stop(procs: list[subprocess.Popen], group: bool = False) -> None:
    """SIGTERM (the process group with `group`), then SIGKILL after 10 s."""
    for p in procs:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGTERM) if group else p.send_signal(signal.SIGTERM)
    for p in procs:
        try:
            p.wait(10)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL) if group else p.kill()
            p.wait()


Result = tuple[dict[str, np.ndarray], dict[str, int], dict[str, list[tuple[int, int]]]]


def measure(client: zenoh.Session, seconds: float, rate: float, rounds: int = 4) -> Result:
    """Warm-up, then the two legs alternately in `rounds` rounds (this VM's wake-up latency
    wanders by ±20 % over tens of seconds: alternating, drift hurts neither leg)."""
    legs = {
        "echo": Leg(client, "bench/ping", "bench/pong", lambda b: m.decode(m.HandPose, b).seq),
        "decision": Leg(
            client,
            KEYS.topic("vision/hand"),
            KEYS.topic("decision/z_r"),
            lambda b: m.decode(m.Opinions, b).src_seq,
        ),
    }
    n = int(seconds * rate) // rounds
    base = 0
    try:
        for leg in legs.values():  # warm-up: routes, caches, the decision's first steps
            leg.run(base, 60, rate)
            base += 1000
        parts: dict[str, list[np.ndarray]] = {name: [] for name in legs}
        lost = dict.fromkeys(legs, 0)
        tails: dict[str, list[tuple[int, int]]] = {name: [] for name in legs}
        for _ in range(rounds):
            for name, leg in legs.items():
                lat, miss, tail = leg.run(base, n, rate)
                base += n + 1000
                parts[name].append(lat)
                lost[name] += miss
                tails[name] += tail
    finally:
        for leg in legs.values():
            leg.close()
    return {name: np.concatenate(p) for name, p in parts.items()}, lost, tails


def report(lat: dict[str, np.ndarray], lost: dict[str, int], loaded: bool, setting: str) -> int:
    """Print the table and the verdict; 0 when every goal is met."""
    p50 = {k: float(np.percentile(v, 50)) for k, v in lat.items()}
    p99 = {k: float(np.percentile(v, 99)) for k, v in lat.items()}
    for leg in lat:
        print(
            f"{leg:>9}: p50 {p50[leg]:7.1f} µs  p99 {p99[leg]:7.1f} µs  "
            f"n={len(lat[leg])}  lost={lost[leg]}"
        )
    ratio = p50["decision"] / p50["echo"]
    goal = 1.5 if loaded else 1.2
    ok = ratio <= goal and p99["decision"] <= 1000.0 and lost["decision"] == 0
    print(
        f"p50 ratio decision/echo: {ratio:.2f} (goal ≤ {goal}); decision p99 "
        f"{p99['decision'] / 1000:.2f} ms (goal ≤ 1 ms; p99 ratio decision/echo "
        f"{p99['decision'] / p99['echo']:.2f}); lost {lost['decision']}; "
        f"{'loaded' if loaded else 'unloaded'}, {setting}; load average "
        f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}: {'PASS' if ok else 'MISS'}"
    )
    return 0 if ok else 1


def anatomy(
    tails: dict[str, list[tuple[int, int]]],
    pauses: dict[str, list[tuple[int, int]]],
    waits: dict[str, tuple[int, int]],
    steal: int,
    seconds: float,
) -> None:
    """What the samples over `TAIL_US` met: the collections they overlap, per process; each
    process's mean run-queue wait per timeslice over the run; the host's steal time."""
    for leg, spans in tails.items():
        far = "echo" if leg == "echo" else "decision"
        hit = {who: overlapping(spans, pauses.get(who, [])) for who in ("bench", far)}
        both = overlapping(spans, [*pauses.get("bench", []), *pauses.get(far, [])])
        print(
            f"{leg:>9} tail > {TAIL_US / 1000:g} ms: {len(spans)} samples; {both} overlap a "
            f"collection (this process {hit['bench']}, {far} {hit[far]})"
        )
    for who, p in pauses.items():
        if p:
            durs = np.array([d for _, d in p]) / 1e3
            print(
                f"{who:>9} collections: {len(p)}, p50 {np.median(durs):.0f} µs, max "
                f"{durs.max():.0f} µs"
            )
    print(
        "run-queue wait per timeslice: "
        + ", ".join(
            f"{who} {w / n / 1e3:.0f} µs ({n} slices)" for who, (w, n) in waits.items() if n
        )
        + f"; steal {steal * 100 / os.sysconf('SC_CLK_TCK') / seconds:.1f} % of a CPU"
    )


def _wait_file(path: str, timeout: float = 10.0) -> None:
    """Block until `path` exists."""
    deadline = time.monotonic() + timeout
    while not os.path.exists(path):
        if time.monotonic() > deadline:
            raise SystemExit(f"{path} did not appear within {timeout} s")
        time.sleep(0.01)


def _gc_log(path: str) -> list[tuple[int, int]]:
    """A far end's collections as (start ns, duration ns); [] if it wrote none."""
    try:
        with open(path) as f:
            return [(start, dur) for start, dur, _ in json.load(f)]
    except (OSError, ValueError):
        return []


def main() -> int:
    """Run the benchmark; the exit code says whether every goal was met."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--rate", type=float, default=120.0)
    ap.add_argument(
        "--loaded", action="store_true", help="measure inside a running `nod run --sim --render`"
    )
    ap.add_argument(
        "--priority",
        choices=PRIORITIES,
        default="none",
        help="router, echo, decision and this process at nice -10 or SCHED_FIFO",
    )
    ap.add_argument(
        "--gc",
        choices=("default", "freeze", "off"),
        default="default",
        help="gc.freeze() (and gc.disable()) in this process, echo and decision",
    )
    ap.add_argument(
        "--lowlatency",
        action="store_true",
        help="zenoh's low-latency transport in every session (unloaded only: every client of a "
        "router must have it)",
    )
    args = ap.parse_args()
    if args.lowlatency and args.loaded:
        ap.error("--lowlatency: unloaded only (the loading rig's services would not connect)")
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    folder = tempfile.TemporaryDirectory(prefix="nod-latency-")
    pauses, settle = gc_probe(args.gc)
    load = [start_load(endpoint, folder.name)] if args.loaded else []
    set_priority(args.priority)  # after the load, before any session: zenoh's threads inherit
    conf = None
    if args.lowlatency:
        conf = os.path.join(folder.name, "lowlatency.json5")
        with open(conf, "w") as f:
            f.write(LOWLATENCY)
    path = Path(conf) if conf else None
    router = (
        None
        if args.loaded
        else open_session(make_config(mode="router", listen=[endpoint], config_file=path))
    )
    client = None
    procs: list[subprocess.Popen] = []
    try:
        client = (
            open_session(make_config(mode="client", connect=[endpoint], config_file=path))
            if not load
            else _connect(endpoint)
        )
        procs = start_far_ends(endpoint, folder.name, args.priority, args.gc, conf)
        wait_alive(client, "bench/pong/alive")
        wait_alive(client, KEYS.alive("decision"))
        if load:
            wait_trial(client)
            prioritize(load[0].pid, args.priority)  # the router's threads, not the rig's
        settle()
        for p in procs:
            p.send_signal(signal.SIGUSR1)
        for name in ("echo", "decision"):  # their collect and freeze done, before any sample
            _wait_file(os.path.join(folder.name, f"{name}.gc.json.settled"))
        who = {
            "bench": os.getpid(),
            "echo": procs[0].pid,
            "decision": procs[1].pid,
            **({"router": load[0].pid} if load else {}),
        }
        before = {name: run_queue(pid) for name, pid in who.items()}
        steal0, t0 = steal_ticks(), time.perf_counter_ns()
        lat, lost, tails = measure(client, args.seconds, args.rate)
        t1 = time.perf_counter_ns()
        waits = {
            name: tuple(a - b for a, b in zip(run_queue(pid), before[name], strict=True))
            for name, pid in who.items()
        }
        steal = steal_ticks() - steal0
        stop(procs)
        found = {  # the collections during the measurement (the far ends log their lives)
            name: [(start, dur) for start, dur in p if t0 <= start < t1]
            for name, p in (
                ("bench", [(start, dur) for start, dur, _ in pauses]),
                ("echo", _gc_log(os.path.join(folder.name, "echo.gc.json"))),
                ("decision", _gc_log(os.path.join(folder.name, "decision.gc.json"))),
            )
        }
        anatomy(tails, found, waits, steal, (t1 - t0) / 1e9)  # type: ignore[arg-type]
        setting = f"priority {args.priority}, gc {args.gc}" + (", lowlatency" if conf else "")
        return report(lat, lost, args.loaded, setting)
    finally:
        stop(procs)
        if client is not None:
            client.close()
        stop(load, group=True)
        if router is not None:
            router.close()
        folder.cleanup()


def _connect(endpoint: str, timeout: float = 30.0) -> zenoh.Session:
    """A client of the loading run's router, once it listens."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            return open_session(make_config(mode="client", connect=[endpoint]))
        except ConnectionError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.2)


if __name__ == "__main__":
    raise SystemExit(main())
