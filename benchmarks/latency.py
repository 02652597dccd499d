"""Hand pose → z_r round trip through a standalone decision process, against a raw Zenoh echo.

Both legs are paced at 120 Hz (a camera's rate, not a ping-pong loop: wake-ups count) through the
same router in this run. Prints p50/p99 of each, the p50 ratio, and lost messages.
Goal: decision p50 ≤ 1.2 × echo p50, decision p99 ≤ 1 ms, nothing lost.

    .venv/bin/python benchmarks/latency.py [--seconds 10] [--rate 120]
"""

from __future__ import annotations

import argparse
import math
import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np

from services.core import messages as m
from services.core.keys import Keys
from services.core.session import make_config, open_session

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)  # the tests' helpers
from tests.processes import free_port  # noqa: E402

KEYS = Keys("bench")


def pose(seq: int, i: int) -> bytes:
    x, y = 0.5 + 0.002 * (i % 100), 0.85 - 0.003 * (i % 100)
    lm = tuple((x + 0.01 * math.cos(k), y + 0.01 * math.sin(k)) for k in range(21))
    return m.encode(
        m.HandPose(
            seq=seq, t_ns=time.time_ns(), detected=True, center=(x, y), landmarks=lm, source="bench"
        )
    )


def paced(session, send_key: str, n: int, rate: float, sent: dict, make) -> None:
    pub = session.declare_publisher(send_key, express=True)
    period = 1.0 / rate
    start = time.perf_counter()
    for i in range(n):
        target = start + i * period
        while (now := time.perf_counter()) < target:
            time.sleep(min(0.001, target - now))
        payload = make(i)
        sent[i] = time.perf_counter_ns()
        pub.put(payload)
    time.sleep(0.3)
    pub.undeclare()


def measure(session, send_key, recv_key, n, rate, make, seq_of) -> tuple[np.ndarray, int]:
    sent: dict[int, int] = {}
    got: dict[int, int] = {}

    def on(sample) -> None:
        t = time.perf_counter_ns()
        seq = seq_of(sample.payload.to_bytes())
        if seq is not None and seq not in got:
            got[seq] = t

    sub = session.declare_subscriber(recv_key, on)
    time.sleep(0.3)
    paced(session, send_key, n, rate, sent, make)
    sub.undeclare()
    lat = np.array([(got[i] - sent[i]) / 1e3 for i in sent if i in got])  # µs
    return lat, len(sent) - len(lat)


def wait_alive(session, key: str, timeout: float = 20.0) -> None:
    ok = threading.Event()
    sub = session.liveliness().declare_subscriber(key, lambda s: ok.set(), history=True)
    if not ok.wait(timeout):
        raise SystemExit(f"no liveliness on {key} after {timeout} s")
    sub.undeclare()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--rate", type=float, default=120.0)
    args = ap.parse_args()
    n = int(args.seconds * args.rate)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = open_session(make_config(mode="router", listen=[endpoint]))
    client = open_session(make_config(mode="client", connect=[endpoint]))
    procs = [
        subprocess.Popen(
            [
                sys.executable,
                os.path.join(ROOT, "benchmarks", "echo_node.py"),
                endpoint,
                "bench/ping",
                "bench/pong",
            ],
            cwd=ROOT,
        ),
        subprocess.Popen(
            [
                sys.executable,
                "-m",
                "services.cli",
                "decision",
                "--connect",
                endpoint,
                "--rig",
                "bench",
            ],
            cwd=ROOT,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        ),
    ]
    try:
        wait_alive(client, "bench/pong/alive")
        wait_alive(client, KEYS.alive("decision"))
        # Warm-up, then the two legs alternately in four rounds, so drift (this VM's wake-up
        # latency wanders by ±20% over tens of seconds) hurts neither.
        results: dict[str, list[np.ndarray]] = {"echo": [], "decision": []}
        lost = {"echo": 0, "decision": 0}

        def echo_seq(b: bytes) -> int | None:
            return m.decode(m.HandPose, b).seq

        def dec_seq(b: bytes) -> int | None:
            return m.decode(m.Scalar, b).src_seq

        seq_base = [0]

        def make_pose(i: int) -> bytes:
            return pose(seq_base[0] + i, i)

        measure(client, "bench/ping", "bench/pong", 60, args.rate, make_pose, echo_seq)
        rounds = 4
        for _ in range(rounds):
            for leg in ("echo", "decision"):
                seq_base[0] += 10 * n + 1000
                base = seq_base[0]
                if leg == "echo":
                    lat, miss = measure(
                        client,
                        "bench/ping",
                        "bench/pong",
                        n // rounds,
                        args.rate,
                        make_pose,
                        lambda b, base=base: echo_seq(b) - base,
                    )
                else:
                    lat, miss = measure(
                        client,
                        KEYS.topic("vision/hand"),
                        KEYS.topic("decision/z_r"),
                        n // rounds,
                        args.rate,
                        make_pose,
                        lambda b, base=base: dec_seq(b) - base,
                    )
                results[leg].append(lat)
                lost[leg] += miss
        stats = {}
        for leg, parts in results.items():
            lat = np.concatenate(parts)
            stats[leg] = (np.percentile(lat, 50), np.percentile(lat, 99), len(lat))
            print(
                f"{leg:>9}: p50 {stats[leg][0]:7.1f} µs  p99 {stats[leg][1]:7.1f} µs  "
                f"n={stats[leg][2]}  lost={lost[leg]}"
            )
        ratio = stats["decision"][0] / stats["echo"][0]
        print(
            f"p50 ratio decision/echo: {ratio:.2f} (goal ≤ 1.2); decision p99 "
            f"{stats['decision'][1] / 1000:.2f} ms (goal ≤ 1 ms); lost {lost['decision']}"
        )
    finally:
        for p in procs:
            p.send_signal(signal.SIGTERM)
        for p in procs:
            p.wait(10)
        client.close()
        router.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
