"""`nod run --sim --rigs N`: N simulated rigs at once on one router, one study across them.

The router is this process's. Each rig (`rig1` … `rigN`) is a `nod run --sim` of its own that
joins it, with every service of that rig as its own process, as on a lab's tables. The study's
participants are split across the rigs in contiguous blocks of ids and seeds (so the people are
those `--rigs 1` would run, each on one rig), and each rig's conductor writes its own store,
`<db stem>-<rig>.sqlite`, as a lab's control stations would: `nod analyze study` and `nod
export` read them as one study (`--db` once per rig). Each rig's table goes to
`<logs>/run-<rig>.log`, its services' logs to `<logs>/<rig>/` (`<logs>`: the run's own folder,
`<db>.logs/<YYYYmmdd-HHMMSS>/`, unless `--logs` names one); when a rig ends its last line is
printed. On the way, each stored trial of each rig is one line here (`rig2 P21 trial 3/8 …`,
from the rigs' experiment/result on this router), and so is a trial that waits for the
operator (from the rig's own output). Ctrl-C (or SIGTERM) stops every rig; the exit code is
the first rig's that failed.

A table of N boxes (`--options N`, or a params file listing the options) is every rig's: each
rig's `nod run` gets the same `--options` and `--params`; its conductor's results are on the one
key space (schema 3) whatever N, and its lines here name the options as the results do.
"""

from __future__ import annotations

import argparse
import signal
import subprocess
import threading
import time
from pathlib import Path

from services.core import messages as m
from services.core.config import load_with_options
from services.core.contract import EXPERIMENT_RESULT
from services.core.keys import Keys
from services.core.lifeline import nod_command
from services.core.session import make_config, open_session
from services.core.signals import on_stop_signal
from services.launch.run_logs import LogWatch, run_folder
from services.store import Store, StoreError
from services.store.participants import first_free_ids, sessions_by_participant

# What every rig takes from the run (argparse dests); the rest is its own: name, store, people.
RIG_FLAGS = ("speed", "params", "options", "clicks", "stale_ms", "record", "render", "verbose")
OWN = ("resume", "participant", "order", "again", "monitor")  # one session's, or one screen's


def check_rigs(args: argparse.Namespace) -> str | None:
    """Why `--rigs` cannot run with these flags (one line), or None."""
    if args.rigs == 1:
        return None
    own = [f"--{f}" for f in OWN if getattr(args, f) is not None]
    if (args.arm_driver, args.eyes_driver) != ("sim", "sim"):
        own.append("--arm-driver/--eyes-driver (one device cannot serve several rigs)")
    if own:
        return ("--rigs runs simulated rigs, each with its share of a study: leave out "
                + ", ".join(own))
    if args.participants < args.rigs:
        return (f"--rigs {args.rigs} needs at least one participant per rig: --participants "
                f"{args.rigs} or more (got {args.participants})")
    try:  # the params and the option count, as each rig will read them
        load_with_options(args.params, args.options)
    except (ValueError, OSError) as exc:  # ConfigError is a ValueError
        return str(exc)
    return None


def rig_names(n: int) -> list[str]:
    """The simulated rigs' names: rig1 … rigN."""
    return [f"rig{k}" for k in range(1, n + 1)]


def rig_store(db: Path, rig: str) -> Path:
    """The store of one rig of a `--rigs` run: `<db stem>-<rig><suffix>` next to `db`."""
    return db.with_name(f"{db.stem}-{rig}{db.suffix or '.sqlite'}")


def blocks(items: list[str], n: int) -> list[list[str]]:
    """`items` in n contiguous blocks whose sizes differ by at most one (the first larger)."""
    size, extra = divmod(len(items), n)
    out, start = [], 0
    for k in range(n):
        end = start + size + (k < extra)
        out.append(items[start:end])
        start = end
    return out


def free_ids(stores: list[Path], n: int) -> list[str]:
    """The first n participant ids with no session in any of the stores.

    StoreError if one is no session store.
    """
    taken: set[str] = set()
    for path in stores:
        if path.is_file():
            store = Store(path)
            try:
                taken |= set(sessions_by_participant(store))
            finally:
                store.close()
    return first_free_ids(taken, n)


class RigProgress:
    """One line per stored trial of a rig, naming its participant (pure: no I/O).

    A rig runs its block of ids one after another, so the k-th session a rig's results name is
    its k-th participant's (a restarted conductor resumes the same session: the same person).
    Results name their options, whatever the option set.
    """

    def __init__(self, people: dict[str, list[str]], n_trials: int) -> None:
        self.people = people
        self.n = n_trials
        self.sessions: dict[str, list[str]] = {rig: [] for rig in people}
        self.lock = threading.Lock()

    def line(self, rig: str, r: m.TrialResult) -> str:
        """The line of one stored trial of `rig`."""
        with self.lock:
            seen = self.sessions[rig]
            if r.session not in seen:
                seen.append(r.session)
            k = seen.index(r.session)
        ids = self.people[rig]
        who = ids[k] if k < len(ids) else r.session
        option = f" O={r.option}" if r.option else ""
        what = "interrupted" if r.interrupted else f"{r.outcome or '-'} score {r.score}"
        return f"{rig} {who} trial {r.trial}/{self.n} [{r.mode}{option}]: {what}"


def next_seed(stores: list[Store]) -> int:
    """The first seed of simulated participants added to these stores (1 if none is stored).

    One past the largest any of their sessions was run with: an added person is never a stored
    one (a second `nod run --sim` into a store holding P01 runs P02 with seed 2, not 1 again).
    """
    seeds = [int(row["seed"]) for st in stores for row in st.sessions() if row["seed"] is not None]
    return max(seeds, default=0) + 1


def _next_seed(paths: list[Path]) -> int:
    """`next_seed` of the stores at `paths` that exist (StoreError if one is no store)."""
    stores = [Store(p) for p in paths if p.is_file()]
    try:
        return next_seed(stores)
    finally:
        for store in stores:
            store.close()


def run_rigs(args: argparse.Namespace, passthrough: list[str]) -> int:
    """Run the rigs of `args.rigs` on one router; `passthrough`: the flags every rig gets."""
    rigs = rig_names(args.rigs)
    stores = [rig_store(args.db, r) for r in rigs]
    try:
        people = blocks(free_ids(stores, args.participants), len(rigs))
        seed = args.seed if args.seed is not None else _next_seed(stores)
    except StoreError as exc:
        print(f"nod run: {exc}", flush=True)
        return 2
    try:  # this run's own folder (`nod run`'s): a later run never overwrites these logs
        logs = args.logs or run_folder(args.db.with_suffix(".logs"))
        logs.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        print(f"nod run: cannot write logs to {args.logs or args.db.with_suffix('.logs')}: "
              f"{exc.strerror}", flush=True)
        return 2
    try:
        router = open_session(make_config(mode="router", listen=[args.listen]))
    except ConnectionError as exc:
        print(f"nod run: cannot listen on {args.listen}: {exc}", flush=True)
        return 2
    print(f"router listening on {args.listen}; {len(rigs)} rigs; speed {args.speed}x; "
          f"{args.participants} participant(s): "
          + "; ".join(f"{r} {b[0]}" + (f"..{b[-1]}" if len(b) > 1 else "")
                      for r, b in zip(rigs, people, strict=True))
          + f"; logs in {logs}/", flush=True)
    stopping = threading.Event()
    on_stop_signal(lambda _signum: stopping.set())  # never set() inside a handler
    children: dict[str, subprocess.Popen] = {}
    cfg, schedule = load_with_options(args.params, args.options)  # checked by check_rigs
    progress = RigProgress(
        dict(zip(rigs, people, strict=True)),
        len(cfg.protocol.trials if schedule is None else schedule.trials),
    )
    subs = [sub for rig in rigs for sub in _follow(router, rig, progress)]
    try:
        for rig, ids, store in zip(rigs, people, stores, strict=True):
            cmd = nod_command(
                "run", "--sim", "--join", "--rig", rig, "--db", str(store), "--listen",
                args.listen, "--participants", str(len(ids)), "--ids", ",".join(ids),
                "--seed", str(seed), "--logs", str(logs / rig), *passthrough,
            )
            seed += len(ids)  # the seeds of the next block: each person keeps theirs
            with (logs / f"run-{rig}.log").open("w") as out:
                children[rig] = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT,
                                                 stdin=subprocess.DEVNULL)
        codes = _wait(children, stopping, logs)
    finally:
        for sub in subs:
            sub.undeclare()
        for proc in children.values():
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        router.close()
    failed = [r for r in rigs if codes.get(r) != 0]
    if not failed:
        print("one study: nod analyze study " + " ".join(f"--db {s}" for s in stores))
        return 0
    return codes.get(failed[0], 1) or 1


def _follow(router, rig: str, progress: RigProgress) -> list:
    """Print a line per trial `rig` stores (a subscriber in a list: undeclare it)."""

    def on_result(sample) -> None:
        try:
            result = m.decode(EXPERIMENT_RESULT.message, sample.payload.to_bytes())
        except m.MessageError:
            return  # the rig's own table names it; one bad message is no reason to stop
        print(progress.line(rig, result), flush=True)

    return [router.declare_subscriber(Keys(rig).topic(EXPERIMENT_RESULT.name), on_result)]


def _wait(children: dict[str, subprocess.Popen], stopping: threading.Event,
          logs: Path) -> dict[str, int]:
    """Every rig's exit code; on Ctrl-C each rig is stopped as `nod run` stops (SIGINT).

    Meanwhile a trial waiting for the operator on a rig (its run's own line) is said here too.
    """
    codes: dict[str, int] = {}
    asked = False
    waiting = {rig: LogWatch(logs / f"run-{rig}.log") for rig in children}
    while len(codes) < len(children):
        for rig, watch in waiting.items():
            for line in watch.new():
                print(f"{rig}: {line}", flush=True)
        if stopping.is_set() and not asked:
            for proc in children.values():
                if proc.poll() is None:
                    proc.send_signal(signal.SIGINT)
            asked = True
        for rig, proc in children.items():
            if rig not in codes and proc.poll() is not None:
                codes[rig] = proc.returncode
                lines = (logs / f"run-{rig}.log").read_text(errors="replace").splitlines()
                last = next((ln for ln in reversed(lines) if ln.strip()), "(no output)")
                print(f"{rig}: exit {proc.returncode}: {last.strip()}", flush=True)
        time.sleep(0.2)
    return codes
