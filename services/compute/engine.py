"""One way to run many independent pure tasks: a Dask distributed cluster, local or a lab's.

`open_engine()` (a context manager) starts an embedded `LocalCluster` on this machine's cores —
one worker process per core, one thread each (the closed loop is pure Python: threads would
share one interpreter lock), no dashboard, no profiler, quiet logs — and closes it on exit;
nothing to install or start. `open_engine("tcp://HOST:8786")` uses a cluster a lab started with
the standard commands (`dask scheduler` on one machine, `dask worker tcp://HOST:8786` on each),
after checking that every worker runs this machine's nod-hri code (a fingerprint of the
`services` sources): a worker with other code would silently simulate another model.

`Engine.map(fn, items)` returns `[fn(x) for x in items]` in input order, computed on the
cluster; `Engine.imap` yields the same results in the same order as they arrive (a progress
bar, a store written as it goes). Items travel in chunks (about `CHUNKS_PER_WORKER` chunks per
worker thread, at most `MAX_CHUNK` items each; `TASKS_PER_WORKER` of them in flight), so a
cohort of 10⁵ people is not 10⁵ scheduler tasks, while the last chunks still keep every worker
busy. `fn` and the items must pickle (a module-level function; Dask pickles a lambda by value).
Every failure to reach or use a cluster is an `EngineError` whose message is one line saying
what to do.
"""

from __future__ import annotations

import argparse
import hashlib
import logging
import math
import os
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from contextlib import AbstractContextManager, contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from services.core.cli import int_in

if TYPE_CHECKING:
    from distributed import Client, Future

T = TypeVar("T")
R = TypeVar("R")

TASKS_PER_WORKER = 16  # tasks in flight per worker thread: bounds the results held at once
# Chunks per worker thread a map is cut into: the last chunk's length is how long one worker may
# wait for the other at the end (300 sessions on 2 workers: chunks of 4, ~0.7 s, not 10), and a
# task costs the scheduler ~1 ms.
CHUNKS_PER_WORKER = 48
MAX_CHUNK = 16  # items per task at most: a chunk of stored sessions stays a few MB
CONNECT_TIMEOUT_S = 10.0  # a scheduler that does not answer in 10 s is not there
QUIET = logging.ERROR  # distributed logs every worker's start and stop at INFO
# The local workers log a heartbeat that races the scheduler's shutdown as an ERROR; a worker's
# real failure reaches the client anyway, as the task's exception (or KilledWorker).
WORKERS_QUIET = logging.CRITICAL
# The embedded cluster's own chores, set for a batch of pure tasks on a small machine: no
# statistical profiler (it samples the running task's stack every 10 ms, for a dashboard that is
# off), and the event loops' health check and monitors every 1-5 s instead of every 20-500 ms.
# Idle, a default local cluster of 2 workers took ~0.11 CPU s per second, this one ~0.015: on 2
# cores that is time taken from the cohort. A lab's own cluster keeps its own settings.
LOCAL_CONFIG: dict[str, Any] = {
    "distributed.worker.profile.enabled": False,
    "distributed.admin.tick.interval": "1s",
    "distributed.admin.system-monitor.interval": "5s",
    "distributed.worker.memory.monitor-interval": "1s",
}


class EngineError(RuntimeError):
    """The cluster cannot be reached or used; the message says how to fix it."""


def code_fingerprint(root: Path | None = None) -> str:
    """12 hex digits of the SHA-256 of every `*.py` under `root` (path and bytes), sorted.

    `root` is the `services` package by default: the same on every machine that installed the
    same commit; run on each worker to refuse one whose model differs from the client's.
    """
    root = root or Path(__file__).resolve().parents[1]
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        digest.update(path.relative_to(root).as_posix().encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()[:12]


def _run_chunk(fn: Callable[[T], R], chunk: Sequence[T]) -> list[R]:
    """One task: fn over a chunk of items (on a worker)."""
    return [fn(item) for item in chunk]


@dataclass
class Engine:
    """A connected Dask client and where it computes (see the module's docstring)."""

    client: Client
    where: str  # for messages: "a local cluster of 2 workers" / "the cluster at tcp://…"

    def threads(self) -> int:
        """How many tasks the cluster runs at once (its workers' threads)."""
        return max(1, sum(self.client.nthreads().values()))

    def imap(
        self, fn: Callable[[T], R], items: Sequence[T], chunk: int | None = None
    ) -> Iterator[R]:
        """fn(x) for each item, yielded in input order as the results arrive.

        At most TASKS_PER_WORKER tasks per worker thread are in flight, and each result is
        released on the cluster once yielded: a cohort of any size holds a bounded amount of
        results in memory, however slowly the caller consumes them.
        """
        items = list(items)
        threads = self.threads()
        per_chunk = math.ceil(len(items) / (threads * CHUNKS_PER_WORKER))
        size = chunk or min(MAX_CHUNK, max(1, per_chunk))
        chunks = deque(items[i : i + size] for i in range(0, len(items), size))
        running: deque[Future] = deque()
        try:
            while chunks or running:
                while chunks and len(running) < threads * TASKS_PER_WORKER:
                    running.append(self.client.submit(_run_chunk, fn, chunks.popleft(), pure=False))
                future = running.popleft()
                results = future.result()
                future.release()
                yield from results
        finally:  # a consumer that stops early (an error, Ctrl-C) leaves no work queued
            if running:
                self.client.cancel(list(running))

    def map(self, fn: Callable[[T], R], items: Sequence[T], chunk: int | None = None) -> list[R]:
        """[fn(x) for x in items], computed on the cluster, in input order."""
        return list(self.imap(fn, items, chunk))


def _check_code(client: Client, address: str) -> None:
    """Refuse a cluster whose workers run other nod-hri code than this machine."""
    mine = code_fingerprint()
    try:
        theirs: dict[str, Any] = client.run(code_fingerprint, on_error="return")
    except Exception as exc:  # noqa: BLE001  # any failure here means: not our code
        raise EngineError(
            f"the workers at {address} cannot run nod-hri ({exc}): install this "
            "project (the same commit) on every worker machine"
        ) from None
    other = {w: f for w, f in theirs.items() if f != mine}
    if other:
        worker, got = next(iter(other.items()))
        got = got if isinstance(got, str) else f"cannot import services: {got}"
        raise EngineError(
            f"worker {worker} of {address} runs other nod-hri code ({got}) than this machine "
            f"({mine}): install the same commit on every worker and restart `dask worker`"
        )


def _connect(address: str, timeout_s: float) -> Client:
    from distributed import Client

    try:
        client = Client(address, timeout=timeout_s, set_as_default=False)
    except (OSError, TimeoutError, ValueError) as exc:
        why = " ".join(str(exc).split()) or type(exc).__name__
        raise EngineError(
            f"cannot reach the Dask scheduler at {address} ({why}): start it with "
            "`dask scheduler` and workers with `dask worker ADDRESS`, or leave out --scheduler "
            "to compute on this machine"
        ) from None
    try:
        client.wait_for_workers(1, timeout=timeout_s)
    except (TimeoutError, OSError):
        client.close()
        raise EngineError(
            f"no Dask worker joined the scheduler at {address} in {timeout_s:.0f} s: start one "
            f"on each machine with `dask worker {address}`"
        ) from None
    try:
        _check_code(client, address)
    except EngineError:
        client.close()
        raise
    return client


@contextmanager
def open_engine(
    scheduler: str | None = None,
    workers: int | None = None,
    timeout_s: float = CONNECT_TIMEOUT_S,
) -> Iterator[Engine]:
    """An engine on `scheduler` (a `dask scheduler`'s address) or, if None, on this machine.

    `workers`: the local cluster's worker processes (default: every core); ignored with a
    scheduler, whose workers are whoever joined it.
    """
    logging.getLogger("distributed").setLevel(QUIET)
    if scheduler is not None:
        client = _connect(scheduler, timeout_s)
        try:
            yield Engine(client, f"the cluster at {scheduler}")
        finally:
            client.close()
        return
    import dask
    from distributed import Client, LocalCluster

    n = workers or os.cpu_count() or 1
    try:
        with dask.config.set(LOCAL_CONFIG):  # read as the cluster starts (its workers: a copy)
            cluster = LocalCluster(
                n_workers=n,
                threads_per_worker=1,
                processes=True,
                host="127.0.0.1",
                # the scheduler's HTTP server always starts: on a free loopback port, no dashboard
                dashboard_address="127.0.0.1:0",
                scheduler_kwargs={"dashboard": False},
                silence_logs=WORKERS_QUIET,
            )
    except (RuntimeError, OSError, TimeoutError) as exc:
        why = " ".join(str(exc).split()) or type(exc).__name__
        raise EngineError(
            f"cannot start a local Dask cluster of {n} workers ({why}): try "
            "fewer --workers, or a cluster of your own with --scheduler"
        ) from None
    with cluster, Client(cluster, set_as_default=False) as client:
        yield Engine(client, f"a local cluster of {n} worker{'s' if n > 1 else ''}")


def add_engine_args(parser: argparse.ArgumentParser) -> None:
    """`--scheduler ADDRESS` and `--workers N`: where a command's cohort is computed."""
    parser.add_argument(
        "--scheduler",
        metavar="tcp://HOST:8786",
        default=None,
        help="compute on the Dask cluster of this scheduler (`dask scheduler`, then `dask "
        "worker tcp://HOST:8786` on each machine); default: a local cluster on this machine",
    )
    parser.add_argument(
        "--workers",
        type=int_in(1, 1024),
        default=None,
        help="worker processes of the local cluster (default: one per core)",
    )


def engine_from_args(args: argparse.Namespace) -> AbstractContextManager[Engine]:
    """`open_engine` with the command line's `--scheduler` and `--workers`."""
    return open_engine(args.scheduler, args.workers)
