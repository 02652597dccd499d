"""`nod experiment`: the conductor of one participant's session.

It drives the protocol state machine (`services.model.protocol.SessionProtocol`, the same one
the offline loop drives) and does what its cues say: command the gaze (the attention gesture's
poses too), announce the setup (decision and actuation reset), count "1, 2, 3, go", record the
streams, and at the end of a trial (the human's press or the timeout, then the robot's press)
judge it, store it with its samples in one SQLite transaction, and publish the result.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
import uuid
from collections import OrderedDict
from collections.abc import Callable
from pathlib import Path

from services.core import messages as m
from services.core.cli import Parser, add_service_args
from services.core.config import load_params
from services.core.node import Node, install_signal_handlers, setup_logging
from services.core.session import Fabric
from services.experiment.recorder import TrialRecorder
from services.model.outcome import OutcomeTracker, judge_trial
from services.model.params import NodConfig
from services.model.protocol import Cue, SessionProtocol, TrialSpec
from services.store import Store, TrialRecord

log = logging.getLogger("nod.experiment")
NS = 1e-9
REQUIRED = ("decision", "actuation", "eyes", "vision")
SAMPLE_HZ = 60.0  # stored samples are decimated to this rate (a 30 Hz camera passes whole)
# The gaze is repeated this often: the eyes' watchdog holds them neutral when it goes stale
# (250 ms), so the keep-alive runs 5x faster than that bound, with room for a busy host.
GAZE_KEEPALIVE_NS = 50_000_000


class Conductor:
    """Runs the protocol over the fabric; callbacks fill the current trial's recorder."""

    def __init__(
        self, node: Node, cfg: NodConfig, store: Store, clicks: Callable[[int], int | None]
    ):
        self.node = node
        self.cfg = cfg
        self.proto = cfg.protocol
        self.layout = cfg.layout
        self.store = store
        self.clicks = clicks
        self.alive: dict[str, bool] = {}
        self.recorder: TrialRecorder | None = None
        self.robot_press: m.PressMsg | None = None
        self.trial = 0
        self.gaze_msg: dict[str, object] | None = None
        self._keepalive_ns = 0
        self.session = ""
        self.records: list[TrialRecord] = []
        self._hands: OrderedDict[int, m.HandPose] = OrderedDict()
        self.pub_trial = node.publisher("experiment/trial")
        self.pub_result = node.publisher("experiment/result")
        self.pub_gaze = node.publisher("eyes/cmd")
        node.subscribe("vision/hand", self.on_hand)
        node.subscribe("vision/layout", lambda msg: setattr(self, "layout", m.layout_from_msg(msg)))
        node.subscribe("decision/z_h", lambda msg: self._scalar("z_h", msg))
        node.subscribe("decision/z_r", lambda msg: self._scalar("z_r", msg))
        node.subscribe("decision/b_r", lambda msg: self._scalar("b_r", msg))
        node.subscribe("actuation/state", self.on_arm)
        node.subscribe("actuation/press", self.on_press)
        for service in REQUIRED:
            node.watch_liveliness(service, lambda a, s=service: self.alive.__setitem__(s, a))

    # -- callbacks (under the node lock) ---------------------------------------------------

    def on_hand(self, pose: m.HandPose) -> None:
        """Keep recent poses to join with decision outputs; detect the human's press."""
        self._hands[pose.seq] = pose
        while len(self._hands) > 256:
            self._hands.popitem(last=False)
        if self.recorder is not None:
            self.recorder.on_hand(pose, self.layout)

    def _scalar(self, name: str, msg: m.Scalar) -> None:
        if self.recorder is not None:
            self.recorder.on_scalar(name, msg, self._hands.get(msg.src_seq))

    def on_arm(self, msg: m.ArmStateMsg) -> None:
        """The arm's end effector, for the samples."""
        if self.recorder is not None:
            self.recorder.on_arm(msg)

    def on_press(self, msg: m.PressMsg) -> None:
        """The robot pressed a buzzer."""
        if msg.trial == self.trial:
            self.robot_press = msg

    # -- the script (main thread) ----------------------------------------------------------

    def _now_s(self) -> float:
        return self.node.clock.now_ns() * NS

    def wait_for_services(self, timeout_s: float) -> None:
        """Block until every required service's liveliness token is seen (wall clock)."""
        deadline = time.monotonic() + timeout_s
        while not all(self.alive.get(s) for s in REQUIRED):
            if time.monotonic() > deadline or self.node.stop.is_set():
                missing = [s for s in REQUIRED if not self.alive.get(s)]
                raise TimeoutError(f"services not alive after {timeout_s:.0f} s: {missing}")
            time.sleep(0.02)

    def run_session(self, session: str, participant: str, seed: int | None) -> list[TrialRecord]:
        """Run every trial of the schedule through the protocol machine; store the records."""
        started = self.node.clock.now_ns()
        self.store.begin_session(
            session, participant, self.node.keys.rig, seed, started, self.cfg.summary()
        )
        self.session = session
        self.records = []
        protocol = SessionProtocol(self.proto)
        status = "aborted"
        try:
            with self.node.lock:
                cues = protocol.start(self._now_s())
            while True:
                self._perform(protocol, cues)
                if protocol.done:
                    break
                self._wait(protocol.next_due())
                with self.node.lock:
                    rec = self.recorder
                    cues = protocol.advance(
                        self._now_s(),
                        human_pressed=rec is not None and rec.human is not None,
                        robot_pressed=self.robot_press is not None,
                    )
            status = "complete"
        finally:
            self.store.finish_session(session, self.node.clock.now_ns(), status)
            self.gaze_msg = None
            self.pub_trial.put(
                phase="session_end" if status == "complete" else "abort",
                trial=self.trial,
                session=session,
                text=status,
            )
        return self.records

    def _wait(self, due_s: float) -> None:
        """Sleep until the protocol's next deadline (or ≤ 5 ms), keeping the gaze alive."""
        end_ns = min(int(due_s * 1e9), self.node.clock.now_ns() + 5_000_000)
        while not self.node.stop.is_set():
            now = self.node.clock.now_ns()
            with self.node.lock:
                if self.gaze_msg is not None and now - self._keepalive_ns >= GAZE_KEEPALIVE_NS:
                    self.pub_gaze.put(t_ns=now, **self.gaze_msg)
                    self._keepalive_ns = now
            if now >= end_ns:
                return
            self.node.stop.wait(min(0.005, self.node.clock.wall_seconds((end_ns - now) * NS)))
        raise KeyboardInterrupt

    def _perform(self, protocol: SessionProtocol, cues: list[Cue]) -> None:
        """Do what the protocol asks, in order (an "end" cue may bring the next trial's cues)."""
        while cues:
            cue = cues.pop(0)
            spec = cue.trial
            if spec is None:  # session_end: run_session publishes it once the store is closed
                continue
            ev = {"trial": spec.index, "mode": spec.mode, "option": spec.option}
            if cue.kind == "gaze" and cue.gaze is not None:
                with self.node.lock:
                    self.gaze_msg = {
                        "yaw": cue.gaze.yaw,
                        "pitch": cue.gaze.pitch,
                        "level": spec.gaze_level,
                        "gesture": cue.gesture,
                        "trial": spec.index,
                    }
                    self.pub_gaze.put(**self.gaze_msg)
                    self._keepalive_ns = self.node.clock.now_ns()
            elif cue.kind == "setup":
                with self.node.lock:
                    self.trial = spec.index
                    self.robot_press = None
                    self.recorder = None
                    self.pub_trial.put(phase="setup", text=cue.text, session=self.session, **ev)
            elif cue.kind == "countdown":
                self.pub_trial.put(phase="countdown", text=cue.text, session=self.session, **ev)
            elif cue.kind == "go":
                with self.node.lock:
                    go = self.pub_trial.put(
                        phase="go", text=cue.text, session=self.session, **ev
                    )
                    tracker = OutcomeTracker(self.cfg.debounce, self.layout.commit)
                    self.recorder = TrialRecorder(go.t_ns, tracker)
            elif cue.kind == "end":
                self._end_trial(spec, protocol)
                cues.extend(protocol.judged(self._now_s()))

    def _end_trial(self, spec: TrialSpec, protocol: SessionProtocol) -> None:
        """Judge, store and publish the trial that just ended."""
        with self.node.lock:
            rec, self.recorder = self.recorder, None
            t_end = self.node.clock.now_ns()
            robot = self.robot_press.colour if self.robot_press else None
        assert rec is not None and protocol.end is not None  # "go" precedes every "end"
        self.pub_trial.put(
            phase="end", trial=spec.index, mode=spec.mode, option=spec.option, session=self.session
        )
        clicks = self.clicks(spec.index)
        j = judge_trial(rec.tracker, rec.human, robot, clicks, self.proto.target_clicks)
        record = TrialRecord(
            trial=spec.index,
            mode=spec.mode,
            option=spec.option,
            gaze_level=spec.gaze_level,
            yaw=spec.gaze.yaw,
            pitch=spec.gaze.pitch,
            t_go_ns=rec.t_go_ns,
            t_end_ns=t_end,
            human=j.human,
            robot=j.robot,
            outcome=j.outcome,
            switches=j.switches,
            violations=j.violations,
            clicks=clicks,
            score=j.score,
            end_reason=protocol.end.reason,
        )
        self.store.write_trial(self.session, record, rec.samples(SAMPLE_HZ))
        self.records.append(record)
        self.pub_result.put(
            trial=spec.index,
            mode=spec.mode,
            option=spec.option,
            robot=j.robot,
            human=j.human,
            outcome=j.outcome,
            switches=j.switches,
            violations=j.violations,
            score=j.score,
            session=self.session,
        )


def ask_clicks(trial: int) -> int | None:
    """Prompt the operator for the counter value of a trial (empty → not entered)."""
    while True:
        try:
            raw = input(f"trial {trial}: counter clicks (empty = not entered)? ").strip()
        except EOFError:
            return None
        if not raw:
            return None
        if raw.isdigit():
            return int(raw)
        print("please enter a non-negative whole number, or nothing")


def build_parser() -> argparse.ArgumentParser:
    """The command line of `nod experiment`."""
    p = Parser(
        prog="nod experiment",
        description="Conduct one participant's 8 trials and store them in a SQLite file.",
    )
    add_service_args(p)
    p.add_argument("--db", type=Path, default=Path("nod-sessions.sqlite"), help="session store")
    p.add_argument("--participant", default="P01", help="participant id stored with the session")
    p.add_argument("--seed", type=int, default=None, help="seed of the sim participant (stored)")
    p.add_argument("--session", default=None, help="session id (default: a new UUID)")
    p.add_argument(
        "--clicks",
        default="prompt",
        help="counter clicks the operator counted: a number for every trial, or 'prompt' (ask "
        "after each trial), or 'none' (not entered)",
    )
    p.add_argument("--wait-services", type=float, default=30.0, help="seconds to wait for peers")
    return p


def clicks_source(spec: str) -> Callable[[int], int | None]:
    """The operator's counter values, from the --clicks flag."""
    if spec == "prompt":
        return ask_clicks
    if spec == "none":
        return lambda _trial: None
    if spec.isdigit():
        return lambda _trial: int(spec)
    raise ValueError(f"--clicks must be a number, 'prompt' or 'none', got {spec!r}")


def main(argv: list[str] | None = None) -> int:
    """Run one session; exit 0 when every trial is stored."""
    args = build_parser().parse_args(argv)
    setup_logging(args.verbose)
    try:
        cfg = load_params(args.params)
        clicks = clicks_source(args.clicks)
        store = Store(args.db)
        node = Node("experiment", Fabric.from_args(args))
    except (ValueError, OSError, ConnectionError) as exc:
        print(f"nod experiment: {exc}", file=sys.stderr)
        return 2
    for session, done in store.interrupted_sessions():
        log.warning(
            "session %s was interrupted after %d stored trial(s); its unfinished trial was lost",
            session,
            done,
        )
    install_signal_handlers(node.stop)
    conductor = Conductor(node, cfg, store, clicks)
    node.ready()
    session = args.session or uuid.uuid4().hex[:12]
    try:
        conductor.wait_for_services(args.wait_services)
        log.info(
            "session %s: all services alive; starting %d trials", session, len(cfg.protocol.trials)
        )
        conductor.run_session(session, args.participant, args.seed)
    except TimeoutError as exc:
        print(f"nod experiment: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        log.warning("session %s interrupted", session)
        return 130
    finally:
        node.close()
        store.close()
    log.info("session %s complete: %s", session, json.dumps(str(args.db)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
