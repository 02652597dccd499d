"""How many simulated rigs one router and one host carry: 1, 2, 4, … rigs until it breaks.

Each step is `nod run --sim --rigs N --render` (every service of each rig as its own process:
decision, actuation, eyes, speaker, vision tracking the sim camera's 30 Hz frames, the sim
person, the conductor; one router for all) on a free loopback port, at `--speed 1` (the camera
and the safety bounds in wall time, as on a real table). An observer on the router counts,
over `--seconds` of trials after every rig's first trial has begun:

- hand → z_r: per rig, the arrival of each hand pose and of the z_r answering it (its
  `src_seq` and `t_ns` are the pose's) at the observer, p50 / p99 over all rigs;
- Hz/rig: the hand poses each rig's camera path delivered per second (30 when it keeps up);
- lost: hand-pose seq gaps plus poses no z_r answered, over the poses expected;
- CPU per service: utime + stime from /proc over the window, per rig (mean over the rigs), the
  router's (the top `nod run`), and the deliveries the services report (rig/status `received`);
- completion: of the trials set up in the window, those stored with a result (not
  interrupted); the trials in flight are waited for (up to 40 s).

A rig count breaks when p99 > `--max-p99-ms` (50), completion < 100 % or losses > 1 %; the
steps stop at the first that breaks (`--keep-going`: every count, the whole curve). Exit 1 if
even one rig breaks.

    .venv/bin/python benchmarks/scale_rigs.py [--rigs 1,2,4,8] [--seconds 60] [--keep-going]
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field

import numpy as np
import zenoh

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)  # the tests' helpers, this folder's probe
from benchmarks.rig_probe import CpuMeter, Hot, seq_gaps, services_of  # noqa: E402
from services.core import messages as m  # noqa: E402
from services.core.session import make_config, open_session  # noqa: E402
from tests.processes import free_port  # noqa: E402

SERVICES = ("decision", "actuation", "eyes", "speaker", "vision", "sim", "experiment",
            "launcher")


@dataclass
class Observer:
    """Every rig's hand poses, z_r, trials and heartbeats as they reach one client."""

    hot: dict[str, Hot] = field(default_factory=dict)
    setups: dict[str, set[tuple[str, int]]] = field(default_factory=dict)
    results: dict[tuple[str, str, int], bool] = field(default_factory=dict)  # → interrupted
    received: dict[tuple[str, str, int], list[int]] = field(default_factory=dict)
    counting: bool = False
    lock: threading.Lock = field(default_factory=threading.Lock)

    def declare(self, session: zenoh.Session) -> list[zenoh.Subscriber]:
        """Subscribe to the four keys on every rig."""
        def rig_of(sample: zenoh.Sample) -> str:
            return str(sample.key_expr).split("/")[1]

        def on_hand(s: zenoh.Sample) -> None:
            t = time.monotonic_ns()
            if self.counting:
                msg = m.decode(m.HandPose, s.payload.to_bytes())
                with self.lock:
                    self.hot.setdefault(rig_of(s), Hot()).pose(msg.seq, msg.t_ns, t)

        def on_zr(s: zenoh.Sample) -> None:
            t = time.monotonic_ns()
            msg = m.decode(m.Opinions, s.payload.to_bytes())
            with self.lock:
                self.hot.setdefault(rig_of(s), Hot()).z_r(msg.src_seq, msg.t_ns, t)

        def on_trial(s: zenoh.Sample) -> None:
            ev = m.decode(m.TrialEvent, s.payload.to_bytes())
            if ev.phase == "setup":
                with self.lock:
                    rig = self.setups.setdefault(rig_of(s), set())
                    if self.counting:
                        rig.add((ev.session, ev.trial))

        def on_result(s: zenoh.Sample) -> None:
            r = m.decode(m.TrialResult, s.payload.to_bytes())
            with self.lock:
                self.results[(rig_of(s), r.session, r.trial)] = r.interrupted

        def on_status(s: zenoh.Sample) -> None:
            st = m.decode(m.NodeStatus, s.payload.to_bytes())
            if self.counting:
                with self.lock:
                    self.received.setdefault((rig_of(s), st.service, st.pid), []).append(
                        st.received)

        fast = {"vision/hand": on_hand, "decision/z_r": on_zr}
        slow = {"experiment/trial": on_trial, "experiment/result": on_result,
                "rig/status": on_status}
        subs = [session.declare_subscriber(f"nod/*/{k}", zenoh.handlers.Callback(
            cb, indirect=False)) for k, cb in fast.items()]
        return subs + [session.declare_subscriber(f"nod/*/{k}", cb) for k, cb in slow.items()]


@dataclass
class Step:
    """One rig count's figures."""

    rigs: int
    p50_ms: float
    p99_ms: float
    gaps: int  # hand-pose seq gaps
    unanswered: int  # poses no z_r answered
    expected: int
    started: int
    completed: int
    cpu: dict[str, float]  # % of one core per rig, by service; "router" for the whole run
    deliveries: float  # messages per second the services handled, all rigs
    seconds: float
    load: tuple[float, float, float]

    @property
    def loss(self) -> float:
        """Lost messages over expected ones."""
        return (self.gaps + self.unanswered) / self.expected if self.expected else 1.0

    @property
    def completion(self) -> float:
        """Trials stored complete over trials set up in the window."""
        return self.completed / self.started if self.started else 0.0

    def breaks(self, max_p99_ms: float) -> list[str]:
        """Why this step counts as broken (empty: it holds)."""
        why = []
        if self.p99_ms > max_p99_ms:
            why.append(f"p99 {self.p99_ms:.1f} ms > {max_p99_ms:g} ms")
        if self.completion < 1.0:
            why.append(f"completion {self.completion:.0%}")
        if self.loss > 0.01:
            why.append(f"losses {self.loss:.1%}")
        return why


def wait(cond, timeout: float, what: str, proc: subprocess.Popen) -> None:
    """Poll `cond` until true; SystemExit with `what` on timeout or if `proc` ended."""
    deadline = time.monotonic() + timeout
    while not cond():
        if proc.poll() is not None:
            raise SystemExit(f"nod run ended (exit {proc.returncode}) while waiting for {what}")
        if time.monotonic() > deadline:
            raise SystemExit(f"no {what} after {timeout:.0f} s")
        time.sleep(0.2)


def connect(endpoint: str, proc: subprocess.Popen) -> zenoh.Session:
    """A client of the run's router once it listens."""
    while True:
        try:
            return open_session(make_config(mode="client", connect=[endpoint]))
        except ConnectionError:
            if proc.poll() is not None:
                raise SystemExit(
                    f"nod run ended (exit {proc.returncode}) before listening") from None
            time.sleep(0.3)


def step(n: int, seconds: float, render: bool, folder: str) -> Step:
    """Run n rigs, measure `seconds` of trials, stop them; the step's figures."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    cmd = [sys.executable, "-m", "services.cli", "run", "--sim", "--rigs", str(n),
           "--participants", str(20 * n), "--listen", endpoint,
           "--db", os.path.join(folder, f"scale{n}.sqlite"), *(["--render"] if render else [])]
    with open(os.path.join(folder, f"run{n}.log"), "w") as log:
        proc = subprocess.Popen(cmd, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT,
                                start_new_session=True)
    session = None
    obs = Observer()
    try:
        session = connect(endpoint, proc)
        subs = obs.declare(session)
        rigs = [f"rig{k}" for k in range(1, n + 1)]
        wait(lambda: all(r in obs.setups for r in rigs), 120 + 30 * n, "first trial on every rig",
             proc)
        meter = CpuMeter()
        meter.sample(services_of(proc.pid), at_start=True)
        obs.counting = True
        start = time.monotonic()
        while time.monotonic() - start < seconds:
            time.sleep(1.0)
            meter.sample(services_of(proc.pid))
        obs.counting = False
        window = time.monotonic() - start
        end_ns = time.monotonic_ns()
        load = os.getloadavg()
        with obs.lock:
            started = {(r, *t) for r, ts in obs.setups.items() for t in ts}

        def finished() -> bool:
            with obs.lock:
                return all(k in obs.results for k in started)

        deadline = time.monotonic() + 40
        while not finished() and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.5)
        time.sleep(1.0)  # the last z_r of the window
        for sub in subs:
            sub.undeclare()
        with obs.lock:
            lat = [x for h in obs.hot.values() for x in h.latencies_ms()]
            gaps = unanswered = expected = 0
            for h in obs.hot.values():
                miss, exp = seq_gaps(h.seqs)
                gaps += miss
                unanswered += h.unanswered(end_ns - 500_000_000)
                expected += exp
            completed = sum(1 for k in started if obs.results.get(k) is False)
            handled = sum(max(v) - min(v) for v in obs.received.values())
        cpu = per_rig_cpu(meter.by_service(), n, window)
    finally:
        if session is not None:
            session.close()
        stop(proc)
    return Step(n, float(np.percentile(lat, 50)) if lat else float("nan"),
                float(np.percentile(lat, 99)) if lat else float("nan"), gaps, unanswered, expected,
                len(started), completed, cpu, handled / window, window, load)


def per_rig_cpu(by: dict[tuple[str, str], float], n: int, window: float) -> dict[str, float]:
    """% of one core: each service's mean over the rigs; the router (the top process) whole."""
    out: dict[str, float] = {}
    for (rig, service), secs in by.items():
        share = 100 * secs / window
        out[service] = out.get(service, 0.0) + (share if rig == "lab" else share / n)
    return out


def stop(proc: subprocess.Popen) -> None:
    """Ctrl-C the run (it stops every rig), then kill its process group if it lingers."""
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGINT)
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    with contextlib.suppress(ProcessLookupError):  # children the run could not stop
        os.killpg(proc.pid, signal.SIGKILL)


def table(steps: list[Step], max_p99_ms: float) -> None:
    """Print the curve: one line per rig count, then CPU per service per rig."""
    print(f"{'rigs':>4} {'Hz/rig':>6} {'p50 ms':>7} {'p99 ms':>7} {'gaps+unanswered/poses':>21} "
          f"{'trials':>9} "
          f"{'deliv/s':>8} {'router %':>8} {'all %':>6}  load        verdict")
    for s in steps:
        total = sum(v * (1 if k == "router" else s.rigs) for k, v in s.cpu.items())
        why = s.breaks(max_p99_ms)
        lost = f"{s.gaps}+{s.unanswered}/{s.expected}"
        hz = s.expected / s.seconds / s.rigs
        print(f"{s.rigs:>4} {hz:6.1f} {s.p50_ms:7.2f} {s.p99_ms:7.2f} {lost:>21} "
              f"{s.completed:>4}/{s.started:<4} {s.deliveries:8.0f} "
              f"{s.cpu.get('router', 0):8.1f} {total:6.0f}  "
              f"{' '.join(f'{x:.1f}' for x in s.load):11} {'; '.join(why) or 'holds'}")
    names = [n for n in SERVICES if any(n in s.cpu for s in steps)]
    print("CPU per rig, % of one core: " + "  ".join(f"{n:>10}" for n in ["rigs", *names]))
    for s in steps:
        print(" " * 28 + f"{s.rigs:>10}  " + "  ".join(f"{s.cpu.get(n, 0):10.1f}"
                                                      for n in names))


def main() -> int:
    """Run the steps until one breaks; exit 1 if one rig already does."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rigs", default="1,2,4,8", help="rig counts to try, in order")
    ap.add_argument("--seconds", type=float, default=60.0, help="measured window per step")
    ap.add_argument("--max-p99-ms", type=float, default=50.0)
    ap.add_argument("--keep-going", action="store_true",
                    help="run every rig count, past the first that breaks (the whole curve)")
    ap.add_argument("--no-render", action="store_true",
                    help="the sim publishes hand poses itself (no camera path, no vision)")
    args = ap.parse_args()
    steps: list[Step] = []
    with tempfile.TemporaryDirectory(prefix="nod-scale-") as folder:
        for n in (int(x) for x in args.rigs.split(",")):
            print(f"{n} rig(s)…", flush=True)
            steps.append(step(n, args.seconds, not args.no_render, folder))
            table(steps[-1:], args.max_p99_ms)
            if steps[-1].breaks(args.max_p99_ms) and not args.keep_going:
                break
    print()
    table(steps, args.max_p99_ms)
    return 1 if steps[0].breaks(args.max_p99_ms) else 0


if __name__ == "__main__":
    raise SystemExit(main())
