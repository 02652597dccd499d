"""What the scale and soak benchmarks read off a running `nod run --sim`: processes and topics.

`services_of(root)` names every process under a launcher by its service and rig (from its
command line), `cpu_seconds(pid)` and `rss_kb(pid)` read /proc; `seq_gaps`, `Hot` and
`rss_verdict` are the pure parts (tested in tests/unit/test_rig_probe.py).
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence
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
    rest = list(argv[at + 1:])
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
