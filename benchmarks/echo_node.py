"""The latency baseline's far end: a client that republishes every sample it gets, untouched.

    echo_node.py ENDPOINT PING PONG [GC_MODE GC_LOG [ZENOH.json5]]

With GC_MODE and GC_LOG its garbage collections are recorded to GC_LOG and GC_MODE ("default",
"freeze", "off") applies on SIGUSR1 (`rig_probe.gc_probe`); its session starts from the zenoh
file if one is given.
"""

import os
import signal
import sys
import threading
from pathlib import Path

import zenoh

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from benchmarks.rig_probe import gc_probe  # noqa: E402
from services.core.session import make_config, open_session  # noqa: E402


def main() -> None:
    endpoint, ping, pong = sys.argv[1:4]
    if len(sys.argv) > 5:
        gc_probe(sys.argv[4], sys.argv[5])
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))  # the finally below, and atexit
    conf = Path(sys.argv[6]) if len(sys.argv) > 6 else None
    session = open_session(make_config(mode="client", connect=[endpoint], config_file=conf))
    pub = session.declare_publisher(pong, express=True)
    # Echo on zenoh's network thread, as decision handles hand poses: the fastest raw baseline.
    echo = zenoh.handlers.Callback(lambda s: pub.put(s.payload.to_bytes()), indirect=False)
    sub = session.declare_subscriber(ping, echo)
    token = session.liveliness().declare_token(pong + "/alive")
    try:
        threading.Event().wait()  # until SIGTERM ends the process
    finally:
        token.undeclare()
        sub.undeclare()
        session.close()


if __name__ == "__main__":
    main()
