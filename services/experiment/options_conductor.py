"""The conductor of one participant's N_o-option session on the fabric (`--options N`).

The paper's `SessionProtocol` clock (trials from `OptionsSchedule.timing_specs`) acted on
over the `options/*` keys: the gaze toward O's box on `eyes/cmd` (kept alive at 20 Hz), the
setup, countdown and "go" on `options/trial` (decision and actuation reset, the sim listens),
then at the end `OptionsTrialJudge` on the poses (`vision/hand`) and ẑ_h vectors
(`options/z_h`) from "go" to the human's press, with the robot's press (`options/press`); the
trial goes into the store's one `trials` table by option name, with the session's option set,
and out on `options/result`.

Safety as the paper's conductor: the devices' states (`options/arm_state`, `eyes/state`), the
e-stop and the services' liveliness feed a `RigWatch`; a stop breaks the running trial, which
is stored as an interruption (`interruptions`, with its safety events) and repeated once the
rig is safe again, up to `max_attempts` (then stored interrupted, never scored); no trial
starts on an unsafe rig.

Resume as the paper's conductor (`services.experiment.resume`, one code for both): a resumed
session goes on at its first trial not stored, with the starts that trial already had; the
attempt a dead conductor left open is stored as the interruption it was; the trials stored
before are kept in `results`. Not here yet (the paper's conductor has them): the operator gate
beyond opening it at once, samples, cues as played, the recorder.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import math
import threading
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import replace
from typing import TypedDict

from services.core import messages as m
from services.core import options_messages as om
from services.core.node import Node
from services.core.options_messages import check_count, same_count, values_for
from services.experiment.fields import GazeFields
from services.experiment.hold import SessionHold
from services.experiment.resume import attempts_so_far, file_open_attempt
from services.experiment.rig_watch import RigWatch
from services.experiment.waiting import wait_for_services
from services.model.geometry import OptionsLayout, Point
from services.model.judge import OptionsTrialJudge
from services.model.params import NodConfig
from services.model.protocol import Cue, Mode, SessionProtocol
from services.model.schedule import OptionsSchedule
from services.store import Interruption, Store, TrialRecord

log = logging.getLogger("nod.experiment")
NS = 1e-9
REQUIRED = ("decision", "actuation", "eyes", "vision")
GAZE_KEEPALIVE_S = 0.05  # rig seconds; the eyes' watchdog holds them neutral after 250 ms


class TrialFields(TypedDict):
    """The trial every `options/trial` event of one cue names."""

    n_options: int
    trial: int
    mode: Mode
    option: int | None
    session: str


class OptionsConductor:
    """Runs an N_o-option session over the fabric and stores it."""

    def __init__(
        self,
        node: Node,
        cfg: NodConfig,
        schedule: OptionsSchedule,
        layout: OptionsLayout,
        store: Store,
        clicks: Callable[[int], int | None],
        resume_at: tuple[int, int] | None = None,
    ) -> None:
        """The conductor of one session of `schedule` on `node`'s rig, storing into `store`.

        `resume_at`: the (trial, attempt) a resumed session stands in, as the paper's
        `Conductor` takes it: the safety events heard before its next trial starts are filed
        under it, not under trial 0.
        """
        self.node = node
        self.cfg = cfg
        self.schedule = schedule
        self.n = schedule.n_options
        self.layout = layout
        self.store = store
        self.clicks = clicks
        self.params = replace(cfg.protocol, trials=schedule.timing_specs(layout))
        self.alive: dict[str, bool] = {}
        self.session = ""
        self.judge: OptionsTrialJudge | None = None
        self.robot: int | None = None
        self.trial = 0
        self.t_go_ns: int | None = None
        self.gaze_msg: GazeFields | None = None
        self.results: list[TrialRecord] = []  # option, human, robot by name
        self._centers: OrderedDict[int, Point] = OrderedDict()  # recent poses' hand centres
        self.rig = RigWatch()
        if resume_at is not None:
            self.rig.begin(*resume_at)
        self.hold = SessionHold(self.rig)
        self._trial_start_ns = 0
        self.pub_trial = node.publisher("options/trial")
        self.pub_result = node.publisher("options/result")
        self.pub_gaze = node.publisher("eyes/cmd")
        node.subscribe("vision/hand", self.on_hand)
        node.subscribe("options/z_h", self.on_z_h)
        node.subscribe("options/press", self.on_press)
        node.subscribe("options/layout", self.on_layout)
        node.subscribe("options/arm_state", self.on_arm)
        node.subscribe("eyes/state", self.on_eyes)
        node.subscribe("safety/estop", self.on_estop)
        node.subscribe("safety/release", self.on_estop)
        for service in REQUIRED:
            node.watch_liveliness(service, functools.partial(self._liveliness, service))
        threading.Thread(target=self._keep_gaze_alive, daemon=True).start()

    # -- callbacks (under the node lock) ---------------------------------------------------

    def _liveliness(self, service: str, alive: bool) -> None:
        was = self.alive.get(service, False)
        self.alive[service] = alive
        if was and not alive:  # during a trial this breaks it; between trials it holds the next
            self.rig.lost(service, self.node.clock.now_ns())

    def on_arm(self, msg: om.OptionsArmState) -> None:
        """The arm's safety state."""
        check_count(msg, self.n)
        self.rig.device_state("actuation", msg.safe_stop, msg.safety_reason,
                              self.node.clock.now_ns())

    def on_eyes(self, msg: m.EyesStateMsg) -> None:
        """The eyes' safety state."""
        self.rig.device_state("eyes", msg.safe_stop, msg.safety_reason, self.node.clock.now_ns())

    def on_estop(self, msg: m.Estop) -> None:
        """An e-stop command: it breaks a running trial and holds the session until released."""
        self.rig.estop(msg.engaged, msg.reason, msg.source, self.node.clock.now_ns())

    def on_hand(self, pose: m.HandPose) -> None:
        """Keep the pose's centre for its ẑ_h; the human's press, once a landmark is in a box."""
        if not pose.detected or pose.center is None:
            return
        self._centers[pose.seq] = pose.center
        while len(self._centers) > 256:
            self._centers.popitem(last=False)
        if self.judge is not None:
            self.judge.see_hand(pose.landmarks, pose.t_ns * NS)

    def on_z_h(self, msg: om.OptionVector) -> None:
        """A ẑ_h vector: it counts toward the outcome until the human's press."""
        z_hat = values_for(msg, self.n)
        if self.judge is not None and self.t_go_ns is not None and msg.t_ns >= self.t_go_ns:
            self.judge.observe(z_hat, self._centers.get(msg.src_seq), msg.t_ns * NS)

    def on_press(self, msg: om.OptionsPress) -> None:
        """The robot pressed a box (this trial's, once)."""
        check_count(msg, self.n)
        if msg.trial == self.trial and self.robot is None:
            self.robot = msg.option

    def on_layout(self, msg: om.OptionsLayoutMsg) -> None:
        """The table the sim (or vision) sees: judged from the next trial."""
        self.layout = same_count(msg.layout(), self.n)

    # -- the script (main thread) ----------------------------------------------------------

    def wait_for_services(self, timeout_s: float) -> None:
        """Block until every required service's liveliness token is seen (wall clock)."""
        wait_for_services(self.node, self.alive, REQUIRED, timeout_s)

    def _now_s(self) -> float:
        return self.node.clock.now_ns() * NS

    def _keep_gaze_alive(self) -> None:
        period_s = self.node.clock.wall_seconds(GAZE_KEEPALIVE_S)
        while not self.node.stop.wait(period_s):
            with self.node.lock:
                if self.gaze_msg is not None and self.node.session is not None:
                    self.pub_gaze.put(**self.gaze_msg)

    def run_session(
        self,
        session: str,
        participant: str,
        seed: int | None,
        first_trial: int = 1,
        resume: bool = False,
        lost: tuple[int, int, int] | None = None,
    ) -> list[TrialRecord]:
        """Run the schedule from `first_trial`; store and publish each trial.

        `resume`: the session is stored already (`prepare_resume`): its trials so far are kept
        in `results`, and `lost` is the attempt a previous conductor left open when it died,
        stored as an interruption and then repeated or moved past, as in the paper's session.
        """
        self.session = session
        if resume:
            stored = self.store.option_names(session)
            if stored != self.schedule.names:  # `resume_problem` refuses it before: a guard
                raise ValueError(f"session {session} ran the options {list(stored)}, not "
                                 f"{list(self.schedule.names)}")
            self.results = [t for _, t in self.store.trials(session)]
        else:
            schedule = [dataclasses.asdict(t) for t in self.schedule.trials]  # the analysis
            self.store.begin_session(
                session, participant, self.node.keys.rig, seed, self.node.clock.now_ns(),
                {**self.cfg.summary(), "options": list(self.schedule.names),
                 "option_schedule": schedule},
                self.schedule.names,
            )
            self.results = []
        status = "aborted"
        try:
            first_trial, attempts_before = attempts_so_far(
                self.store, session, self.params, first_trial, lost, self._file_open_attempt,
                self._give_up,
            )
            if first_trial > len(self.params.trials):  # the lost attempt was the last one's last
                status = "complete"
                return self.results
            protocol = SessionProtocol(self.params, first_trial, attempts_before)
            self._wait_for_a_safe_rig()
            with self.node.lock:
                cues = protocol.start(self._now_s())
            while True:
                self._perform(protocol, cues)
                if protocol.done:
                    break
                self._wait(protocol.next_due())
                with self.node.lock:
                    now_ns = self.node.clock.now_ns()
                    why = self.rig.interruption(now_ns) if protocol.running_trial else None
                    if why is not None:
                        cues = protocol.interrupt(self._now_s(), why)
                        continue
                    if protocol.phase in ("paused", "rest") and not self._rig_ready():
                        cues = []  # no new trial, no repeat, on an unsafe rig
                        continue
                    if protocol.phase == "paused":
                        cues = protocol.resume(self._now_s())
                        continue
                    if protocol.waiting_for_operator:
                        cues = protocol.open_gate(self._now_s())
                        continue
                    judge = self.judge
                    cues = protocol.advance(
                        self._now_s(),
                        human_pressed=judge is not None and judge.human is not None,
                        robot_pressed=self.robot is not None,
                    )
            status = "complete"
        finally:
            with self.node.lock:
                events = self.rig.take_events()
            self.store.write_events(session, events)
            self.store.finish_session(session, self.node.clock.now_ns(), status)
            with self.node.lock:
                self.gaze_msg = None
            self.pub_trial.put(n_options=self.n, phase="session_end" if status == "complete"
                               else "abort", trial=self.trial, session=session, text=status)
        return self.results

    def stop_mid_trial(self, why: str) -> bool:
        """The conductor is stopped (SIGINT, SIGTERM): store the attempt under way as interrupted.

        As the paper's conductor: a stop by the operator is on record as such, not filed as a
        lost conductor by the resumed session. Returns whether an attempt was open.
        """
        lost = self.store.open_attempt(self.session) if self.session else None
        if lost is not None:
            self._file_open_attempt(lost, why)
        return lost is not None

    def _file_open_attempt(self, lost: tuple[int, int, int], why: str) -> None:
        """Store an attempt left open, (trial, attempt, t_start_ns), as an interruption."""
        with self.node.lock:
            self.judge = None
            events = self.rig.take_events()
        file_open_attempt(self.store, self.session, lost, why, self.node.clock.now_ns(), events)

    def _rig_ready(self) -> bool:
        """Is the rig safe (and settled)? Says once when it is not, and when it is again."""
        return self.hold.ready(self.node.clock.now_ns())

    def _wait_for_a_safe_rig(self) -> None:
        """Before the first trial: eyes neutral (kept alive), then wait until the rig is safe."""
        with self.node.lock:
            self.gaze_msg = {"yaw": 0.0, "pitch": 0.0, "level": "neutral", "trial": 0}
            self.pub_gaze.put(**self.gaze_msg)
        while True:
            with self.node.lock:
                if self._rig_ready():
                    return
            self._wait(math.inf)

    def _wait(self, due_s: float) -> None:
        """Sleep until the protocol's next deadline, or at most 5 ms of rig time (presses)."""
        now = self.node.clock.now_ns()
        end_ns = now + 5_000_000
        if math.isfinite(due_s):
            end_ns = min(int(due_s * 1e9), end_ns)
        if self.node.stop.wait(max(0.0, self.node.clock.wall_seconds((end_ns - now) * NS))):
            raise KeyboardInterrupt

    def _perform(self, protocol: SessionProtocol, cues: list[Cue]) -> None:
        """Do what the protocol asks, in order (an "end" cue may bring the next trial's cues)."""
        while cues:
            cue = cues.pop(0)
            if cue.trial is None:  # session_end: published by run_session once stored
                continue
            trial = self.schedule.trial(cue.trial.index)
            ev: TrialFields = {"n_options": self.n, "trial": trial.index, "mode": trial.mode,
                               "option": trial.option, "session": self.session}
            if cue.kind == "gaze" and cue.gaze is not None:
                with self.node.lock:
                    self.gaze_msg = {"yaw": cue.gaze.yaw, "pitch": cue.gaze.pitch,
                                     "level": trial.gaze_level, "gesture": cue.gesture,
                                     "trial": trial.index}
                    self.pub_gaze.put(**self.gaze_msg)
            elif cue.kind == "setup":
                started = self.node.clock.now_ns()
                self.store.begin_attempt(self.session, trial.index, protocol.attempt, started)
                with self.node.lock:
                    self.trial, self.judge, self.robot, self.t_go_ns = trial.index, None, None, None
                    self.rig.begin(trial.index, protocol.attempt)
                    self._trial_start_ns = started
                self.pub_trial.put(phase="setup", text=cue.text, **ev)
                log.info("trial %d: %s, O = %s", trial.index, trial.mode,
                         self.schedule.name(trial.option))
            elif cue.kind == "countdown":
                self.pub_trial.put(phase="countdown", text=cue.text, **ev)
            elif cue.kind == "go":
                with self.node.lock:
                    go = self.pub_trial.put(phase="go", text=cue.text, **ev)
                    self.judge = OptionsTrialJudge(self.cfg, self.layout, trial.mode)
                    self.t_go_ns = go.t_ns
            elif cue.kind == "end":
                self._end_trial(protocol, cue.trial.yaw or 0.0, cue.trial.pitch or 0.0, ev)
                cues.extend(protocol.judged(self._now_s()))
            elif cue.kind == "interrupted":
                self._interrupted(protocol, ev, cue.text)

    def _end_trial(
        self, protocol: SessionProtocol, yaw: float, pitch: float, ev: TrialFields
    ) -> None:
        """Judge the trial, store it with the session's option set, publish the result."""
        with self.node.lock:
            judge, robot, t_go = self.judge, self.robot, self.t_go_ns
            self.judge = None
        trial = self.schedule.trial(self.trial)
        end = protocol.end
        assert judge is not None and end is not None  # set at "go", which precedes every "end"
        self.pub_trial.put(phase="end", text=end.reason, **ev)
        # Stored the moment it ends, clicks not entered; the operator's answer updates it (a
        # Ctrl-C at the prompt leaves it stored once), as in the paper's conductor.
        j = judge.verdict(end, robot, None)
        name = self.schedule.name
        rec = TrialRecord(
            trial.index, trial.mode, name(trial.option), trial.gaze_level, yaw, pitch, t_go,
            self.node.clock.now_ns(), name(j.human), name(j.robot), j.outcome, j.switches,
            j.violations, None, j.score, end.reason, attempts=protocol.attempt,
        )
        with self.node.lock:
            events = self.rig.take_events()
        self.store.write_trial(self.session, rec, (), events)  # no samples kept yet at N > 2
        self.results.append(rec)
        try:
            clicks = self.clicks(trial.index)
        except (KeyboardInterrupt, EOFError):  # stored, clicks not entered: said, then stop
            self._publish(rec)
            raise
        if clicks is not None:
            rec = self.store.set_clicks(self.session, trial.index, clicks)
            self.results[-1] = rec
        self._publish(rec)
        log.info("trial %d: human %s, robot %s -> %s (%+d)", trial.index, rec.human,
                 rec.robot, rec.outcome, rec.score)

    def _index(self, name: str | None) -> int | None:
        """The box index of a stored option name (None stays None)."""
        return None if name is None else self.schedule.index_of(name)

    def _publish(self, rec: TrialRecord) -> None:
        """A stored trial's result on `options/result` (options by index, as its schema has)."""
        index = self._index
        self.pub_result.put(
            n_options=self.n, trial=rec.trial, mode=rec.mode, option=index(rec.option),
            robot=index(rec.robot), human=index(rec.human), outcome=rec.outcome,
            switches=rec.switches,
            violations=rec.violations, score=rec.score, session=self.session,
        )

    def _interrupted(self, protocol: SessionProtocol, ev: TrialFields, why: str) -> None:
        """Store the broken start of a trial; the session pauses until the rig is safe."""
        with self.node.lock:
            self.judge = None
            events, now = self.rig.take_events(), self.node.clock.now_ns()
        trial = self.schedule.trial(self.trial)
        log.warning("trial %d (attempt %d) INTERRUPTED: %s", trial.index, protocol.attempt, why)
        self.pub_trial.put(phase="interrupted", text=why[:400], **ev)
        record = Interruption(trial.index, protocol.attempt, self._trial_start_ns, now, why)
        self.store.write_interruption(self.session, record, events)
        proto = self.params
        if not proto.repeat_interrupted or protocol.attempt >= proto.max_attempts:
            self._give_up(trial.index, protocol.attempt, f"interrupted: {why}")

    def _give_up(self, index: int, attempts: int, reason: str) -> None:
        """Store a trial out of attempts as interrupted (never scored) and publish it.

        Called for a break on its last attempt, and by a resume for a trial whose attempts
        were all used before (`attempts_so_far`).
        """
        trial, spec = self.schedule.trial(index), self.params.trials[index - 1]
        rec = TrialRecord(
            trial.index, trial.mode, self.schedule.name(trial.option), trial.gaze_level,
            spec.yaw or 0.0, spec.pitch or 0.0, None, self.node.clock.now_ns(), None, None,
            None, 0, 0, None, 0, reason[:400], interrupted=True, attempts=attempts,
        )
        self.store.write_trial(self.session, rec, ())
        self.results.append(rec)
        # published as the paper's conductor does: the launcher's table and the monitor
        # show every trial stored, the one given up on as well
        self.pub_result.put(
            n_options=self.n, trial=trial.index, mode=trial.mode, option=trial.option,
            session=self.session, interrupted=True,
        )
