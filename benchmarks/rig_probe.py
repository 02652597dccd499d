"""What the scale and soak benchmarks read off a running `nod run --sim`: processes and topics.

`services_of(root)` names every process under a launcher by its service and rig (from its
command line), `cpu_seconds(pid)` and `rss_kb(pid)` read /proc; `seq_gaps`, `Hot` and
`rss_verdict` are the pure parts (tested in tests/unit/test_rig_probe.py).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field

TICK = os.sysconf("SC_CLK_TCK")


def children(pid: int) -> list[int]:
    """Every descendant of `pid` (from /proc's parent links), deepest last."""
    parent: dict[int, list[int]] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as f:
                    ppid = int(f.read().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            parent.setdefault(ppid, []).append(int(entry))
    out, todo = [], [pid]
    while todo:
        for child in parent.get(todo.pop(), []):
            out.append(child)
            todo.append(child)
    return out


def service_name(argv: Sequence[str]) -> tuple[str, str] | None:
    """(rig, service) of a `nod` process's command line, or None for anything else.

    `python -m services.cli decision --rig rig2 …` → ("rig2", "decision"); the launchers are
    "router" (`nod run` hosting the router: the top process) and "launcher" (a rig's `nod run
    --join`).
    """
    try:
        at = list(argv).index("services.cli")
    except ValueError:
        return None
    rest = list(argv[at + 1 :])
    if not rest:
        return None
    rig = rest[rest.index("--rig") + 1] if "--rig" in rest[:-1] else "rig1"
    name = rest[0]
    if name == "run":
        return (rig, "launcher") if "--join" in rest else ("lab", "router")
    return rig, name


def argv_of(pid: int) -> list[str]:
    """A process's command line ([] once it is gone)."""
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            return [a.decode(errors="replace") for a in f.read().split(b"\0") if a]
    except OSError:
        return []


def cpu_seconds(pid: int) -> float | None:
    """User + system CPU seconds of a process so far (utime + stime), None once it is gone."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / TICK


def rss_kb(pid: int) -> int | None:
    """A process's resident memory (VmRSS, kB), None once it is gone."""
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1])
    except OSError:
        return None
    return None


def services_of(root: int) -> dict[int, tuple[str, str]]:
    """Every `nod` process at and under `root`: pid → (rig, service)."""
    out = {}
    for pid in [root, *children(root)]:
        name = service_name(argv_of(pid))
        if name is not None:
            out[pid] = name
    return out


@dataclass
class CpuMeter:
    """CPU seconds per process over a window, processes that come and go included.

    A process first seen inside the window counts from 0 (its start-up is load too); one that
    ends between two samples loses at most a sampling interval of its CPU.
    """

    first: dict[int, float] = field(default_factory=dict)
    last: dict[int, float] = field(default_factory=dict)
    names: dict[int, tuple[str, str]] = field(default_factory=dict)

    def sample(self, procs: dict[int, tuple[str, str]], at_start: bool = False) -> None:
        """Read every process's CPU now."""
        for pid, name in procs.items():
            cpu = cpu_seconds(pid)
            if cpu is None:
                continue
            self.names[pid] = name
            self.first.setdefault(pid, cpu if at_start else 0.0)
            self.last[pid] = cpu

    def by_service(self) -> dict[tuple[str, str], float]:
        """CPU seconds in the window per (rig, service)."""
        out: dict[tuple[str, str], float] = {}
        for pid, cpu in self.last.items():
            key = self.names[pid]
            out[key] = out.get(key, 0.0) + cpu - self.first[pid]
        return out


def seq_gaps(seqs: Iterable[int]) -> tuple[int, int]:
    """(messages missing, messages expected) in a publisher's `seq`s in arrival order.

    A seq below the last one is a new publisher (a restarted service counts from 0 again), not
    a loss; a repeated seq is ignored.
    """
    missing = expected = 0
    last: int | None = None
    for s in seqs:
        if last is None or s < last:
            expected += 1
        elif s > last:
            missing += s - last - 1
            expected += s - last
        else:
            continue
        last = s
    return missing, expected


@dataclass
class Hot:
    """Hand pose → z_r pairs of one rig, by the pose's (seq, t_ns) and the z_r's (src_seq, t_ns).

    z_r carries the pose's own timestamp and seq; the pair's arrival times at one observer give
    the hop through decision (router → decision → router), whatever the clocks.
    """

    poses: dict[tuple[int, int], int] = field(default_factory=dict)
    answers: dict[tuple[int, int], int] = field(default_factory=dict)
    seqs: list[int] = field(default_factory=list)

    def pose(self, seq: int, t_ns: int, arrived_ns: int) -> None:
        """A hand pose seen at `arrived_ns`."""
        self.poses.setdefault((seq, t_ns), arrived_ns)
        self.seqs.append(seq)

    def z_r(self, src_seq: int, t_ns: int, arrived_ns: int) -> None:
        """A z_r seen at `arrived_ns`."""
        self.answers.setdefault((src_seq, t_ns), arrived_ns)

    def latencies_ms(self) -> list[float]:
        """Every answered pose's pose → z_r time (ms)."""
        return [(self.answers[k] - t) / 1e6 for k, t in self.poses.items() if k in self.answers]

    def unanswered(self, before_ns: int) -> int:
        """Poses seen before `before_ns` that no z_r answered."""
        return sum(1 for k, t in self.poses.items() if t < before_ns and k not in self.answers)


def rss_verdict(samples: Sequence[float], tolerance: float = 0.10) -> tuple[bool, float]:
    """Whether resident memory is flat: (max − min) / min ≤ tolerance over `samples`.

    Returns (flat, growth) with growth that spread as a fraction; no samples count as flat.
    """
    if not samples:
        return True, 0.0
    low = min(samples)
    growth = (max(samples) - low) / low if low > 0 else 0.0
    return growth <= tolerance, growth


# The hot path's tail (benchmarks/latency.py): priorities, the GC's pauses, run-queue waits.

NICE = -10  # as the devices run (services/core/priority.py)
FIFO = 10  # SCHED_FIFO priority: above every normal task, far below the kernel's own threads
PRIORITIES = ("none", "nice", "fifo")


def threads(pid: int) -> list[int]:
    """The thread ids of a process ([] once it is gone)."""
    try:
        return [int(t) for t in os.listdir(f"/proc/{pid}/task")]
    except OSError:
        return []


def set_priority(kind: str, tid: int = 0) -> None:
    """Run thread `tid` (0: the caller) at `kind`: "nice" (nice −10), "fifo" (SCHED_FIFO 10) or
    "none" (left as is). Threads it starts afterwards inherit it; needs CAP_SYS_NICE."""
    if kind == "nice":
        os.setpriority(os.PRIO_PROCESS, tid, NICE)
    elif kind == "fifo":
        os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(FIFO))
    elif kind != "none":
        raise ValueError(f"priority {kind!r}: one of {', '.join(PRIORITIES)}")


def prioritize(pid: int, kind: str) -> int:
    """Every thread of a running process at `kind` (its children are left alone); how many."""
    done = 0
    for tid in threads(pid):
        try:
            set_priority(kind, tid)
            done += 1
        except ProcessLookupError:  # a thread that just ended
            continue
    return done


def run_queue(pid: int) -> tuple[int, int]:
    """(ns waited on a run queue, timeslices run) summed over a process's threads so far
    (/proc/<pid>/task/<tid>/schedstat): how long its wake-ups waited for a CPU."""
    wait = slices = 0
    for tid in threads(pid):
        try:
            with open(f"/proc/{pid}/task/{tid}/schedstat") as f:
                _, w, n = (int(x) for x in f.read().split())
        except (OSError, ValueError):
            continue
        wait += w
        slices += n
    return wait, slices


def steal_ticks() -> int:
    """The host's steal time so far, in clock ticks (/proc/stat): CPU the hypervisor gave to
    others while this VM had work."""
    with open("/proc/stat") as f:
        fields = f.readline().split()
    return int(fields[8]) if len(fields) > 8 else 0


def overlapping(spans: Sequence[tuple[int, int]], pauses: Sequence[tuple[int, int]]) -> int:
    """How many of the (start, end) `spans` overlap at least one (start, duration) pause."""
    ends = sorted((start, start + dur) for start, dur in pauses)
    count = 0
    for a, b in spans:
        if any(s < b and e > a for s, e in ends):
            count += 1
    return count


def gc_probe(
    mode: str, path: str | None = None
) -> tuple[list[tuple[int, int, int]], Callable[..., None]]:
    """Record this process's garbage collections; `mode` takes effect on SIGUSR1.

    Every collection is kept as (start perf_counter_ns, duration ns, generation) — the clock is
    CLOCK_MONOTONIC, one for every process of the host — and written to `path` (JSON) at exit
    if given.
    On SIGUSR1 (the benchmark sends it once the service is up): "freeze" collects and moves
    every object to the permanent generation (`gc.freeze()`), "off" also disables the
    collector, "default" changes nothing; then `path`.settled is created. Returns the pauses and
    the function SIGUSR1 runs.
    """
    import atexit
    import gc
    import json
    import signal
    import time

    pauses: list[tuple[int, int, int]] = []
    began = [0]

    def on_gc(phase: str, info: dict[str, int]) -> None:
        if phase == "start":
            began[0] = time.perf_counter_ns()
        else:
            pauses.append((began[0], time.perf_counter_ns() - began[0], info["generation"]))

    def settle(*_: object) -> None:
        if mode in ("freeze", "off"):
            gc.collect()
            gc.freeze()
        if mode == "off":
            gc.disable()
        if path is not None:  # done: the benchmark waits for this before it measures
            with open(path + ".settled", "w"):
                pass

    def write() -> None:
        if path is not None:
            with open(path, "w") as f:
                json.dump(pauses, f)

    gc.callbacks.append(on_gc)
    signal.signal(signal.SIGUSR1, settle)
    if path is not None:
        atexit.register(write)
    return pauses, settle
