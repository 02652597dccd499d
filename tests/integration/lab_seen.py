"""What a lab's session receives from a rig, for the tests of rig isolation on secured routers."""

from __future__ import annotations

import time

import zenoh


class Seen:
    """Every sample and liveliness token a session receives from a rig (`*`: every rig)."""

    def __init__(self, session: zenoh.Session, rig: str = "*") -> None:
        self.puts: list[tuple[str, bytes]] = []
        self.alive: set[str] = set()
        self._subs = [
            session.declare_subscriber(f"nod/{rig}/**", self._on),
            session.liveliness().declare_subscriber(f"nod/{rig}/alive/*", self._on_alive,
                                                    history=True),
        ]

    def _on(self, sample: zenoh.Sample) -> None:
        self.puts.append((str(sample.key_expr), sample.payload.to_bytes()))

    def _on_alive(self, sample: zenoh.Sample) -> None:
        if sample.kind == zenoh.SampleKind.PUT:
            self.alive.add(str(sample.key_expr))

    def has(self, key: str, payload: bytes | None = None) -> bool:
        return any(k == key and payload in (None, p) for k, p in self.puts)


def put_until_seen(sender: zenoh.Session, seen: Seen, key: str, payload: bytes) -> None:
    """Put an allowed key until the observer has it (every route to it is up)."""
    deadline = time.monotonic() + 15
    while not seen.has(key, payload):
        assert time.monotonic() < deadline, f"timed out waiting for {key}"
        sender.put(key, payload)
        time.sleep(0.02)
