"""`nod estimate`: the participant's parameters after each trial, as the session goes.

The service hears the session's trials on the fabric (the trial events, the hand poses between
a trial's "go" and its "end", the trial's gaze command and its result) and, after each result,
estimates the participant's parameters from their trials 1..k with the same estimator `nod fit`
uses, trained for partial sessions (`ByLength`, `services.fit.pipeline.prepare_by_length`: one
estimator per session length, over the fit's stated prior, cached beside `nod fit`'s table). It
publishes each estimate — per parameter its value and 90 % interval (a 0/1 parameter's most
likely value, set and probability) — on `estimate/person`, with how many of the k trials it
heard and what the estimate cost; the conductor stores it with the trial, and a recording
keeps it.

Why a service of its own, not a part of the conductor: the estimator's training (a table of
simulated people, eight boosted regressions) and each estimate take CPU and memory the
conductor's safety and timing paths must never wait behind, and a lab may put it on another
machine. The trial's path is built here as `nod fit` reads a stored trial (`services.fit.data.
trial_path`, one rule: `services.model.summaries.HandPath`).

Until the estimator is ready (training at start, when not cached) finished trials wait in order
and are estimated once it is; a trial it did not hear (the service started late, or restarted)
counts as one with nothing to read, as in `nod fit`, and `trials_seen` says so.
"""

from __future__ import annotations

import argparse
import logging
import math
import queue
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from services.core import messages as m
from services.core.cli import fail, int_in, service_parser
from services.core.config import load_with_options, params_hash
from services.core.node import Node, setup_logging
from services.core.session import Fabric
from services.fit.estimator import ByLength, Estimates, estimate_after
from services.model.geometry import TableLayout
from services.model.summaries import HandPath, TrialPath

log = logging.getLogger("nod.estimate")
K_LIVE = 500  # the table `nod fit recovery --by-length` uses (cached: shared with it)


@dataclass
class _Trial:
    """What has been heard of one trial so far."""

    t_go_ns: int | None = None
    ended: bool = False  # its "end" event: poses after it are not the trial's
    yaw: float = 0.0
    path: HandPath = field(default_factory=HandPath)


class SessionPaths:
    """A session's trials as `TrialPath`s, from its messages (pure: no fabric, no clock)."""

    def __init__(self) -> None:
        self.session = ""
        self.trials: dict[int, _Trial] = {}
        self.paths: dict[int, TrialPath] = {}
        self._current: int | None = None

    def on_trial(self, ev: m.TrialEvent) -> None:
        """A trial event: a new session starts over; "go" opens a trial's path, "end" closes it."""
        if ev.session and ev.session != self.session:
            self.session, self.trials, self.paths = ev.session, {}, {}
        if ev.phase == "setup":  # a repeated trial starts over
            self.trials[ev.trial] = _Trial()
            self._current = ev.trial
        elif ev.phase == "go":
            self.trials.setdefault(ev.trial, _Trial()).t_go_ns = ev.t_ns
            self._current = ev.trial
        elif ev.phase in ("end", "interrupted") and ev.trial in self.trials:
            self.trials[ev.trial].ended = True

    def on_gaze(self, msg: m.GazeMsg) -> None:
        """The trial's gaze cue (not a pose of the attention gesture)."""
        t = self.trials.get(msg.trial)
        if t is not None and not msg.gesture:
            t.yaw = msg.yaw

    def on_hand(self, pose: m.HandPose) -> None:
        """A hand pose: its centre joins the running trial's path (detected, after "go")."""
        t = self.trials.get(self._current) if self._current is not None else None
        if t is None or t.t_go_ns is None or t.ended or not pose.detected or pose.center is None:
            return
        t.path.add((pose.t_ns - t.t_go_ns) / 1e9, *pose.center)

    def on_result(self, res: m.TrialResult) -> TrialPath | None:
        """A trial's result: its whole path (None: another session's, or a trial not heard)."""
        if res.session != self.session:
            return None
        t = self.trials.get(res.trial)
        if t is None:
            return None
        path = t.path.trial(res.trial, res.mode, t.yaw, res.human, res.robot, res.switches,
                            res.interrupted)
        self.paths[res.trial] = path
        return path


def estimate_message(est: Estimates, session: str, trial: int, seen: int, seconds: float
                     ) -> dict[str, Any]:
    """The fields of an `estimate/person` message from one row of `Estimates`."""
    params = []
    for j, name in enumerate(est.names):
        value, low, high = (float(est.estimate[0, j]), float(est.low[0, j]),
                            float(est.high[0, j]))
        prob = float(est.probability[0, j])
        params.append(m.ParamEstimate(
            name=name, estimate=value, low=min(low, value), high=max(high, value),
            probability=None if math.isnan(prob) else min(max(prob, 0.0), 1.0)))
    return {"session": session, "trial": trial, "trials_seen": seen,
            "seconds": round(min(seconds, 3600.0), 6), "params": tuple(params)}


class EstimateService:
    """The fabric's side: the session's paths in, one estimate per result out (a worker)."""

    def __init__(self, node: Node, layout: TableLayout) -> None:
        self.node = node
        self.layout = layout
        self.paths = SessionPaths()
        self.pub = node.publisher("estimate/person")
        self._todo: queue.Queue[tuple[str, int, list[TrialPath]] | None] = queue.Queue()
        node.subscribe("experiment/trial", self.paths.on_trial)
        node.subscribe("eyes/cmd", self.paths.on_gaze)
        node.subscribe("vision/hand", self.paths.on_hand)
        node.subscribe("experiment/result", self.on_result)
        self._worker: threading.Thread | None = None

    def start(self, estimators: ByLength) -> None:
        """The estimators are ready: estimate every trial heard so far, then each as it ends."""
        self._worker = threading.Thread(target=self._work, args=(estimators,),
                                        name="estimate", daemon=True)
        self._worker.start()

    def on_result(self, res: m.TrialResult) -> None:
        """A trial ended: estimate from the session's trials so far (on the worker)."""
        if self.paths.on_result(res) is None and res.session != self.paths.session:
            return
        paths = [self.paths.paths[k] for k in sorted(self.paths.paths) if k <= res.trial]
        self._todo.put((res.session, res.trial, paths))

    def _work(self, estimators: ByLength) -> None:
        top = max(estimators.at)
        while (item := self._todo.get()) is not None:
            session, trial, paths = item
            k = min(trial, top)
            t1 = time.perf_counter()
            est = estimate_after(estimators, k, paths, self.layout)
            seconds = time.perf_counter() - t1
            seen = sum(1 for p in paths if 1 <= p.trial <= k)
            with self.node.lock:
                self.pub.put(**estimate_message(est, session, trial, seen, seconds))
            log.info("trial %d: estimated from %d of %d trials in %.0f ms", trial, seen, k,
                     seconds * 1e3)

    def close(self) -> None:
        """Let the worker end."""
        self._todo.put(None)


def build_parser() -> argparse.ArgumentParser:
    """The command line of `nod estimate`."""
    p = service_parser(
        "nod estimate",
        "Estimate the participant's parameters after each trial (nod fit's estimator for "
        "partial sessions) and publish them on estimate/person.")
    p.add_argument("--person", type=Path, default=None, metavar="FILE.toml",
                   help="the simulated person's traits the prior is drawn over (as `nod fit "
                   "--params`; default: the cohort fitted to the paper)")
    p.add_argument("--prior", default=None, metavar="FILE.toml|cohort",
                   help="what people may differ in (as `nod fit --prior`)")
    p.add_argument("--table", type=int_in(20, 10**6), default=K_LIVE, metavar="K",
                   help=f"simulated people the estimators learn from ({K_LIVE})")
    p.add_argument("--cache", type=Path, default=None, metavar="DIR",
                   help="where tables are kept (as `nod fit --cache`)")
    return p


def main(argv: list[str] | None = None) -> int:
    """Run the estimator service until SIGINT/SIGTERM."""
    args = build_parser().parse_args(argv)
    setup_logging(args.verbose)
    from services.cohort.person import load_cohort_params
    from services.fit.pipeline import prepare_by_length
    from services.fit.prior import load_prior
    from services.fit.simulate import Population, default_cache

    try:
        cfg, _ = load_with_options(args.params, None)
        pop = Population(load_cohort_params(args.person), load_prior(args.prior))
        node = Node("estimate", Fabric.from_args(args), retry_s=math.inf,
                    params_hash=params_hash(cfg))
    except (ValueError, OSError, ConnectionError) as exc:
        return fail("nod estimate", exc)
    service = EstimateService(node, cfg.layout)  # hears the trials while it prepares
    try:
        t0 = time.monotonic()
        # One core, serially: the rig's services keep the others (`nod fit recovery
        # --by-length --table K` builds the same cached table faster on a cluster).
        estimators = prepare_by_length(pop, args.table, lambda fn, jobs: [fn(j) for j in jobs],
                                       args.cache or default_cache())[1]
        log.info("estimators after 1-%d trials ready (%.0f s)", max(estimators.at),
                 time.monotonic() - t0)
        service.start(estimators)
        node.run()  # alive (its token) only now: a conductor waits for estimates from then on
    except KeyboardInterrupt:
        return 130
    except (ValueError, OSError) as exc:
        return fail("nod estimate", f"the estimator could not be prepared: {exc}")
    finally:
        service.close()
        node.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
