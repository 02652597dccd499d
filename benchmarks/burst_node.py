"""The burst benchmark's other processes: the baseline's router and subscriber, and the senders.

    burst_node.py router ENDPOINT             the rig's session config before bounded intake
    burst_node.py sub ENDPOINT KEY...         (multicast off, 1 MiB messages; nothing else)
    burst_node.py blast ENDPOINT SIZE SECONDS COUNT KEY...   zenoh's defaults, as any process

The baseline subscriber checks each payload's size on zenoh's thread and drops it, as
`Node.subscribe` did; it holds the liveliness token `nod/<rig>/alive/baseline`.
"""

from __future__ import annotations

import json
import sys
import threading
import time

import zenoh


def config(mode: str, endpoint: str, *, before: bool) -> zenoh.Config:
    """zenoh's defaults, with the endpoint; `before`: the rig's old additions on top."""
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(mode))
    side = "listen/endpoints" if mode == "router" else "connect/endpoints"
    conf.insert_json5(side, json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    if before:
        conf.insert_json5("transport/link/rx/max_message_size", str(1 << 20))
    return conf


def serve(mode: str, endpoint: str, keys: list[str]) -> None:
    """Run a baseline router or subscriber until killed."""
    session = zenoh.open(config(mode, endpoint, before=True))
    dropped = [0]

    def on_sample(sample: zenoh.Sample) -> None:
        if len(sample.payload) > 64 * 1024:
            dropped[0] += 1

    subs = [
        session.declare_subscriber(k, zenoh.handlers.Callback(on_sample, indirect=False))
        for k in keys
    ]
    token = None
    if mode == "client":
        rig = keys[0].split("/")[1]
        token = session.liveliness().declare_token(f"nod/{rig}/alive/baseline")
    try:
        threading.Event().wait()  # until SIGTERM ends the process
    finally:
        del subs, token
        session.close()


def blast(endpoint: str, size: int, seconds: float, count: int, keys: list[str]) -> None:
    """Put `count` payloads of `size` bytes round the keys (at most `seconds`); print how many."""
    session = zenoh.open(config("client", endpoint, before=False))
    pubs = [
        session.declare_publisher(k, congestion_control=zenoh.CongestionControl.BLOCK)
        for k in keys
    ]
    time.sleep(0.3)  # the router learns of the publishers' keys' subscribers
    payload = b"\x00" * size
    start, n = time.monotonic(), 0
    while n < count and time.monotonic() - start < seconds:
        pubs[n % len(pubs)].put(payload)
        n += 1
    print(n, flush=True)
    session.close()


def main() -> None:
    what, endpoint, *rest = sys.argv[1:]
    if what == "blast":
        size, seconds, count, *keys = rest
        blast(endpoint, int(size), float(seconds), int(count), keys)
    else:
        serve("router" if what == "router" else "client", endpoint, rest)


if __name__ == "__main__":
    main()
