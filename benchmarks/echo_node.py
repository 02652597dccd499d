"""The latency baseline's far end: a client that republishes every sample it gets, untouched."""

import sys
import threading

import zenoh

from services.core.session import make_config, open_session


def main() -> None:
    endpoint, ping, pong = sys.argv[1:4]
    session = open_session(make_config(mode="client", connect=[endpoint]))
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
