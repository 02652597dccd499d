"""The thin runtime every service shell shares: session, liveliness, typed pub/sub, ticks.

A `Node` owns one Zenoh session and one lock. Every subscriber callback and every periodic tick
runs under that lock, so a service's logic is single-threaded without a queue hop on the hot path
(zenoh delivers samples on its own threads). Bad payloads are decoded, counted, logged in one line
and dropped; the service keeps running.
"""

from __future__ import annotations

import json
import logging
import os
import socket
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any, TypeVar

import zenoh

from services.core import messages as m
from services.core.clock import Clock
from services.core.contract import EVERY_SERVICE, QoS, check_publisher, check_subscriber
from services.core.keys import Keys
from services.core.limits import max_payload_bytes
from services.core.session import Fabric, open_session, open_session_retrying
from services.core.signals import on_stop_signal
from services.model.safety import Watchdog

M = TypeVar("M", bound=m.Message)
log = logging.getLogger(__name__)
_PRIORITY = {
    "real_time": zenoh.Priority.REAL_TIME,
    "interactive_high": zenoh.Priority.INTERACTIVE_HIGH,
    "data_high": zenoh.Priority.DATA_HIGH,
    "data": zenoh.Priority.DATA,
}


def declare_publisher(session: zenoh.Session, key: str, qos: QoS) -> zenoh.Publisher:
    """A zenoh publisher with a topic's QoS from the contract (every publisher goes here)."""
    return session.declare_publisher(
        key,
        express=qos.express,
        congestion_control=zenoh.CongestionControl.BLOCK
        if qos.congestion == "block"
        else zenoh.CongestionControl.DROP,
        priority=_PRIORITY[qos.priority],
    )


class TopicPublisher:
    """Publishes one topic's messages with a running `seq` and the node clock's `t_ns`."""

    def __init__(self, node: Node, topic: str) -> None:
        spec = check_publisher(topic, node.service)
        self.topic = topic
        self.key = node.keys.topic(topic)
        self.cls = spec.message
        self._clock = node.clock
        self._pub = declare_publisher(node.session, self.key, spec.qos)
        self.seq = 0

    def matched(self) -> bool:
        """Whether some subscriber of the topic is reachable now (zenoh's matching status)."""
        status = self._pub.matching_status  # a MatchingStatus at run time
        return bool(status.matching)  # type: ignore[attr-defined]  # zenoh's stub says bool

    def put(self, t_ns: int | None = None, **fields: Any) -> m.Message:
        """Build, validate, encode and publish one message; return it."""
        msg = self.cls(seq=self.seq, t_ns=self._clock.now_ns() if t_ns is None else t_ns, **fields)
        self.seq += 1
        self._pub.put(m.encode(msg))
        return msg


class Node:
    """One service process on the Zenoh fabric."""

    def __init__(
        self,
        service: str,
        fabric: Fabric,
        *,
        stands_in_for: tuple[str, ...] = (),
        retry_s: float | None = None,
        params_hash: str | None = None,
    ) -> None:
        """Open the session; with `retry_s`, wait up to that long for a router (inf: forever).

        Services retry (a rig's hosts start in any order, and a router may restart); one-shot
        tools fail at once. SIGINT/SIGTERM end the wait. `params_hash` (of the parameters the
        service runs, `services.core.config.params_hash`) goes out with every heartbeat.
        """
        self.service = service
        self.params_hash = params_hash
        self.fabric = fabric
        self.keys = Keys(fabric.rig)
        self.clock: Clock = fabric.clock()
        self.lock = threading.RLock()
        self.stop = threading.Event()
        self._exit_hooks: list[Callable[[], object]] = []
        install_signal_handlers(self.stop, self._exit_hooks)
        self.session = open_session_retrying(fabric, self.stop, service, retry_s)
        self.bad: Counter[str] = Counter()
        self.received: Counter[str] = Counter()
        self._handles: list[Any] = []
        self._urgent_session: zenoh.Session | None = None  # the safety path's own link
        self._urgent_waiting = threading.Condition(threading.Lock())
        self._urgent_count = 0  # safety handlers waiting for (or holding) the lock
        self._ticks: list[tuple[float, Callable[[int], None], list[float]]] = []
        # Liveliness is declared by `ready()`, after the service has declared its subscriptions:
        # a peer that waits for our token (the conductor does) must not talk to us before we
        # listen. A simulator standing in for another service also holds that service's token,
        # so watchdogs that require e.g. "vision" accept the sim without special cases.
        self._alive_as = (service, *stands_in_for)
        self._tokens: list[Any] = []
        self.started_ns = time.time_ns()
        # The launcher (`nod up`, `nod run`) tells a restarted service how often it restarted it.
        self.restarts = _env_int("NOD_RESTARTS")
        self._heartbeat: threading.Thread | None = None
        # What the service is doing, sent with every heartbeat (set under `lock`; the
        # conductor's session, participant and trial, for `nod lab status`).
        self.activity: dict[str, Any] = {}
        log.info("%s up on rig %r (clock speed %.3g)", service, self.keys.rig, self.clock.speed)

    # -- pub/sub -------------------------------------------------------------------------------

    def publisher(self, topic: str) -> TopicPublisher:
        """A publisher for one topic of this rig."""
        return TopicPublisher(self, topic)

    def subscribe_urgent(self, topic: str, handler: Callable[[Any], None]) -> None:
        """`subscribe` for the safety path (the e-stop): on a session of its own, ahead of data.

        A flood on a data key fills the one link a session has to its router: an e-stop sent
        after it waited behind thousands of queued samples (3.5 s under a z_r flood). Its own
        session is its own link and its own receiving thread; and while its handler waits for
        the node's lock, data handlers wait for it (at most the one running finishes first).
        """
        self._declare_subscriber(self._urgent_link(), topic, handler, urgent=True)

    def subscribe(self, topic: str, handler: Callable[[Any], None]) -> None:
        """Decode every sample of `topic` strictly and pass good ones to `handler` (locked).

        The handler runs on zenoh's network thread, as the sample arrives: no queue between the
        network and the check (zenoh's own hand-off queue is unbounded, and a burst of hostile
        samples held there grew a service by tens of MB), one thread wake-up less per message.
        So handlers must be short — every one in this project is; I/O lives on its own threads.
        The size limit is the topic's (`services.core.limits`), which the session's low-pass
        filter already applies: this check only sees what a peer's or router's config let by.
        """
        self._declare_subscriber(self.session, topic, handler, urgent=False)

    def _declare_subscriber(
        self, session: zenoh.Session, topic: str, handler: Callable[[Any], None], *, urgent: bool
    ) -> None:
        key = self.keys.topic(topic)
        cls: type[m.Message] = check_subscriber(topic, self.service).message
        limit = max_payload_bytes(cls)

        def on_sample(sample: zenoh.Sample) -> None:
            # A data handler stands aside while a safety handler waits (unlocked reads: at worst
            # one more data handler goes first). Python's lock is not fair: a flood's thread,
            # releasing it and asking again sample after sample, mostly won it back, and the
            # e-stop waited behind. Checked before the decode (the CPU to the e-stop first) and
            # again before the lock (an e-stop that came during the decode).
            if not urgent and self._urgent_count:
                self._stand_aside()
            size = len(sample.payload)
            if size > limit:  # before copying it out of zenoh's buffer
                self._drop(topic, f"payload of {size} bytes exceeds the limit {limit}")
                return
            try:
                msg = m.decode(cls, sample.payload.to_bytes())
            except m.MessageError as exc:
                self._drop(topic, str(exc))
                return
            if not urgent and self._urgent_count:
                self._stand_aside()
            with self._urgent_lock() if urgent else self.lock:
                self.received[topic] += 1
                try:
                    handler(msg)
                except ValueError as exc:  # a valid message the model cannot use (bad geometry)
                    self._drop(topic, f"refused: {exc}")
                except Exception:  # a handler bug must not kill zenoh's delivery thread
                    log.exception("%s: handler for %s failed", self.service, topic)

        callback = zenoh.handlers.Callback(on_sample, indirect=False)
        self._handles.append(session.declare_subscriber(key, callback))

    @contextmanager
    def _urgent_lock(self) -> Iterator[None]:
        """The node's lock for a safety handler: data handlers stand aside while it waits."""
        with self._urgent_waiting:
            self._urgent_count += 1
        try:
            with self.lock:
                yield
        finally:
            with self._urgent_waiting:
                self._urgent_count -= 1
                self._urgent_waiting.notify_all()

    def _stand_aside(self) -> None:
        """Wait (without the interpreter lock) until no safety handler waits or runs."""
        with self._urgent_waiting:
            while self._urgent_count:
                self._urgent_waiting.wait()

    def _urgent_link(self) -> zenoh.Session:
        """The session of the safety path: a second link to the same router (opened once).

        Without an endpoint to connect it to (a router, or a peer that only listens) it would
        reach nobody: the safety path then shares the data session, and says so.
        """
        if self._urgent_session is None:
            conf = self.fabric.zenoh_config()
            connect = json.loads(conf.get_json("connect/endpoints") or "[]")
            if self.fabric.mode == "router" or not connect:
                log.info("%s: the e-stop shares the data session (no endpoint for a second "
                         "link)", self.service)
                self._urgent_session = self.session
            else:
                # Listening is the data session's job (a second bind of its port would fail).
                conf.insert_json5("listen/endpoints", "[]")
                self._urgent_session = open_session(conf)
        return self._urgent_session

    def answer(self, topic: str, reply: Callable[[], m.Message]) -> None:
        """Answer every query on `topic` with `reply()`, built under the lock (a publisher's right).

        For state a peer asks for when it starts (the e-stop latch): a query needs no history.
        """
        check_publisher(topic, self.service)
        key = self.keys.topic(topic)

        def on_query(query: zenoh.Query) -> None:
            try:
                with self.lock:
                    payload = m.encode(reply())
                query.reply(key, payload)
            except Exception:  # an answer that fails must not kill zenoh's delivery thread
                log.exception("%s: answering a query on %s failed", self.service, topic)

        self._handles.append(self.session.declare_queryable(key, on_query))

    def ask(self, topic: str, timeout_s: float) -> list[Any]:
        """Query every answerer of `topic` (a declared subscriber); the valid replies.

        Blocks up to `timeout_s` (wall): zenoh ends the query early once every answerer it knows
        of has replied. Bad replies are dropped like bad samples.
        """
        cls: type[m.Message] = check_subscriber(topic, self.service).message
        replies = self.session.get(
            self.keys.topic(topic),
            target=zenoh.QueryTarget.ALL,
            consolidation=zenoh.ConsolidationMode.NONE,
            timeout=timeout_s,
        )
        out: list[Any] = []
        for reply in replies:
            if reply.ok is None:
                continue
            try:
                out.append(m.decode(cls, reply.ok.payload.to_bytes()))
            except m.MessageError as exc:
                self._drop(topic, str(exc))
        return out

    def _drop(self, topic: str, why: str) -> None:
        self.bad[topic] += 1
        n = self.bad[topic]
        if n <= 10 or n % 1000 == 0:  # one line each, but never a log flood from a bad peer
            log.warning(
                "%s: dropped bad message #%d on %s: %s", self.service, n, topic, clip(why)
            )

    def watch_liveliness(self, service: str, on_change: Callable[[bool], None]) -> None:
        """Call `on_change(alive)` (locked) when `service`'s liveliness token appears or goes."""

        def on_sample(sample: zenoh.Sample) -> None:
            alive = sample.kind == zenoh.SampleKind.PUT
            with self.lock:
                on_change(alive)

        sub = self.session.liveliness().declare_subscriber(
            self.keys.alive(service), on_sample, history=True
        )
        self._handles.append(sub)

    def other_rigs(self, timeout_s: float = 0.3) -> str:
        """The other rigs whose services are alive on this router, e.g. "rig1 (decision, eyes)"."""
        found: dict[str, set[str]] = {}
        for reply in self.session.liveliness().get("nod/*/alive/*", timeout=timeout_s):
            if reply.ok is None:
                continue
            parts = str(reply.ok.key_expr).split("/")
            if len(parts) == 4 and parts[1] != self.keys.rig:
                found.setdefault(parts[1], set()).add(parts[3])
        return "; ".join(f"{rig} ({', '.join(sorted(s))})" for rig, s in sorted(found.items()))

    def peer_alive(self, service: str, timeout_s: float = 0.3) -> bool:
        """Whether some process holds `service`'s liveliness token on this rig right now."""
        replies = self.session.liveliness().get(self.keys.alive(service), timeout=timeout_s)
        return any(r.ok is not None for r in replies)

    def on_forced_exit(self, hook: Callable[[], object]) -> None:
        """Run `hook` (e.g. hold the arm) if a signal's clean stop does not finish in time."""
        self._exit_hooks.append(hook)

    # -- time ----------------------------------------------------------------------------------

    @staticmethod
    def arrival_ns() -> int:
        """Now on this host's monotonic clock: what a watchdog judges freshness by."""
        return time.monotonic_ns()

    def offset_ns(self, t_ns: int) -> float:
        """A source timestamp minus the rig clock now, in wall ns (skew, or delay if negative)."""
        return (t_ns - self.clock.now_ns()) / self.clock.speed

    def feed_watchdog(self, watchdog: Watchdog, name: str, t_ns: int) -> bool:
        """Feed a watchdog with a message that arrived now; False if its stamp was refused."""
        offset = self.offset_ns(t_ns)
        if watchdog.feed(name, self.arrival_ns(), offset):
            return True
        n = watchdog.clock_faults
        if n <= 10 or n % 100 == 0:  # one line each, never a flood
            log.warning(
                "%s: %s refused: stamped %+.0f ms from our clock (clock fault #%d)",
                self.service, name, offset / 1e6, n,
            )
        return False

    def every(self, period_s: float, fn: Callable[[int], None]) -> None:
        """Run `fn(now_ns)` (locked) every `period_s` of simulated time from `run()`."""
        self._ticks.append((period_s, fn, [0.0]))

    def ready(self) -> None:
        """Declare this service alive (idempotent): call once every subscription is declared.

        A long-running service also starts its heartbeat on rig/status (for `nod status`).
        """
        if not self._tokens:
            self._tokens = [
                self.session.liveliness().declare_token(self.keys.alive(name))
                for name in self._alive_as
            ]
        if self._heartbeat is None and self.service in EVERY_SERVICE:
            status = self.publisher("rig/status")
            self._heartbeat = threading.Thread(
                target=self._beat, args=(status,), name="heartbeat", daemon=True
            )
            self._heartbeat.start()

    def _beat(self, status: TopicPublisher) -> None:
        """Publish a NodeStatus every second of wall time until the node stops."""
        host, pid, version = socket.gethostname(), os.getpid(), package_version()
        while True:
            with self.lock:  # a consistent snapshot; the put itself runs unlocked
                if self.session is None:
                    return
                received, dropped = sum(self.received.values()), sum(self.bad.values())
                activity = dict(self.activity)
            try:
                status.put(
                    service=self.service, host=host[:200], pid=pid, version=version,
                    started_ns=self.started_ns, wall_ns=time.time_ns(),
                    restarts=self.restarts, received=received, dropped=dropped,
                    params_hash=self.params_hash, **activity,
                )
            except Exception as exc:  # a heartbeat must never take the service down
                log.debug("%s: heartbeat not sent: %s", self.service, exc)
            if self.stop.wait(1.0):
                return

    def run(self) -> None:
        """Declare the service alive, run ticks until SIGINT/SIGTERM or `stop`, then close."""
        self.ready()
        try:
            while not self.stop.is_set():
                now_wall = time.monotonic()
                next_due = now_wall + 0.5
                for period, fn, due in self._ticks:
                    if now_wall >= due[0]:
                        with self.lock:
                            try:
                                fn(self.clock.now_ns())
                            except Exception:  # keep ticking: one bad tick is not a shutdown
                                log.exception("%s: tick failed", self.service)
                        due[0] += self.clock.wall_seconds(period)
                        if due[0] < now_wall:  # fell behind (or first run): no burst of catch-ups
                            due[0] = now_wall + self.clock.wall_seconds(period)
                    next_due = min(next_due, due[0])
                self.stop.wait(max(0.0, next_due - time.monotonic()))
        finally:
            self.close()

    def join_threads(self, timeout: float) -> list[threading.Thread]:
        """Wait (at most `timeout` s) for the node's own threads to end once `stop` is set.

        Returns those still running (none, unless a put blocks): the heartbeat's.
        """
        beat = self._heartbeat
        if beat is None or beat is threading.current_thread():
            return []
        beat.join(max(0.0, timeout))
        return [beat] if beat.is_alive() else []

    def close(self) -> None:
        """Stop, undeclare everything and close the session (idempotent)."""
        if self.session is None:
            return
        self.stop.set()  # threads of the service (ticks, keep-alives) wind down
        # The heartbeat drops its zenoh publisher as it ends: joined here, so that never happens
        # during the interpreter's finalization, where a thread asking for the GIL is ended by
        # pthread_exit inside PyO3's catch_unwind and glibc aborts the process (SIGABRT, "FATAL:
        # exception not rethrown"; found under load on `nod vision`'s error exit).
        self.join_threads(HEARTBEAT_JOIN_S)
        log.info(
            "%s: messages handled %s; bad ones dropped %s",
            self.service,
            dict(self.received),
            dict(self.bad) or "none",
        )
        for h in self._handles:
            h.undeclare()
        self._handles.clear()
        # A handler may still be running on a zenoh thread: let it finish publishing everything
        # it derived from its input (z_r, ẑ_h and b_r of one pose go out together or not at
        # all). From here on `session` is None under the lock: nothing publishes any more.
        with self.lock:
            session, self.session = self.session, None  # type: ignore[assignment]
        for token in self._tokens:
            token.undeclare()
        if self._urgent_session is not None and self._urgent_session is not session:
            self._urgent_session.close()
        self._urgent_session = None
        session.close()


def _env_int(name: str) -> int:
    """A small non-negative integer from the environment (0 when absent or malformed)."""
    try:
        return max(0, min(1_000_000, int(os.environ.get(name, "0"))))
    except ValueError:
        return 0


def package_version() -> str:
    """The installed version of nod-hri ("dev" when run from a tree without metadata)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("nod-hri")
    except PackageNotFoundError:
        return "dev"


HEARTBEAT_JOIN_S = 2.0  # a heartbeat ends within its put once `stop` is set
EXIT_GRACE_S = 2.0  # a service stops within this after SIGTERM, whatever blocks it


def install_signal_handlers(
    stop: threading.Event,
    exit_hooks: list[Callable[[], object]] | None = None,
    grace_s: float = EXIT_GRACE_S,
) -> None:
    """Turn SIGINT and SIGTERM into `stop.set()`; force the exit if that has not ended us soon.

    A clean stop undeclares, closes and lets the device reach its safe state. If the process is
    still alive `grace_s` later (a put blocked on a vanished router, a hung driver), the exit
    hooks run (the device's safe state, best effort, for at most a second) and the process exits
    with 128 + signal. The signal is handled on a helper thread (`services.core.signals`), and the
    forced exit is armed before anything else: neither can wait on a lock the main thread holds.
    Only possible from the main thread.
    """

    def force_exit(signum: int) -> None:
        hooks = threading.Thread(target=_run_exit_hooks, args=(exit_hooks or (),), daemon=True)
        hooks.start()
        hooks.join(1.0)  # a hook stuck on a dead device must not keep the process alive
        # os.write, not logging: a thread stuck while holding the logging lock must not stop us.
        os.write(2, f"did not stop within {grace_s:.0f} s of signal {signum}: exiting now\n"
                 .encode())
        os._exit(128 + signum)

    armed = threading.Lock()

    def arm(signum: int) -> None:
        if armed.acquire(blocking=False):  # one timer, however many signals arrive
            timer = threading.Timer(grace_s, force_exit, (signum,))
            timer.daemon = True
            timer.start()
        stop.set()

    on_stop_signal(arm)


def _run_exit_hooks(hooks: Sequence[Callable[[], object]]) -> None:
    for hook in hooks:
        try:
            hook()
        except Exception:  # best effort: nothing may prevent the exit itself
            log.exception("exit hook failed")


def clip(text: str, limit: int = 200) -> str:
    """One short line of untrusted text for a log: whitespace folded, long text cut."""
    flat = " ".join(text.split())
    return flat if len(flat) <= limit else flat[:limit] + f"… (+{len(flat) - limit} chars)"


def setup_logging(verbose: bool = False) -> None:
    """One log format for every service: time, level, logger, message — one line each."""
    logging.basicConfig(
        level=logging.DEBUG if verbose else logging.INFO,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
