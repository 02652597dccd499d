"""A flood of valid, size-legal messages on the devices' input keys, from a process of its own.

What a stuck publisher, a replay at full speed or a hostile host on the rig's network sends:
every message decodes and passes validation, so each one reaches the device's handler (the
worst case: a malformed one is dropped before). Used by `benchmarks/estop_flood.py` and
`tests/integration/test_estop_flood.py`.

    .venv/bin/python benchmarks/flood.py --connect tcp/127.0.0.1:7447 [--keys z_r,hand,gaze]
        [--seconds 30] [--rig rig1]

Runs until `--seconds` pass or SIGTERM; prints the number of messages sent per key at the end.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from pathlib import Path

import zenoh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from services.core import messages as m  # noqa: E402
from services.core.keys import Keys  # noqa: E402
from services.core.session import make_config, open_session  # noqa: E402

TOPICS = {"z_r": "decision/z_r", "hand": "vision/hand", "gaze": "eyes/cmd"}


def payload(name: str, seq: int) -> bytes:
    """One valid message of the key `name`, stamped now (fresh by every device's rule)."""
    t = time.time_ns()
    if name == "z_r":
        z = 0.1 * ((seq % 21) - 10)
        return m.encode(m.Opinions(seq=seq, t_ns=t, src_seq=seq, **m.signed_fields(z)))
    if name == "hand":
        points = tuple((0.5 + 0.001 * (i % 7), 0.6 + 0.001 * (i % 5)) for i in range(21))
        return m.encode(m.HandPose(seq=seq, t_ns=t, detected=True, center=(0.502, 0.601),
                                   landmarks=points, source="flood"))
    return m.encode(m.GazeMsg(seq=seq, t_ns=t, yaw=0.2, level="low", trial=1))


def main(argv: list[str] | None = None) -> int:
    """Flood until the time is up or a signal arrives."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--connect", required=True)
    p.add_argument("--keys", default="z_r,hand,gaze")
    p.add_argument("--seconds", type=float, default=30.0)
    p.add_argument("--rig", default="rig1")
    args = p.parse_args(argv)
    names = [k for k in args.keys.split(",") if k]
    keys = Keys(args.rig)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    session = open_session(make_config(mode="client", connect=[args.connect]))
    sent = dict.fromkeys(names, 0)

    def flood(name: str) -> None:
        # Blocking congestion control: the flood fills every queue on its way, as a publisher
        # of a reliable key would; batching on, for the most messages per second.
        pub = session.declare_publisher(keys.topic(TOPICS[name]),
                                        congestion_control=zenoh.CongestionControl.BLOCK)
        seq = 0
        while not stop.is_set():
            for _ in range(200):
                pub.put(payload(name, seq))
                seq += 1
            sent[name] = seq

    threads = [threading.Thread(target=flood, args=(n,), daemon=True) for n in names]
    for t in threads:
        t.start()
    stop.wait(args.seconds)
    stop.set()
    for t in threads:
        t.join(5)
    print(" ".join(f"{n}={c}" for n, c in sent.items()), flush=True)
    session.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
