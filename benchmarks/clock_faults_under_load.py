"""Delay is not a clock fault: a simulated study on the emulated Feetech bus under two CPU burners.

`nod run --sim` with the arm's real Feetech driver over a pty (the bus emulator in a process of
its own, as in tests/integration/test_device_faults.py), the rig's default safety bounds
(stale 250 ms, skew 100 ms), while two processes burn a core each. Counts what the store and
the devices' logs say: trials stored interrupted, interruptions whose reason is a clock fault,
and the clock faults the actuation service logged. Before the sender's clock was judged from
its least-delayed message (docs/safety.md §11.6), a delay of 100–177 ms read as a clock fault
and trials used up their attempts (2 of 12 in one bus-fault run).

    .venv/bin/python benchmarks/clock_faults_under_load.py [--participants 5] [--speed 2]
        [--burners 2] [--tree DIR]

Goal: no trial lost to clock faults (exit 1 otherwise). `--tree DIR` runs another checkout's
services (an older commit, to see the before).
"""

from __future__ import annotations

import argparse
import multiprocessing
import re
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from services.actuation.calibrate import config_toml  # noqa: E402
from services.actuation.feetech_arm import FeetechArmConfig  # noqa: E402
from services.store import Store  # noqa: E402
from tests.emulators.feetech_emulator import IDS, POSES  # noqa: E402
from tests.emulators.links import RIG  # noqa: E402
from tests.emulators.own_process import DeviceProcess  # noqa: E402


def burn(stop_at: float) -> None:
    """Keep one core busy until `stop_at` (monotonic)."""
    x = 0
    while time.monotonic() < stop_at:
        x = (x * 31 + 7) % 1_000_003


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--participants", type=int, default=5)
    p.add_argument("--speed", type=float, default=2.0)
    p.add_argument("--burners", type=int, default=2)
    p.add_argument("--tree", type=Path, default=ROOT)
    args = p.parse_args(argv)
    tmp = Path(tempfile.mkdtemp(prefix="nod-clock-"))
    arm_file = tmp / "arm.toml"
    arm_file.write_text(config_toml(FeetechArmConfig(ids=IDS, poses=POSES, link=RIG)))
    db, logs = tmp / "s.sqlite", tmp / "logs"
    burners = [multiprocessing.Process(target=burn, args=(time.monotonic() + 3600,), daemon=True)
               for _ in range(args.burners)]
    for b in burners:
        b.start()
    t0 = time.monotonic()
    try:
        with DeviceProcess("feetech", tmp) as bus:
            run = subprocess.run(
                [sys.executable, "-m", "services.cli", "run", "--sim", "--speed",
                 str(args.speed), "--participants", str(args.participants), "--db", str(db),
                 "--listen", f"tcp/127.0.0.1:{free_port()}", "--logs", str(logs),
                 "--arm-driver", "feetech", "--arm-port", bus.port, "--arm-config",
                 str(arm_file)],
                cwd=args.tree, capture_output=True, text=True, timeout=3600, check=False,
            )
    finally:
        for b in burners:
            b.terminate()
    seconds = time.monotonic() - t0
    store = Store(db)
    try:
        sessions = [s["session"] for s in store.sessions()]
        trials = [t for s in sessions for _, t in store.trials(s)]
        breaks = [i for s in sessions for i in store.interruptions(s)]
    finally:
        store.close()
    clock_breaks = [i for i in breaks if "clock fault" in i.reason]
    lost = [t for t in trials if t.interrupted]
    logged = sum(len(re.findall(r"clock fault #", f.read_text(errors="replace")))
                 for f in logs.rglob("actuation*.log"))
    print(f"services of {args.tree}; {args.participants} participants at {args.speed}x under "
          f"{args.burners} CPU burners, {seconds:.0f} s (nod run exit {run.returncode})")
    print(f"  trials stored: {len(trials)}; stored interrupted (lost): {len(lost)}")
    print(f"  interruptions: {len(breaks)}, of them clock faults: {len(clock_breaks)}")
    print(f"  clock faults logged by actuation: {logged}")
    for i in breaks[:10]:
        print(f"    trial {i.trial} attempt {i.attempt}: {i.reason[:120]}")
    ok = run.returncode == 0 and not clock_breaks and not [
        t for t in lost if "clock fault" in t.end_reason]
    print(f"goal, no trial lost to clock faults: {'met' if ok else 'MISSED'}")
    if run.returncode != 0:
        print(run.stdout[-2000:], run.stderr[-2000:])
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
