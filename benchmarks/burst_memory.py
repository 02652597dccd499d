"""Does a burst of large messages leave the router and a service larger for good? Measure it.

Two setups in the same run, each with a router process and a subscribing service process on a
free loopback port, and the same bursts from `--senders` processes with zenoh's default config
(as any program on the host has): for each size (60 kB, 200 kB), every sender puts up to
`--count` messages round the keys the service subscribes to (at most `--seconds`).

- **Baseline**: the rig's session config before bounded intake (multicast off, 1 MiB messages:
  `benchmarks/burst_node.py`), a subscriber dropping oversized payloads in its callback as
  `Node.subscribe` did.
- **Candidate**: `nod router` and `nod eyes --driver sim` (or `--service`) as they run now.

RSS (VmRSS) is read at baseline (after start-up), at its peak during the bursts, and after: polled
until within 20 MB of the baseline or `--settle` seconds. Exit 1 when the candidate misses it.

    .venv/bin/python benchmarks/burst_memory.py [--senders 4] [--count 3000] [--seconds 3]
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from services.core.contract import TOPICS  # noqa: E402
from services.core.keys import Keys  # noqa: E402
from services.core.session import make_config, open_session  # noqa: E402

KEYS = Keys("rig1")
NODE = str(ROOT / "benchmarks" / "burst_node.py")
BOUND_MB = 20.0


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return math.nan


def free_endpoint() -> str:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def start(cmd: list[str], log: Path) -> subprocess.Popen:
    return subprocess.Popen(
        cmd, cwd=ROOT, stdout=log.open("w"), stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL
    )


def wait_alive(endpoint: str, token: str, procs: list[subprocess.Popen], timeout: float) -> None:
    """Poll the router until the subscriber's liveliness token shows (processes still alive)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if any(p.poll() is not None for p in procs):
            raise RuntimeError("a process of the setup exited during start-up")
        try:
            session = open_session(make_config(mode="client", connect=[endpoint]))
        except ConnectionError:
            time.sleep(0.1)
            continue
        try:
            while time.monotonic() < deadline:
                if any(r.ok for r in session.liveliness().get(KEYS.alive(token), timeout=0.5)):
                    return
                time.sleep(0.1)
        finally:
            session.close()
    raise RuntimeError(f"{token} not alive after {timeout} s")


def run_setup(name: str, service: str, args: argparse.Namespace, tmp: Path) -> dict:
    endpoint = free_endpoint()
    keys = [KEYS.topic(t) for t, spec in TOPICS.items() if service in spec.subscribers]
    py = sys.executable
    if name == "baseline":
        router = start([py, NODE, "router", endpoint], tmp / f"{name}-router.log")
        time.sleep(0.2)
        sub = start([py, NODE, "sub", endpoint, *keys], tmp / f"{name}-sub.log")
        token = "baseline"
    else:
        router = start([py, "-m", "services.cli", "router", "--listen", endpoint],
                       tmp / f"{name}-router.log")
        sub = start([py, "-m", "services.cli", service, "--connect", endpoint,
                     *(["--driver", "sim"] if service in ("eyes", "actuation") else [])],
                    tmp / f"{name}-{service}.log")
        token = service
    procs = {"router": router, "service": sub}
    try:
        wait_alive(endpoint, token, list(procs.values()), 30)
        time.sleep(1.0)  # start-up settles (imports, first states)
        base = {k: rss_mb(p.pid) for k, p in procs.items()}
        peak = dict(base)
        sent = {}
        for size in args.sizes:
            blasters = [
                subprocess.Popen(
                    [py, NODE, "blast", endpoint, str(size), str(args.seconds), str(args.count),
                     *keys],
                    cwd=ROOT, stdout=subprocess.PIPE, text=True,
                )
                for _ in range(args.senders)
            ]
            while any(b.poll() is None for b in blasters):
                peak = {k: max(peak[k], rss_mb(p.pid)) for k, p in procs.items()}
                time.sleep(0.1)
            sent[size] = sum(int(b.stdout.read().strip() or 0) for b in blasters)
        deadline = time.monotonic() + args.settle
        after = {k: rss_mb(p.pid) for k, p in procs.items()}
        while time.monotonic() < deadline and max(after[k] - base[k] for k in after) > BOUND_MB:
            time.sleep(0.2)
            after = {k: rss_mb(p.pid) for k, p in procs.items()}
        alive = all(p.poll() is None for p in procs.values())
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        for p in procs.values():
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                p.kill()
    return {
        "setup": name,
        "service": service if name != "baseline" else "baseline subscriber",
        "sent": {f"{size // 1000} kB": n for size, n in sent.items()},
        "rss_baseline_mb": {k: round(v, 1) for k, v in base.items()},
        "rss_peak_mb": {k: round(v, 1) for k, v in peak.items()},
        "rss_after_mb": {k: round(v, 1) for k, v in after.items()},
        "growth_mb": {k: round(after[k] - base[k], 1) for k in base},
        "alive_after": alive,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--service", default="eyes", help="the subscribing service (default eyes)")
    ap.add_argument("--senders", type=int, default=4, help="sender processes per burst")
    ap.add_argument("--count", type=int, default=3000, help="messages per sender per size")
    ap.add_argument("--seconds", type=float, default=3.0, help="at most this long per burst")
    ap.add_argument("--settle", type=float, default=10.0, help="seconds to wait for RSS after")
    ap.add_argument("--sizes", type=int, nargs="+", default=[60_000, 200_000])
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="burstbench-"))
    results = [run_setup(name, args.service, args, tmp) for name in ("baseline", "candidate")]
    base, cand = results
    for r in results:
        print(json.dumps(r))
    print(f"{'':24}{'router':>10}{args.service:>10}")
    for label, r in (("baseline growth (MB)", base), ("candidate growth (MB)", cand)):
        g = r["growth_mb"]
        print(f"{label:24}{g['router']:>10.1f}{g['service']:>10.1f}")
    ok = cand["alive_after"] and max(cand["growth_mb"].values()) <= BOUND_MB
    print(f"goal: candidate growth <= {BOUND_MB:.0f} MB in both, both alive -> "
          f"{'met' if ok else 'MISSED'} (logs in {tmp})")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
