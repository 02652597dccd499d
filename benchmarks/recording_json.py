"""The recorder's cost of JSON channels: encode and write per message, and the file size.

1. Per message of 30 Hz hand poses with 21 landmarks: `messages.encode` (msgpack, what the
   recorder used to keep as it travelled) against `messages.encode_json` (what it keeps now).
2. The recorder's whole step per arrival, `Recorder.add` (validate, encode JSON, write to a
   zstd-chunked MCAP) against the step before JSON channels (validate, write the payload).
3. File size: one minute of a session's traffic (hand poses at 30 Hz; ẑ_h, z_r, b_r per pose;
   the arm's state at 50 Hz) recorded both ways, zstd, without the layouts' attachments.

Interleaved rounds, best of each.

    .venv/bin/python benchmarks/recording_json.py [--rounds 5]
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from services.core import messages as m  # noqa: E402
from services.core.contract import TOPICS  # noqa: E402
from services.core.keys import topic_of  # noqa: E402
from services.recording.mcap_io import McapOut  # noqa: E402
from services.recording.record import Recorder  # noqa: E402

RIG = "nod/rig1/"


def _hand(seq: int, t_ns: int) -> m.HandPose:
    x, y = 0.5 + 0.2 * math.sin(seq / 40), 0.8 - 0.3 * (seq % 90) / 90
    pts = tuple((x + 0.03 * math.cos(k), y + 0.03 * math.sin(k)) for k in range(21))
    return m.HandPose(seq=seq, t_ns=t_ns, detected=True, center=(x, y), landmarks=pts)


def traffic(seconds: float) -> list[tuple[str, bytes, int]]:
    """A session's payloads: (key, msgpack payload, arrival ns), in arrival order."""
    out: list[tuple[int, str, bytes]] = []
    t0 = 1_700_000_000_000_000_000
    for i in range(int(seconds * 30)):
        t = t0 + i * 33_333_333
        out.append((t, RIG + "vision/hand", m.encode(_hand(i, t))))
        z = math.tanh(i / 100)
        out.append((t + 1, RIG + "decision/z_h", m.encode(m.Observed(
            seq=i, t_ns=t, src_seq=i, theta=1.0, distance=0.3, **m.signed_fields(z)))))
        for q in ("z_r", "b_r"):
            out.append((t + 2, RIG + f"decision/{q}", m.encode(m.Opinions(
                seq=i, t_ns=t, src_seq=i, **m.signed_fields(z / 2)))))
    for i in range(int(seconds * 50)):
        t = t0 + i * 20_000_000
        out.append((t, RIG + "actuation/state", m.encode(m.ArmStateMsg(
            seq=i, t_ns=t, ee=(0.5, 0.1 + 0.001 * (i % 300)), phase="move", moving=True))))
    out.sort(key=lambda r: r[0])
    return [(k, p, t) for t, k, p in out]


def _before(out: McapOut, key: str, payload: bytes, log_time: int) -> None:
    """The recorder's step before JSON channels: validate, keep the payload as it travelled."""
    topic = topic_of(key)
    assert topic is not None
    msg = m.decode(TOPICS[topic].message, payload)
    out.write(out.channel(key), log_time, msg.t_ns, payload, msg.seq)


def _best(rounds: int, fns: dict[str, Callable[[], float]]) -> dict[str, float]:
    best = dict.fromkeys(fns, math.inf)
    for _ in range(rounds):
        for name, fn in fns.items():
            best[name] = min(best[name], fn())
    return best


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args()
    poses = [_hand(i, i * 33_333_333) for i in range(3000)]

    def timed(encode: Callable[[m.Message], bytes]) -> Callable[[], float]:
        def run() -> float:
            t = time.perf_counter()
            for p in poses:
                encode(p)
            return (time.perf_counter() - t) / len(poses)
        return run

    enc = _best(args.rounds, {"msgpack": timed(m.encode), "json": timed(m.encode_json)})
    print(f"encode a 21-landmark hand pose: msgpack {enc['msgpack'] * 1e6:.2f} µs, "
          f"JSON {enc['json'] * 1e6:.2f} µs ({enc['json'] / enc['msgpack']:.2f}x)")

    session = traffic(60.0)
    tmp = Path(tempfile.mkdtemp())
    sizes: dict[str, int] = {}

    def record(name: str) -> Callable[[], float]:
        def run() -> float:
            path = tmp / f"{name}.mcap"
            out = McapOut(path)
            rec = Recorder(out)
            t = time.perf_counter()
            for key, payload, log_time in session:
                if name == "json":
                    rec.add(key, payload, log_time)
                else:
                    _before(out, key, payload, log_time)
            out.finish()
            sizes[name] = path.stat().st_size
            return (time.perf_counter() - t) / len(session)
        return run

    step = _best(args.rounds, {"msgpack": record("msgpack"), "json": record("json")})
    print(f"recorder step per message ({len(session)} messages, one minute): payload as it "
          f"travelled {step['msgpack'] * 1e6:.2f} µs, JSON {step['json'] * 1e6:.2f} µs "
          f"({step['json'] / step['msgpack']:.2f}x); at {len(session) / 60:.0f} msg/s JSON "
          f"takes {step['json'] * len(session) / 60 * 100:.2f} % of one core")
    print(f"one minute, zstd: msgpack {sizes['msgpack'] / 1e6:.2f} MB, JSON "
          f"{sizes['json'] / 1e6:.2f} MB ({sizes['json'] / sizes['msgpack']:.2f}x)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
