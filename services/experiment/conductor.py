"""The conductor of one participant's session on the fabric, for any number of options.

It drives the protocol state machine (`services.model.protocol.SessionProtocol`, the same one
the offline loop drives) and does what its cues say: command the gaze (the attention gesture's
poses too), announce the setup (decision and actuation reset), count "1, 2, 3, go", record the
streams, and at the end of a trial (the human's press or the timeout, then the robot's press)
judge it (the key space's judge, `services.model.judge`), store it with its samples and its
cues as played (`nod speaker`, `services.experiment.cues`) in one SQLite transaction, and
publish the result. `nod experiment` (`services.experiment.service`) is its command line.

One conductor for every option set, on one key space (schema 3, options by name): what
differs by the number of options — the trials' source, the judge, O as a colour or a box index
— is the session's form (`services.experiment.keyspace`), chosen by the option count.
Everything else here (the operator gate, the cues as played, the console, the samples, the
recorder's link, resume, the rig watch, interruptions, the clicks prompt) is written once, in
option names.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import math
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from pathlib import Path
from typing import Any

from services.core import messages as m
from services.core.node import Node
from services.experiment.console import SessionConsole
from services.experiment.cues import CueLog
from services.experiment.fields import GazeFields, TrialFields
from services.experiment.hold import SessionHold
from services.experiment.keyspace import ArmReading, KeySpace, Output, PaperKeys
from services.experiment.operator import EnterStarts, OperatorGate
from services.experiment.policy_link import PolicyChoice, PolicyLink
from services.experiment.presses import Box, RobotPresses
from services.experiment.resume import attempts_so_far, file_open_attempt
from services.experiment.rig_watch import RigWatch
from services.experiment.trial_samples import TrialSamples
from services.experiment.waiting import wait_for_services
from services.model.judge import TrialJudge
from services.model.params import NodConfig
from services.model.protocol import Cue, SessionProtocol, TrialEnd, TrialSpec
from services.model.scoring import points_said
from services.store import Interruption, Store, TrialRecord
from services.store.estimates import ParamRow, TrialEstimate, write_estimate

log = logging.getLogger("nod.experiment")
NS = 1e-9
REQUIRED = ("decision", "actuation", "eyes", "vision")
SAMPLE_HZ = 60.0  # stored samples are decimated to this rate (a 30 Hz camera passes whole)
# The gaze is repeated this often: the eyes' watchdog holds them neutral when it goes stale
# (250 ms), so the keep-alive runs 5x faster than that bound, with room for a busy host.
GAZE_KEEPALIVE_NS = 50_000_000
# At a session's start the rig is held for a moment on every normal run (the eyes wait for the
# first gaze, then it settles 0.5 s): only a hold longer than this (wall s), or an e-stop, is
# shown to the operator.
START_QUIET_S = 3.0
# At a session's end, how long (wall s) the conductor waits for the last trial's estimate when
# an estimator (`nod estimate`) is alive: every trial is stored before, so this delays only the
# session's end line, and only while an estimate is owed.
ESTIMATE_WAIT_S = 5.0


class Conductor:
    """Runs the protocol over the fabric; callbacks fill the current trial's samples."""

    def __init__(
        self,
        node: Node,
        cfg: NodConfig,
        store: Store,
        clicks: Callable[[int], int | None],
        console: SessionConsole | None = None,
        resume_at: tuple[int, int] | None = None,
        keys: KeySpace | None = None,
        policy: PolicyChoice | None = None,
    ):
        """The conductor of one session on `node`'s rig, storing into `store`.

        `resume_at`: the (trial, attempt) a resumed session is in — the one a lost conductor
        left open, or the last one stored — so the safety events seen before its next trial
        starts (a device's safe stop while no conductor ran) are filed under it, not trial 0.
        `keys`: the session's key space (its configuration is the session's); default the
        paper's two options on `cfg`.
        `policy`: the robot policy that chooses each trial's b*, gaze level and u_r
        (`services.experiment.policy_link`); None: the paper's robot, with nothing sent.
        """
        self.node = node
        self.console = console or SessionConsole()
        self.console.interrupt = node.stop  # a prompt waiting for the operator ends on SIGINT
        self.keys = keys if keys is not None else PaperKeys(cfg)
        self.cfg = cfg = self.keys.cfg
        self.proto = dataclasses.replace(cfg.protocol, trials=self.keys.trials)
        self.layout = self.keys.layout()
        self.store = store
        self.clicks = clicks
        self.alive: dict[str, bool] = {}
        self.trial_samples: TrialSamples | None = None
        self.presses = RobotPresses()
        self.trial = 0
        self.gaze_msg: GazeFields | None = None
        self.session = ""
        self.records: list[TrialRecord] = []
        self.rig = RigWatch()
        if resume_at is not None:
            self.rig.begin(*resume_at)
        self.hold = SessionHold(self.rig, self.console.note)
        self.protocol: SessionProtocol | None = None
        self._trial_start_ns = 0
        self._hands: OrderedDict[int, m.HandPose] = OrderedDict()
        self._last_hand_seq: int | None = None
        self._seq_regressions = 0  # in the current trial
        self.recording: tuple[Path, int] | None = None  # (file, started_ns) of `--record`
        self.pub_trial, self.pub_result = self.keys.publishers(node)
        self.pub_gaze = node.publisher("eyes/cmd")
        node.subscribe("vision/hand", self.on_hand)
        self.keys.wire(node, self)  # layout, decision outputs, the arm's state, its press
        node.subscribe("eyes/state", self.on_eyes)
        node.subscribe("safety/estop", self.on_estop)
        node.subscribe("safety/release", self.on_estop)
        node.subscribe("rig/event", lambda msg: self.rig.rig_event(self._now_ns(), msg))
        self.gate = OperatorGate()
        node.subscribe("experiment/operator", self.on_operator)
        if policy is not None and len(self.keys.names) != 2:
            raise ValueError("a robot policy runs on the paper's two-option table only")
        self.policy = PolicyLink(node, cfg, store, policy) if policy is not None else None
        # The person's estimate after each trial (`nod estimate`, when one runs): taken on the
        # fabric's thread, stored by the session's (the store's one writer).
        self._estimates: list[m.PersonEstimate] = []
        self._estimated = 0  # the last trial whose estimate is stored
        node.subscribe("estimate/person", self.on_estimate)
        self.enter_starts = EnterStarts(self.console, self.gate, node.lock)
        self.cues = CueLog()  # the countdown as played, stored with its trial
        node.subscribe("speaker/played", self.cues.on_played)
        for service in REQUIRED:
            node.watch_liveliness(service, functools.partial(self._liveliness, service))
        # An e-stop engaged while no conductor ran (or before this one started) holds the session
        # from the start: the devices answer with their latches.
        for latch in node.ask("safety/latch", 1.0):
            if latch.engaged:
                with node.lock:
                    self.rig.estop(True, latch.reason, latch.source or latch.service,
                                   self._now_ns())
        # The gaze keep-alive runs on its own thread: the operator's counter prompt blocks the
        # main thread, and the eyes must not drop to neutral while the operator types.
        self._keepalive = threading.Thread(target=self._keep_gaze_alive, daemon=True)
        self._keepalive.start()

    # -- callbacks (under the node lock) ---------------------------------------------------

    def _liveliness(self, service: str, alive: bool) -> None:
        was = self.alive.get(service, False)
        self.alive[service] = alive
        if was and not alive:  # during a trial this breaks it; between trials it holds the next
            self.rig.lost(service, self._now_ns())

    def on_hand(self, pose: m.HandPose) -> None:
        """Keep recent poses to join with decision outputs; detect the human's press.

        One camera numbers its poses in order; a pose numbered at or below the last one means
        a second publisher on the key (a restarted camera starts over once). Three in a trial
        and the trial is interrupted: its press could be anyone's.
        """
        if self._last_hand_seq is not None and pose.seq <= self._last_hand_seq:
            self._seq_regressions += 1
            if self._seq_regressions == 3:
                self.rig.compromised(
                    "two publishers on vision/hand (its seq went backwards 3 times)",
                    self._now_ns(),
                )
        self._last_hand_seq = pose.seq
        self._hands[pose.seq] = pose
        while len(self._hands) > 256:
            self._hands.popitem(last=False)
        if self.trial_samples is not None:
            self.trial_samples.on_hand(pose)

    def on_output(self, name: str, out: Output) -> None:
        """A decision output: on the console (a scalar), into the trial's samples and judge."""
        if out.value is not None:
            self.console.value(name, out.value)
        if self.trial_samples is not None:
            self.trial_samples.on_output(name, out, self._hands.get(out.src_seq))

    def on_layout(self, layout: Any) -> None:
        """The table the camera (or the sim) sees: judged from the next trial's "go"."""
        self.layout = layout

    def on_arm(self, arm: ArmReading) -> None:
        """The arm's end effector for the samples, and its safety state."""
        self.rig.device_state("actuation", arm.safe_stop, arm.safety_reason, self._now_ns())
        self.presses.arm_state(arm.trial, arm.phase, arm.target)
        self.console.robot(arm.phase, self.keys.name(arm.target))
        if self.trial_samples is not None:
            self.trial_samples.on_arm(arm.ee)

    def on_eyes(self, msg: m.EyesStateMsg) -> None:
        """The eyes' safety state."""
        self.rig.device_state("eyes", msg.safe_stop, msg.safety_reason, self._now_ns())

    def on_estop(self, msg: m.Estop) -> None:
        """An e-stop command: it breaks a running trial and holds the session until released."""
        self.rig.estop(msg.engaged, msg.reason, msg.source, self._now_ns())

    def on_operator(self, msg: m.OperatorCmd) -> None:
        """The operator's command: the start gate's (start, pause), or the policy's freeze."""
        if msg.action != "freeze":
            self.gate.command(msg)
        elif self.policy is None:  # nothing to freeze: no confirmation is sent
            log.warning("freeze from %s: this session runs no robot policy", msg.source or "?")
        else:
            self.policy.freeze(msg.source)
            self.console.note("robot policy frozen: its last settings hold for the session")

    def on_estimate(self, msg: m.PersonEstimate) -> None:
        """An estimate of this session's participant: kept for the session's thread to store."""
        if msg.session == self.session and self.session:
            self._estimates.append(msg)

    def _store_estimates(self) -> None:
        """Store the estimates heard since the last call (main thread)."""
        with self.node.lock:
            heard, self._estimates = self._estimates, []
        for e in heard:
            rows = tuple(ParamRow(p.name, p.estimate, p.low, p.high, p.probability)
                         for p in e.params)
            write_estimate(self.store, self.session,
                           TrialEstimate(e.trial, e.trials_seen, e.seconds, rows))
            self._estimated = max(self._estimated, e.trial)

    def _await_last_estimate(self) -> None:
        """Wait (at most ESTIMATE_WAIT_S) for the last stored trial's estimate, if one is owed."""
        if not self.records or not self.node.peer_alive("estimate"):
            return
        last = self.records[-1].trial
        deadline = time.monotonic() + ESTIMATE_WAIT_S
        while self._estimated < last and time.monotonic() < deadline:
            if self.node.stop.wait(0.02):
                return
            self._store_estimates()
        if self._estimated < last:
            log.warning("no estimate of trial %d came within %g s of the session's end",
                        last, ESTIMATE_WAIT_S)

    def on_press(self, trial: int, option: Box) -> None:
        """The robot pressed a box: taken once the arm's own state confirms it."""
        self.presses.press(trial, option)

    # -- the script (main thread) ----------------------------------------------------------

    def _now_ns(self) -> int:
        return self.node.clock.now_ns()

    def _now_s(self) -> float:
        return self.node.clock.now_ns() * NS

    def wait_for_services(self, timeout_s: float) -> None:
        """Block until every required service's liveliness token is seen (wall clock)."""
        wait_for_services(self.node, self.alive, REQUIRED, timeout_s)

    def run_session(
        self,
        session: str,
        participant: str,
        seed: int | None,
        first_trial: int = 1,
        resume: bool = False,
        lost: tuple[int, int, int] | None = None,
    ) -> list[TrialRecord]:
        """Run the schedule from `first_trial` through the protocol machine; store the records.

        A trial broken by a safe stop or an e-stop is stored as interrupted; the session waits
        until the rig is safe again, then repeats it (or moves on, as the protocol says).
        `lost` is the attempt (trial, attempt, t_start_ns) a previous conductor of this session
        left open when it died: stored as an interruption, then repeated or moved past alike.
        """
        started = self.node.clock.now_ns()
        if resume and (ran := self.store.option_names(session)) != self.keys.names:
            # `resume_problem` refuses it before anything is written: a guard
            raise ValueError(f"session {session} ran the options {list(ran)}, not "
                             f"{list(self.keys.names)}")
        if not resume:
            self.store.begin_session(
                session, participant, self.node.keys.rig, seed, started, self.keys.summary(),
                self.keys.names,
            )
        if self.recording is not None:
            self.store.add_recording(session, *self.recording)
        self.session = session
        self.records = []
        with self.node.lock:
            self.node.activity = {"session": session, "participant": participant[:200]}
        self.console.start(session, participant, len(self.proto.trials))
        for _, t in self.store.trials(session) if resume else []:  # the panel goes on from them
            self.console.result(t.trial, t.mode, t.option, t.robot, t.human, t.outcome, t.score,
                                t.interrupted)
        status = "aborted"
        try:
            first_trial, attempts_before = self._attempts_so_far(first_trial, lost)
            if first_trial > len(self.proto.trials):  # the lost attempt was the last one's last
                status = "complete"
                return self.records
            if self.policy is not None:  # its history: the trials stored before a resume
                self.policy.begin(session, [t for _, t in self.store.trials(session)])
            protocol = self.protocol = SessionProtocol(
                self.proto, first_trial, attempts_before,
                planner=self.policy.plan if self.policy is not None else None)
            self._wait_for_a_safe_rig()
            with self.node.lock:
                cues = protocol.start(self._now_s())
            while True:
                self._perform(protocol, cues)
                if protocol.done:
                    break
                self._wait(protocol.next_due())
                with self.node.lock:
                    why = self.rig.interruption(self._now_ns()) if protocol.running_trial else None
                    if why is not None:
                        cues = protocol.interrupt(self._now_s(), why)
                        continue
                    if protocol.phase == "paused":
                        cues = protocol.resume(self._now_s()) if self._rig_ready() else []
                        continue
                    if protocol.phase == "rest" and not self._rig_ready():
                        cues = []  # no new trial on an unsafe rig: the rest lasts until it is
                        continue
                    cues, note = self.gate.step(
                        protocol, protocol.waiting_for_operator and self._rig_ready(),
                        self._now_s(),
                    )
                    if note:
                        log.info("%s", note)
                        self.console.note(note)
                    if protocol.waiting_for_operator and not cues and protocol.trial:
                        self.enter_starts.offer(protocol.trial.index)
                    elif cues:
                        self.enter_starts.withdraw()
                    if cues or protocol.waiting_for_operator:
                        continue
                    rec = self.trial_samples
                    cues = protocol.advance(
                        self._now_s(),
                        human_pressed=rec is not None and rec.human is not None,
                        robot_pressed=self.presses.confirmed is not None,
                    )
            status = "complete"
            self._await_last_estimate()
        finally:
            self.enter_starts.withdraw()
            self._store_estimates()
            with self.node.lock:
                events = self.rig.take_events()
            self.store.write_events(session, events)
            self.store.finish_session(session, self.node.clock.now_ns(), status)
            with self.node.lock:
                self.gaze_msg = None
                self.node.activity = {}  # no session under way
            self.pub_trial.put(**self.keys.trial_event(
                phase="session_end" if status == "complete" else "abort",
                trial=self.trial,
                session=session,
                text=status,
            ))
            self.console.stop()
        return self.records

    def stop_mid_trial(self, why: str) -> bool:
        """The conductor is stopped (SIGINT, SIGTERM): store the attempt under way as interrupted.

        Without this a stop by the operator looked like a crash: the resumed session filed the
        open attempt as "conductor lost". Returns whether an attempt was open.
        """
        lost = self.store.open_attempt(self.session) if self.session else None
        if lost is not None:
            self._file_open_attempt(lost, why)
        return lost is not None

    def _file_open_attempt(self, lost: tuple[int, int, int], why: str) -> None:
        """Store an attempt left open, (trial, attempt, t_start_ns), as an interruption."""
        with self.node.lock:
            self.trial_samples = None
            events, cues = self.rig.take_events(), self.cues.take()
        file_open_attempt(self.store, self.session, lost, why, self._now_ns(), events, cues)

    def _attempts_so_far(
        self, first_trial: int, lost: tuple[int, int, int] | None
    ) -> tuple[int, int]:
        """(first trial to run, its starts so far): `attempts_so_far`, shared with N options.

        A trial out of attempts before the resume is stored interrupted, never scored.
        """
        return attempts_so_far(
            self.store, self.session, self.proto, first_trial, lost, self._file_open_attempt,
            lambda trial, made, why: self._store_trial(
                self.proto.trials[trial - 1], made, None, None, None, None, why,
                interrupted=True,
            ),
        )

    def _wait_for_a_safe_rig(self) -> None:
        """Before the first trial: eyes neutral (kept alive), then wait until the rig is safe.

        No trial starts on an unsafe rig; the first one too: a device still stopped from its
        start-up (the eyes before any gaze) would otherwise break trial 1 as soon as it began.
        """
        with self.node.lock:
            self.gaze_msg = {"yaw": 0.0, "pitch": 0.0, "level": "neutral", "trial": 0}
            self.pub_gaze.put(**self.gaze_msg)
        quiet_until = time.monotonic() + START_QUIET_S
        while not self._rig_ready(quiet=time.monotonic() < quiet_until):
            self._wait(math.inf)

    def _rig_ready(self, quiet: bool = False) -> bool:
        down = [s for s in REQUIRED if not self.alive.get(s, False)]
        return self.hold.ready(self._now_ns(), quiet, down)

    def _keep_gaze_alive(self) -> None:
        """Repeat the current gaze command every GAZE_KEEPALIVE_NS (rig clock) until closed."""
        period_s = self.node.clock.wall_seconds(GAZE_KEEPALIVE_NS * NS)
        while not self.node.stop.wait(period_s):
            with self.node.lock:
                if self.gaze_msg is not None and self.node.session is not None:
                    self.pub_gaze.put(**self.gaze_msg)

    def _wait(self, due_s: float) -> None:
        """Sleep until the protocol's next deadline, or at most 5 ms (presses, safety)."""
        now = self.node.clock.now_ns()
        end_ns = now + 5_000_000
        if math.isfinite(due_s):  # inf while paused or judging: poll
            end_ns = min(int(due_s * 1e9), end_ns)
        if self.node.stop.wait(max(0.0, self.node.clock.wall_seconds((end_ns - now) * NS))):
            raise KeyboardInterrupt
        if self._estimates:
            self._store_estimates()

    def _perform(self, protocol: SessionProtocol, cues: list[Cue]) -> None:
        """Do what the protocol asks, in order (an "end" cue may bring the next trial's cues)."""
        while cues:
            cue = cues.pop(0)
            spec = cue.trial
            if spec is None:  # session_end: run_session publishes it once the store is closed
                continue
            mode, option = self.keys.trial(spec)
            ev: TrialFields = {"trial": spec.index, "mode": mode, "option": option}
            if cue.kind in ("setup", "countdown", "go", "end", "interrupted"):
                self.console.cue(cue.kind, spec.index, mode, option, cue.text)
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
            elif cue.kind == "setup":
                # On record before anything moves: a conductor killed from here on leaves this
                # attempt open, and the resumed session stores it as interrupted.
                started = self._now_ns()
                self.store.begin_attempt(self.session, spec.index, protocol.attempt, started)
                if self.policy is not None:  # the settings it runs on, stored before it runs
                    self.policy.store_chosen()
                with self.node.lock:
                    self.trial = spec.index
                    self.node.activity["trial"] = spec.index
                    self.presses.begin(spec.index)
                    self.trial_samples = None
                    self.rig.begin(spec.index, protocol.attempt)
                    # A service lost since the rig was judged ready (its loss was heard before
                    # `begin` cleared the last trial's stops) breaks this trial at once.
                    for service in REQUIRED:
                        if not self.alive.get(service, False):
                            self.rig.lost(service, started)
                    self.cues.begin(spec.index, protocol.attempt)
                    self._seq_regressions = 0
                    self._trial_start_ns = started
                    self._event("setup", cue.text, ev)
            elif cue.kind == "countdown":
                self._event("countdown", cue.text, ev)
            elif cue.kind == "go":
                with self.node.lock:
                    if self.policy is not None:  # again: a decision restarted since setup
                        self.policy.send(spec.index)
                    go = self._event("go", cue.text, ev)
                    judge = self.keys.judge(self.layout, mode)
                    self.trial_samples = TrialSamples(go.t_ns, judge)
            elif cue.kind == "end":
                self._end_trial(spec, protocol)
                cues.extend(protocol.judged(self._now_s()))
            elif cue.kind == "interrupted":
                self._interrupted(spec, protocol, cue.text)

    def _event(self, phase: str, text: str, ev: TrialFields) -> Any:
        """Publish a step of a trial on the session's trial key (the sent message)."""
        return self.pub_trial.put(
            **self.keys.trial_event(phase=phase, text=text, session=self.session, **ev)
        )

    def _interrupted(self, spec: TrialSpec, protocol: SessionProtocol, why: str) -> None:
        """Store the broken start of a trial; the session pauses until the rig is safe."""
        with self.node.lock:
            self.trial_samples = None
            events, cues = self.rig.take_events(), self.cues.take()
            now = self._now_ns()
        log.warning("trial %d (attempt %d) INTERRUPTED: %s", spec.index, protocol.attempt, why)
        mode, option = self.keys.trial(spec)
        self._event("interrupted", why[:400], {"trial": spec.index, "mode": mode,
                                                "option": option})
        record = Interruption(spec.index, protocol.attempt, self._trial_start_ns, now, why)
        self.store.write_interruption(self.session, record, events, cues)
        last_chance = (
            not self.proto.repeat_interrupted or protocol.attempt >= self.proto.max_attempts
        )
        if last_chance:  # not repeated: stored as an interrupted trial, never scored
            self._store_trial(
                spec, protocol.attempt, None, None, None, None, f"interrupted: {why}",
                interrupted=True,
            )

    def _end_trial(self, spec: TrialSpec, protocol: SessionProtocol) -> None:
        """Judge, store and publish the trial that just ended."""
        with self.node.lock:
            rec, self.trial_samples = self.trial_samples, None
            robot = self.presses.confirmed
            refused = self.presses.unconfirmed()
            arm = self.presses.where()
        name = self.keys.name
        for box in refused:  # pressed on the key, never shown by the arm: not the robot's
            log.warning(
                "trial %d: a press of %s was never confirmed by the arm's state (last: trial %d, "
                "%s, at %s): refused (forged, or a second actuation?)",
                spec.index, name(box), arm[0], arm[1], name(arm[2]),
            )
        assert rec is not None and protocol.end is not None  # "go" precedes every "end"
        mode, option = self.keys.trial(spec)
        self.pub_trial.put(**self.keys.trial_event(
            phase="end", trial=spec.index, mode=mode, option=option, session=self.session
        ))
        # Stored the moment it ends, its clicks "not entered": the operator's prompt comes after
        # and its answer updates the stored trial. A Ctrl-C, a crash or a lost terminal at the
        # prompt leaves the trial stored once (clicks not entered, `nod clicks` enters them
        # later), never interrupted nor repeated.
        record = self._store_trial(
            spec, protocol.attempt, protocol.end, rec, robot, None, protocol.end.reason,
            announce=False,
        )
        try:
            clicks = self.clicks(spec.index)  # the console's prompt (`nod experiment --clicks`)
        except (KeyboardInterrupt, EOFError):
            self._announce(record)
            raise
        if clicks is not None:
            record = self.store.set_clicks(self.session, spec.index, clicks)
            self.records[-1] = record
        said = points_said(record.human, record.robot, record.violations, record.clicks,
                           self.cfg.protocol.target_clicks)
        self.console.note(f"trial {spec.index}: the participant sees {said}")
        log.info("trial %d: %s", spec.index, said)
        self._announce(record)

    def _store_trial(
        self,
        spec: TrialSpec,
        attempt: int,
        end: TrialEnd | None,
        rec: TrialSamples | None,
        robot: Box | None,
        clicks: int | None,
        reason: str,
        interrupted: bool = False,
        announce: bool = True,
    ) -> TrialRecord:
        """Judge and store a trial (`announce`: then show and publish its result)."""
        if interrupted or rec is None:  # never scored: no outcome, no points
            j = TrialJudge.void()
        else:
            j = rec.judge.verdict(end, robot, clicks)
        with self.node.lock:
            events, cues = self.rig.take_events(), self.cues.take()
        # The judgement's fields (presses, outcome, switches, violations, score) are stored and
        # published as they are, its presses by option name.
        verdict = {**dataclasses.asdict(j), "human": self.keys.name(j.human),
                   "robot": self.keys.name(j.robot)}
        mode, option = self.keys.trial(spec)
        trial: TrialFields = {"trial": spec.index, "mode": mode, "option": option}
        record = TrialRecord(
            **trial, **verdict, gaze_level=spec.gaze_level, yaw=spec.gaze.yaw,
            pitch=spec.gaze.pitch, t_go_ns=rec.t_go_ns if rec is not None else None,
            t_end_ns=self._now_ns(), clicks=clicks, end_reason=reason[:400],
            interrupted=interrupted, attempts=attempt,
        )
        samples = rec.decimated(SAMPLE_HZ) if rec is not None else []
        if rec is not None:  # poses beyond the trial's cap: their count goes on record
            events += rec.drop_records(spec.index, attempt, self._now_ns())
        self.store.write_trial(self.session, record, samples, events, cues)
        self.records.append(record)
        if self.policy is not None:
            self.policy.ended(record)
        if announce:
            self._announce(record)
        return record

    def _announce(self, record: TrialRecord) -> None:
        """Show a stored trial on the console and publish its result (display, LSL, `nod run`)."""
        self.console.result(record.trial, record.mode, record.option, record.robot, record.human,
                            record.outcome, record.score, record.interrupted)
        self.pub_result.put(**self.keys.result(
            trial=record.trial, mode=record.mode, option=record.option, human=record.human,
            robot=record.robot, outcome=record.outcome, switches=record.switches,
            violations=record.violations, score=record.score, session=self.session,
            interrupted=record.interrupted,
        ))
