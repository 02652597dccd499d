"""One way to run many independent pure tasks: a Dask distributed cluster, local or a lab's.

`open_engine()` (a context manager) starts an embedded `LocalCluster` on this machine's cores —
one worker process per core, one thread each (the closed loop is pure Python: threads would
share one interpreter lock), no dashboard, no profiler, quiet logs — and closes it on exit;
nothing to install or start; it listens on loopback only (127.0.0.1: the scheduler, the workers
and their HTTP servers), so nothing on the network can reach it. `open_engine("tls://HOST:8786",
tls_dir=DIR)` uses a cluster a lab started with the standard commands (`dask scheduler` on one
machine, `dask worker tls://HOST:8786` on each) and the certificates of `nod lab secure`
(`services.lab.compute`): the client shows DIR's certificate (mutual TLS, encryption required),
so a cluster that admits only its CA's certificates runs nobody else's code. A plain `tcp://`
scheduler anywhere but on loopback is refused unless `insecure` (`--insecure`): a Dask
scheduler runs whatever any client sends, as the workers' user, on every worker. Before it
computes, the engine checks that every worker runs this machine's nod-hri code (a fingerprint
of the `services` sources): a worker with other code would silently simulate another model.

`Engine.map(fn, items)` returns `[fn(x) for x in items]` in input order, computed on the
cluster; `Engine.imap` yields the same results in the same order as they arrive (a progress
bar, a store written as it goes). Items travel in chunks (about `CHUNKS_PER_WORKER` chunks per
worker thread, at most `MAX_CHUNK` items each; `TASKS_PER_WORKER` of them in flight), so a
cohort of 10⁵ people is not 10⁵ scheduler tasks, while the last chunks still keep every worker
busy. `fn` and the items must pickle (a module-level function; Dask pickles a lambda by value).
Every failure to reach or use a cluster is an `EngineError` whose message is one line saying
what to do — also a scheduler or worker that dies mid-map (`imap` raises it with how many
results had arrived, so the caller can mark its work incomplete and say how to resume).
"""

from __future__ import annotations

import argparse
import hashlib
import ipaddress
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
    from distributed.security import Security

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


# The client's own reconnection logs a traceback at ERROR when its scheduler goes away; the
# caller learns it from the futures (an EngineError), in one line.
CLIENT_QUIET = logging.CRITICAL
TLS_DIR_ENV = "NOD_DASK_TLS"  # the default of --tls-dir
# The files of a Dask identity's folder (`nod lab secure`: out/dask/client/).
TLS_FILES = ("ca.pem", "cert.pem", "key.pem")


class EngineError(RuntimeError):
    """The cluster cannot be reached or used; the message says how to fix it."""


def is_loopback(host: str) -> bool:
    """Whether `host` (a name or an address) is this machine's loopback, never the network."""
    if host.lower() in ("localhost", "localhost.localdomain"):
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False  # a name: it may resolve to anything


def scheduler_security(
    address: str, tls_dir: Path | None, insecure: bool = False
) -> Security | None:
    """How to reach the scheduler at `address`: mutual TLS with `tls_dir`'s identity, or nothing.

    `tls://HOST:PORT` needs `tls_dir` (ca.pem, cert.pem, key.pem: `nod lab secure`'s
    out/dask/client/); `tcp://` is allowed to a loopback address, elsewhere only if `insecure`
    (`tls_dir` is not used with tcp). EngineError (one line) for anything else.
    """
    from distributed.comm.addressing import parse_address, parse_host_port

    try:
        scheme, location = parse_address(address, strict=False)
        host, _ = parse_host_port(location)
    except ValueError as exc:
        raise EngineError(
            f"--scheduler {address!r} is not a scheduler address ({exc}): give "
            "tls://HOST:8786 (or tcp://127.0.0.1:PORT on this machine)"
        ) from None
    if scheme == "tcp":
        if not (is_loopback(str(host)) or insecure):
            raise EngineError(
                f"refusing plain tcp to {address}: any machine on that network could run code on "
                "its workers and read or alter the cohort; start the cluster with the certificates "
                "of `nod lab secure` and give --scheduler tls://HOST:PORT --tls-dir DIR (or "
                "--insecure on a network you trust)"
            )
        return None
    if scheme != "tls":
        raise EngineError(
            f"--scheduler {address!r}: the scheme {scheme}:// is not supported; give "
            "tls://HOST:8786 with --tls-dir (or tcp:// on loopback)"
        )
    if tls_dir is None:
        raise EngineError(
            f"{address} needs this machine's client certificate: give --tls-dir DIR (the "
            f"dask/client/ folder of `nod lab secure`), or set {TLS_DIR_ENV}"
        )
    missing = [n for n in TLS_FILES if not (tls_dir / n).is_file()]
    if missing:
        raise EngineError(
            f"--tls-dir {tls_dir} lacks {', '.join(missing)}: give the dask/client/ folder "
            "that `nod lab secure` wrote (ca.pem, cert.pem, key.pem)"
        )
    from distributed.security import Security

    security = Security(
        tls_ca_file=str(tls_dir / "ca.pem"),
        tls_client_cert=str(tls_dir / "cert.pem"),
        tls_client_key=str(tls_dir / "key.pem"),
        require_encryption=True,
    )
    try:  # the files load now, or the message says which cannot
        security.get_connection_args("client")
    except (OSError, ValueError) as exc:
        why = " ".join(str(exc).split()) or type(exc).__name__
        raise EngineError(
            f"cannot use the certificates in {tls_dir} ({why}): give the dask/client/ folder "
            "of `nod lab secure` as it was written"
        ) from None
    return security


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
        done = 0
        try:
            while chunks or running:
                try:
                    while chunks and len(running) < threads * TASKS_PER_WORKER:
                        running.append(
                            self.client.submit(_run_chunk, fn, chunks.popleft(), pure=False)
                        )
                    future = running.popleft()
                    results = future.result()
                except Exception as exc:
                    if not self._lost(exc):
                        raise  # the task's own error, as fn raised it
                    raise EngineError(
                        f"{self.where} stopped computing after {done} of {len(items)} results "
                        f"({_why(exc)}): restart its scheduler and workers"
                    ) from None
                future.release()
                done += len(results)
                yield from results
        finally:  # a consumer that stops early (an error, Ctrl-C) leaves no work queued
            if running and self.client.status == "running":
                self.client.cancel(list(running))

    def _lost(self, exc: Exception) -> bool:
        """Whether a failed result means the cluster failed (not the task's own error)."""
        from concurrent.futures import CancelledError

        from distributed import KilledWorker
        from distributed.comm import CommClosedError

        lost = (CancelledError, KilledWorker, CommClosedError)
        return isinstance(exc, lost) or self.client.status != "running"

    def map(self, fn: Callable[[T], R], items: Sequence[T], chunk: int | None = None) -> list[R]:
        """[fn(x) for x in items], computed on the cluster, in input order."""
        return list(self.imap(fn, items, chunk))


def _why(exc: BaseException) -> str:
    """An exception as a short single line, for an EngineError's parentheses."""
    reason = getattr(exc, "reason", None)  # FutureCancelledError: scheduler-connection-lost
    why = str(reason) if reason else " ".join(str(exc).split()) or type(exc).__name__
    return why if len(why) <= 160 else why[:157] + "..."


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


def _connect(address: str, timeout_s: float, security: Security | None) -> Client:
    from distributed import Client

    try:
        client = Client(address, timeout=timeout_s, set_as_default=False, security=security)
    except (OSError, TimeoutError, ValueError, RuntimeError) as exc:
        how = (
            "check that it was started with the certificates of the same `nod lab secure` "
            "(`dask scheduler --tls-ca-file … --tls-cert … --tls-key …`)"
            if security is not None
            else "start it with `dask scheduler` and workers with `dask worker ADDRESS`"
        )
        raise EngineError(
            f"cannot reach the Dask scheduler at {address} ({_why(exc)}): {how}, or leave out "
            "--scheduler to compute on this machine"
        ) from None
    try:
        client.wait_for_workers(1, timeout=timeout_s)
    except (TimeoutError, OSError, RuntimeError):
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
    tls_dir: Path | None = None,
    insecure: bool = False,
) -> Iterator[Engine]:
    """An engine on `scheduler` (a `dask scheduler`'s address) or, if None, on this machine.

    `workers`: the local cluster's worker processes (default: every core); ignored with a
    scheduler, whose workers are whoever joined it. `tls_dir` and `insecure`: see
    `scheduler_security`.
    """
    import distributed  # noqa: F401  # sets its loggers' levels when first imported: before ours

    logging.getLogger("distributed").setLevel(QUIET)
    logging.getLogger("distributed.client").setLevel(CLIENT_QUIET)
    if scheduler is not None:
        security = scheduler_security(scheduler, tls_dir, insecure)
        client = _connect(scheduler, timeout_s, security)
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
    """`--scheduler`, `--tls-dir`, `--insecure` and `--workers`: where a command computes."""
    parser.add_argument(
        "--scheduler",
        metavar="tls://HOST:8786",
        default=None,
        help="compute on the Dask cluster of this scheduler, started with the certificates of "
        "`nod lab secure` (the commands it prints); default: a local cluster on this machine",
    )
    parser.add_argument(
        "--tls-dir",
        type=Path,
        default=os.environ.get(TLS_DIR_ENV) or None,
        metavar="DIR",
        help="this machine's Dask client identity for a tls:// scheduler: the dask/client/ "
        f"folder of `nod lab secure` (ca.pem, cert.pem, key.pem; default ${TLS_DIR_ENV})",
    )
    parser.add_argument(
        "--insecure",
        action="store_true",
        help="allow a plain tcp:// scheduler that is not on loopback (anyone who reaches it "
        "runs code on its workers)",
    )
    parser.add_argument(
        "--workers",
        type=int_in(1, 1024),
        default=None,
        help="worker processes of the local cluster (default: one per core)",
    )


def engine_from_args(args: argparse.Namespace) -> AbstractContextManager[Engine]:
    """`open_engine` with the command line's engine flags (`add_engine_args`)."""
    return open_engine(
        args.scheduler,
        args.workers,
        tls_dir=getattr(args, "tls_dir", None),
        insecure=getattr(args, "insecure", False),
    )


def engine_argv(args: argparse.Namespace) -> list[str]:
    """The engine's flags as given, to repeat in a command line (a resume)."""
    out: list[str] = []
    if args.scheduler is not None:
        out += ["--scheduler", args.scheduler]
    tls_dir = getattr(args, "tls_dir", None)
    if tls_dir is not None and args.scheduler is not None:
        out += ["--tls-dir", str(tls_dir)]
    if getattr(args, "insecure", False):
        out.append("--insecure")
    if args.workers is not None:
        out += ["--workers", str(args.workers)]
    return out
