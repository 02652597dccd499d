"""Can `nod monitor` keep up with a 120 Hz camera without growing memory? Measure it.

Starts a router in this process and `nod monitor --save` as a child, publishes what one rig
publishes per camera frame (hand pose with 21 landmarks, ẑ_h, z_r, b_r) at `--rate` Hz plus arm
and eyes states at 50 Hz for `--seconds`, samples the monitor's RSS every 0.25 s, stops it with
SIGTERM and compares what the .rrd holds with what was sent. Baseline in the same run: the RSS of
the monitor after start-up, before any traffic.

    .venv/bin/python benchmarks/monitor_throughput.py --rate 120 --seconds 10
    .venv/bin/python benchmarks/monitor_throughput.py --rate 1000 --seconds 10   # overload
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
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from services.core import messages as m  # noqa: E402
from services.core.keys import Keys  # noqa: E402
from services.core.session import make_config, open_session  # noqa: E402
from services.monitor.bridge import rrd_rows  # noqa: E402
from tests.processes import free_port  # noqa: E402


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return math.nan


def cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rate", type=float, default=120.0, help="hand poses per second")
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--extra", nargs=argparse.REMAINDER, default=[], help="more monitor flags")
    args = ap.parse_args()
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    tmp = Path(tempfile.mkdtemp(prefix="monbench-"))
    rrd = tmp / "bench.rrd"
    router = open_session(make_config(mode="router", listen=[endpoint]))
    client = open_session(make_config(mode="client", connect=[endpoint]))
    keys = Keys("rig1")
    log = (tmp / "monitor.log").open("w")
    proc = subprocess.Popen(
        [sys.executable, "-m", "services.cli", "monitor", "--connect", endpoint]
        + ["--save", str(rrd), *args.extra],
        cwd=ROOT,
        stdout=log,
        stderr=subprocess.STDOUT,
    )
    try:
        while not any(r.ok for r in client.liveliness().get(keys.alive("monitor"), timeout=0.5)):
            time.sleep(0.1)
        time.sleep(0.5)
        baseline = rss_mb(proc.pid)
        cpu0 = cpu_s(proc.pid)
        topics = ("vision/hand", "decision/z_h", "decision/z_r", "decision/b_r")
        topics += ("actuation/state", "eyes/state")
        pubs = {t: client.declare_publisher(keys.topic(t)) for t in topics}
        sent = dict.fromkeys(topics, 0)
        samples: list[float] = []
        period = 1.0 / args.rate
        n = int(args.rate * args.seconds)
        start = time.monotonic()
        next_rss = start
        for i in range(n):
            t_ns = time.time_ns()
            x = 0.3 + 0.4 * (i % 600) / 600
            lm = tuple((x + 0.002 * k, 0.7 + 0.001 * k) for k in range(21))
            hand = m.HandPose(
                seq=i, t_ns=t_ns, detected=True, center=(x + 0.02, 0.71), landmarks=lm
            )
            pubs["vision/hand"].put(m.encode(hand))
            sent["vision/hand"] += 1
            for t, v in (("decision/z_h", x), ("decision/z_r", -x), ("decision/b_r", 0.1)):
                cls = m.Observed if t == "decision/z_h" else m.Opinions
                pubs[t].put(m.encode(cls(seq=i, t_ns=t_ns, src_seq=i, **m.signed_fields(v))))
                sent[t] += 1
            if i % max(1, round(args.rate / 50)) == 0:
                arm = m.ArmStateMsg(seq=i, t_ns=t_ns, ee=(x, 0.1), phase="move", moving=True)
                eyes = m.EyesStateMsg(seq=i, t_ns=t_ns, angles_deg=(90 + x, 90, 90 + x, 90))
                pubs["actuation/state"].put(m.encode(arm))
                pubs["eyes/state"].put(m.encode(eyes))
                sent["actuation/state"] += 1
                sent["eyes/state"] += 1
            now = time.monotonic()
            if now >= next_rss:
                samples.append(rss_mb(proc.pid))
                next_rss = now + 0.25
            delay = start + (i + 1) * period - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        elapsed = time.monotonic() - start
        time.sleep(0.5)
        samples.append(rss_mb(proc.pid))
        cpu = (cpu_s(proc.pid) - cpu0) / (elapsed + 0.5)
        t_stop = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(60)
        stop_s = time.monotonic() - t_stop
    finally:
        if proc.poll() is None:
            proc.kill()
        client.close()
        router.close()
    rows, _ = rrd_rows(rrd)
    paths = {
        "vision/hand": "/table/hand",
        "decision/z_h": "/opinion/z_h",
        "decision/z_r": "/opinion/z_r",
        "decision/b_r": "/opinion/b_r",
        "actuation/state": "/table/arm",  # + 1 row: the arm's colour, logged on change
        "eyes/state": "/eyes/servos",
    }
    tail = [ln for ln in (tmp / "monitor.log").read_text().splitlines() if "monitor" in ln]
    report = {
        "rate_hz": args.rate,
        "achieved_hand_hz": round(sent["vision/hand"] / elapsed, 1),
        "seconds": round(elapsed, 2),
        "messages_per_s": round(sum(sent.values()) / elapsed),
        "monitor_cpu_percent": round(100 * cpu),
        "rss_baseline_mb": round(baseline, 1),
        "rss_max_mb": round(max(samples), 1),
        "rss_every_10s_mb": [round(x, 1) for x in samples[::40]] + [round(samples[-1], 1)],
        "sent": sent,
        "in_rrd": {t: rows.get(p, 0) for t, p in paths.items()},
        "rrd_mb": round(rrd.stat().st_size / 2**20, 2),
        "exit_code": code,
        "sigterm_to_exit_s": round(stop_s, 2),
        "monitor_log_tail": tail[-2:],
    }
    print(json.dumps(report, indent=2))
    os.remove(rrd)
    return 0 if code == 0 else 1


if __name__ == "__main__":
    raise SystemExit(main())
