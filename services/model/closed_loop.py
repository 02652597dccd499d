"""The closed loop in one process, without Zenoh: for cohorts, power analysis, tuning and tests.

It drives the same `SessionProtocol` as the conductor and reacts to its cues the way the
services do on the fabric — decision and actuation reset at "setup", start at "go"; the
participant reads the gaze, waits for "go" and watches the arm — with the same pure parts:
`Participant`, the decision engine, the robot's Algorithm 2, the simulated arm and the judge.
Everything advances in lock step at camera rate, so a seed gives one exact session. A
distributed session gives the same kind of outcomes, not bit-identical ones: message timing
differs.

One loop for any option set (docs/multi-option.md): the cues, the protocol's pauses and
repeats, the frame and the stored trial are written once (`_Loop`). What a table is made of
is its subclass's: `_PaperLoop`, the two-option kernel — the paper's parts in red and blue
(`DecisionModel`, `RobotTrial`, `SimArm`, `TrialJudge`), the gaze as its yaw, the arm's
heading as a sign — kept because the cohort's sessions are pinned by the golden
(tests/unit/test_golden.py); `_OptionsLoop`, the general form over a schedule's N options
(`OptionsDecision`, `OptionsRobotTrial`, `OptionsSimArm`, `OptionsTrialJudge`; options as
indices). Both draw the person's random numbers in the same order.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any, Generic, NamedTuple, Protocol, TypeVar, overload

import numpy as np

from services.model.arm import OptionsSimArm, SimArm
from services.model.compiled import VIEW_ROWS, PoseView, view_kernel
from services.model.compiled import enabled as compiled_enabled
from services.model.decision import DecisionModel, OptionsDecision, PoseEngine
from services.model.gaze import GazeCommand
from services.model.geometry import Box, Colour, Point, colour_sign
from services.model.judge import Judge, OptionsTrialJudge, TrialJudge
from services.model.outcome import TrialJudgement
from services.model.params import NodConfig
from services.model.participant import Participant, ParticipantParams, jittered
from services.model.policy import (
    Kind,
    Played,
    Policy,
    PolicyRun,
    PolicySettings,
    decision_for,
    kind_of,
    paper_settings,
    spec_for,
)
from services.model.protocol import Cue, ProtocolParams, SessionProtocol
from services.model.replayed_hand import Pose, ReplayedHand
from services.model.robot import OptionsRobotTrial, RobotTrial, TrialReactor
from services.model.schedule import Mode, OptionsSchedule, TrialSpec

Opt = TypeVar("Opt", Colour, int)  # an option: the paper's colour, or an index of N
Opt_co = TypeVar("Opt_co", covariant=True)


class LoopSample(NamedTuple):
    """One camera frame of a simulated trial: the hand, the decision's outputs, the arm.

    Over N options ẑ_h, z_r, b_r are vectors with no faithful scalar: their columns are None,
    as the conductor stores them (`services.experiment.keyspace`).
    """

    t_ns: int
    hand_x: float
    hand_y: float
    z_h: float | None
    z_r: float | None
    b_r: float | None
    ee_x: float
    ee_y: float
    theta: float | None  # eq 7's θ when this frame set ẑ_h
    distance: float | None  # eq 7's d when this frame set ẑ_h


@dataclass(frozen=True, slots=True)
class OfflineTrial(Generic[Opt]):
    """The result of one simulated trial (options by colour, or by index into the schedule)."""

    trial: int
    mode: str
    option: Opt | None
    human: Opt | None
    robot: Opt | None
    outcome: str | None
    switches: int
    violations: int
    score: int
    duration_s: float  # from "go" to the end of the trial
    press_s: float | None = None  # from "go" to the human's press (None: never pressed)
    samples: tuple[LoopSample, ...] = ()  # every frame from "go" to the end (when recorded)
    interrupted: bool = False  # broken by a safe stop and not repeated: never scored
    attempts: int = 1  # starts of this trial, the interrupted ones included
    settings: PolicySettings | None = None  # the robot policy's settings (None: no policy)


def centre(pts: np.ndarray) -> Point:
    """The mean (x, y) of landmarks (n × 2): `pts[:, k].mean()` bit for bit, 5× quicker.

    NumPy's mean of a float array is its `add.reduce` (the same pairwise summation) divided by
    the count; calling both directly skips `mean`'s generic wrapper, ~10 µs a call.
    """
    n = len(pts)
    return float(_SUM(pts[:, 0])) / n, float(_SUM(pts[:, 1])) / n


_SUM = np.add.reduce


def view_of(pts: np.ndarray, bounds: Sequence[tuple[float, float, float, float]]
            ) -> tuple[float, float, bool]:
    """(centre x, centre y, reach): the landmarks' mean and whether they can be in a box.

    The mean is `centre`'s; reach, whether their bounding box meets any box of `bounds` (x1, x2,
    y1, y2 each: `box_bounds`). Judge and robot test every landmark against every box (the
    layout's `pressed`) and change nothing when none is in one; a hand whose bounding box meets
    no box cannot press, so neither test needs to run. `compiled.pose_view` is this compiled
    (the offline loop's).
    """
    cx, cy = centre(pts)
    xs, ys = pts.T.tolist()
    x_lo, x_hi, y_lo, y_hi = min(xs), max(xs), min(ys), max(ys)
    reach = any(
        x_lo <= x2 and x1 <= x_hi and y_lo <= y2 and y1 <= y_hi for x1, x2, y1, y2 in bounds
    )
    return cx, cy, reach


def box_bounds(boxes: Sequence[Box]) -> list[tuple[float, float, float, float]]:
    """(x1, x2, y1, y2) of each box: a pose whose landmarks all lie outside presses none."""
    return [(b.x1, b.x2, b.y1, b.y2) for b in boxes]


class _Arm(Protocol[Opt_co]):
    """Either simulated arm, as the loop drives it (commands are its robot's own)."""

    def connect(self) -> None: ...
    def home(self) -> object: ...
    def hold(self) -> object: ...
    def send(self, cmd: Any) -> object: ...
    def state(self, t: float) -> object: ...
    def glance(self, t: float) -> tuple[Point, bool, Opt_co | None, Opt_co | None]: ...


def _draws(cfg: NodConfig, seed: int, cohort: bool) -> tuple[ParticipantParams, int]:
    """The person's traits (jittered in a cohort) and their own seed, drawn in this order."""
    rng = np.random.default_rng(seed)
    params = jittered(cfg.participant, rng) if cohort else cfg.participant
    return params, int(rng.integers(2**31))


def person_kind(cfg: NodConfig, seed: int, cohort: bool = True) -> Kind:
    """The kind of the person `run_offline_session` simulates for this seed (`policy.kind_of`)."""
    params, person_seed = _draws(cfg, seed, cohort)
    p = Participant(params, cfg.layout, seed=person_seed)
    return kind_of(p.strategist, p.contrarian, p.firm)


class _Loop(ABC, Generic[Opt]):
    """One participant's session: the protocol's cues dispatched to the loop's parts."""

    def __init__(
        self,
        cfg: NodConfig,
        clicks: int | None,
        record: bool,
        person: Participant[Opt] | ReplayedHand,
        model: PoseEngine[Any, Opt, Any],
        robot: TrialReactor[Any, Any, Opt, Any],
        arm: _Arm[Opt],
        boxes: Sequence[Box],
        protocol: ProtocolParams,
        policy: PolicyRun | None = None,
    ) -> None:
        self.cfg = cfg
        self.clicks = clicks
        self.person: Participant[Opt] | ReplayedHand = person
        self.model: PoseEngine[Any, Opt, Any] = model
        self.robot: TrialReactor[Any, Any, Opt, Any] = robot
        self.arm: _Arm[Opt] = arm
        self._boxes = box_bounds(boxes)
        self._bounds = np.array(self._boxes, dtype=np.float64)  # the same, for `compiled.pose_view`
        # The landmarks' centre and box pre-test compiled (`view_of` as machine code), or None.
        self._view: PoseView | None = view_kernel() if compiled_enabled() else None
        self.arm.connect()
        self.policy = policy
        self._settings: dict[int, PolicySettings] = {}  # the policy's, per trial index
        self.protocol = SessionProtocol(protocol, planner=None if policy is None else self._plan)
        self.judge: Judge[Any, Opt, Any] | None = None  # from "go" to the trial's verdict
        self.ended = False  # the trial's "end" has come (its verdict and samples are kept)
        self.t_go = 0.0
        self.record = record
        self.samples: list[LoopSample] = []
        self.results: list[OfflineTrial[Opt]] = []

    # -- what a table is made of -----------------------------------------------------------

    @abstractmethod
    def _trial(self, spec: TrialSpec) -> tuple[Mode, Opt | None, Opt | None]:
        """The trial's mode, its O (the person's and the stored one), the decision engine's O."""

    @abstractmethod
    def _new_judge(self, mode: Mode) -> Judge[Any, Opt, Any]:
        """The judge of a trial from its "go"."""

    @abstractmethod
    def _gaze(self, gaze: GazeCommand) -> GazeCommand | float:
        """The gaze cue as the person reads it."""

    @abstractmethod
    def _heading(self, target: Opt | None, moving: bool) -> int | None:
        """What the person sees the arm head for (`Participant.see_robot`)."""

    @abstractmethod
    def _opinions(self, out: Any) -> tuple[float | None, ...]:
        """A recorded frame's ẑ_h, z_r, b_r, θ and d."""

    def _retune(self, s: PolicySettings, paper: PolicySettings) -> None:
        """Give the decision engine a trial's b* and u_r (only the paper's table has a policy)."""
        raise ValueError("a robot policy runs on the paper's two-option table only")

    def _plan(self, spec: TrialSpec) -> TrialSpec:
        """The trial as the policy sets it, as it begins: its gaze level, b* and u_r."""
        assert self.policy is not None  # the protocol's planner only with a policy
        paper = paper_settings(self.cfg.decision, spec)
        s = self.policy.settings(spec, paper)
        self._settings[spec.index] = s
        self._retune(s, paper)
        return spec_for(spec, s)

    # -- the session, written once -----------------------------------------------------------

    @property
    def human(self) -> Opt | None:
        """The human's press this trial (the judge's, the same one the robot sees)."""
        return self.judge.human if self.judge is not None else None

    def on_cues(self, t: float, cues: list[Cue]) -> None:
        while cues:
            cue = cues.pop(0)
            spec = cue.trial
            if cue.kind == "gaze" and not cue.gesture and cue.gaze is not None:
                self.person.see_gaze(self._gaze(cue.gaze))
            elif spec is None:
                continue
            elif cue.kind == "setup":
                mode, option, decided = self._trial(spec)
                self.model.reset(mode, decided)
                self.robot.setup(spec.index)
                self.arm.state(t)
                self.arm.home()
                self.person.new_trial(option)
                self.judge = None
                self.samples = []
                self.ended = False
            elif cue.kind == "go":
                mode, _, decided = self._trial(spec)
                self.model.reset(mode, decided)
                self.robot.go(t)
                self.person.go(t)
                self.judge = self._new_judge(mode)
                self.t_go = t
                self.ended = False
            elif cue.kind == "end":
                self._judge(t, spec)
                self.ended = True
                cues.extend(self.protocol.judged(t))
            elif cue.kind == "interrupted":
                self._interrupted(t, spec)

    def _judge(self, t: float, spec: TrialSpec) -> None:
        robot = self.robot.pressed
        self.person.trial_ended(robot)
        assert self.judge is not None  # set at "go", which precedes every "end"
        j = self.judge.verdict(self.protocol.end, robot, self.clicks)
        t_press = self.judge.t_press
        press_s = None if t_press is None or j.human is None else t_press - self.t_go
        self._keep(t, spec, j, press_s, tuple(self.samples))

    def _interrupted(self, t: float, spec: TrialSpec) -> None:
        """A safe stop broke the trial: void it, and keep it if it is not repeated.

        The conductor's rule: after `max_attempts`, stored interrupted and never scored.
        """
        self.robot.interrupted()
        self.arm.hold()
        self.judge = None
        proto = self.cfg.protocol
        if not proto.repeat_interrupted or self.protocol.attempt >= proto.max_attempts:
            self._keep(t, spec, Judge.void(), None, (), interrupted=True)

    def _keep(
        self,
        t: float,
        spec: TrialSpec,
        j: TrialJudgement[Opt],
        press_s: float | None,
        samples: tuple[LoopSample, ...],
        interrupted: bool = False,
    ) -> None:
        """Store the trial ending at t with judgement j, as the conductor stores it."""
        mode, option, _ = self._trial(spec)
        settings = self._settings.get(spec.index)
        self.results.append(
            OfflineTrial(
                spec.index, mode, option, j.human, j.robot, j.outcome, j.switches, j.violations,
                j.score, t - self.t_go, press_s, samples, interrupted=interrupted,
                attempts=self.protocol.attempt, settings=settings,
            )
        )
        if self.policy is not None and settings is not None:
            self.policy.played(Played.of(spec.index, mode, settings, j.outcome, option,
                                         j.human))

    def _idle(self) -> bool:
        """Whether nothing reads this frame's pose or the decision engine (`frame` skips both).

        Before a trial's "go" (and before the first setup) the robot idles (its `step` gives
        None), there is no judge and no sample, and "go" resets the engine. Once the human has
        pressed and the robot's choice is final (`decided`: its steps repeat the press whatever
        z_r), the judge reads no more poses and Algorithm 2 no more z_r: only the samples are
        left, so from then on a loop that records none is idle, and one that does is idle after
        the trial's "end" (its samples are kept; the next setup starts anew).
        tests/unit/test_loop_speed.py holds the skip bit for bit.
        """
        if not self.robot.running:
            return self.judge is None
        return (self.ended or not self.record) and self.human is not None and self.robot.decided

    def frame(self, t: float) -> None:
        """One camera frame: the person moves, decision reads the pose, actuation steps."""
        self.person.advance(t)
        if self._idle():  # the arm moves and the person watches it; nothing else runs
            self.person.unseen()  # the camera's noise is drawn all the same (the random stream)
            self._actuate(t, None)
            return
        pts = self.person.landmarks()
        landmarks: list[Point] = list(map(tuple, pts.tolist()))  # the same floats, 10× quicker
        out = self.model.on_hand(int(round(t * 1e9)), landmarks)
        judge = self.judge
        view = self._view
        if view is not None and VIEW_ROWS[0] <= len(pts) <= VIEW_ROWS[1]:
            cx, cy, reach = view(pts, self._bounds)
        else:
            cx, cy, reach = view_of(pts, self._boxes)
        center = (cx, cy)
        if judge is not None and judge.human is None:
            judge.observe(out.z_hat, center, t)
            if reach:
                judge.see_hand(landmarks, t)
        if reach:
            self.robot.see_hand(landmarks)
        ee_x, ee_y = self._actuate(t, out.z_r)
        if self.record and judge is not None:
            z_h, z_r, b_r, theta, distance = self._opinions(out)
            self.samples.append(
                LoopSample(round(t * 1e9), cx, cy, z_h, z_r, b_r, ee_x, ee_y, theta, distance)
            )

    def _actuate(self, t: float, z_r: Any) -> Point:
        """Algorithm 2 steps on z_r (None: no new sample), the arm moves, the person sees it.

        Returns where the end effector is after the step.
        """
        # The arm's report as a tuple (`glance`): its state's fields without building the
        # frozen dataclass, ~2 µs one to two times a frame.
        ee, moving, target, pressed = self.arm.glance(t)
        cmd = self.robot.step(t, z_r, ee)
        if cmd is not None:
            self.arm.send(cmd)
            ee, moving, target, pressed = self.arm.glance(t)
        self.person.see_robot(t, self._heading(target, moving))
        if pressed is not None:
            self.robot.arm_pressed(pressed)
        return ee


class _PaperLoop(_Loop[Colour]):
    """The two-option kernel: the paper's table of red and blue and its own parts."""

    def __init__(
        self,
        cfg: NodConfig,
        seed: int,
        cohort: bool,
        clicks: int | None,
        record: bool = False,
        hand: ReplayedHand | None = None,
        policy: PolicyRun | None = None,
    ) -> None:
        params, person_seed = _draws(cfg, seed, cohort)
        layout = cfg.layout
        model = DecisionModel(cfg.decision, layout)
        model.use_compiled()  # its RK4 as machine code, the same values (`services.model.compiled`)
        arm = SimArm(layout, cfg.sim_arm, t0=0.0)
        arm.use_compiled()  # its substeps too
        person: Participant[Colour] | ReplayedHand
        if hand is None:
            person = Participant(params, layout, seed=person_seed)
            person.use_compiled()  # its 2 ms steps as machine code, the same values
        else:
            person = hand
        super().__init__(
            cfg, clicks, record,
            person=person,
            model=model,
            robot=RobotTrial(layout, cfg.behaviour, cfg.debounce, cfg.protocol.trial_timeout_s),
            arm=arm,
            boxes=(layout.red, layout.blue),
            protocol=cfg.protocol,
            policy=policy,
        )

    def _trial(self, spec: TrialSpec) -> tuple[Mode, Colour | None, Colour | None]:
        return spec.mode, spec.option, spec.consensus_option

    def _retune(self, s: PolicySettings, paper: PolicySettings) -> None:
        params = self.cfg.decision if s == paper else decision_for(self.cfg.decision, s)
        model = self.model
        assert isinstance(model, DecisionModel)
        if params != model.params:
            model.retune(params)

    def _new_judge(self, mode: Mode) -> TrialJudge:
        return TrialJudge(self.cfg, self.cfg.layout, mode)

    def _gaze(self, gaze: GazeCommand) -> float:
        return gaze.yaw  # the paper's person reads the yaw (> 0 toward red)

    def _heading(self, target: Colour | None, moving: bool) -> int:
        return colour_sign(target) if target and moving else 0

    def _opinions(self, out: Any) -> tuple[float | None, ...]:
        obs = out.observation
        return out.z_hat, out.z_r, out.b_r, obs.theta, obs.distance


class _OptionsLoop(_Loop[int]):
    """The general form: a schedule's N options on the config's table of N boxes."""

    def __init__(
        self,
        cfg: NodConfig,
        schedule: OptionsSchedule,
        seed: int,
        cohort: bool,
        clicks: int | None,
        record: bool = False,
        hand: ReplayedHand | None = None,
    ) -> None:
        params, person_seed = _draws(cfg, seed, cohort)
        self.schedule = schedule
        self.layout = layout = cfg.table(schedule.n_options)
        super().__init__(
            cfg, clicks, record,
            person=hand if hand is not None else Participant(params, layout, person_seed),
            model=OptionsDecision(layout, cfg.decision),
            robot=OptionsRobotTrial(
                layout, cfg.behaviour, cfg.debounce, cfg.protocol.trial_timeout_s
            ),
            arm=OptionsSimArm(layout, cfg.sim_arm, t0=0.0),
            boxes=layout.boxes,
            protocol=replace(cfg.protocol, trials=schedule.timing_specs(layout)),
        )

    def _trial(self, spec: TrialSpec) -> tuple[Mode, int | None, int | None]:
        trial = self.schedule.trial(spec.index)  # the clock's spec carries no mode and no O
        return trial.mode, trial.option, trial.option

    def _new_judge(self, mode: Mode) -> OptionsTrialJudge:
        return OptionsTrialJudge(self.cfg, self.layout, mode)

    def _gaze(self, gaze: GazeCommand) -> GazeCommand:
        return gaze

    def _heading(self, target: int | None, moving: bool) -> int | None:
        return target if moving else None

    def _opinions(self, out: Any) -> tuple[float | None, ...]:
        return None, None, None, None, None


@overload
def run_offline_session(
    cfg: NodConfig,
    seed: int,
    rate_hz: float = ...,
    cohort: bool = ...,
    clicks: int = ...,
    record: bool = ...,
    breaks: Mapping[tuple[int, int], float] | None = ...,
    safe_again_s: float = ...,
    hands: Mapping[int, Sequence[Pose]] | None = ...,
    schedule: None = ...,
    policy: Policy | PolicyRun | None = ...,
) -> list[OfflineTrial[Colour]]: ...


@overload
def run_offline_session(
    cfg: NodConfig,
    seed: int,
    rate_hz: float = ...,
    cohort: bool = ...,
    clicks: int = ...,
    record: bool = ...,
    breaks: Mapping[tuple[int, int], float] | None = ...,
    safe_again_s: float = ...,
    hands: Mapping[int, Sequence[Pose]] | None = ...,
    *,
    schedule: OptionsSchedule,
    policy: None = ...,
) -> list[OfflineTrial[int]]: ...


def run_offline_session(
    cfg: NodConfig,
    seed: int,
    rate_hz: float = 30.0,
    cohort: bool = False,
    clicks: int = 10,
    record: bool = False,
    breaks: Mapping[tuple[int, int], float] | None = None,
    safe_again_s: float = 1.0,
    hands: Mapping[int, Sequence[Pose]] | None = None,
    schedule: OptionsSchedule | None = None,
    policy: Policy | PolicyRun | None = None,
) -> list[OfflineTrial[Colour]] | list[OfflineTrial[int]]:
    """Simulate one participant's whole session; return each trial's outcome (and samples).

    `schedule` runs its N options (options by index; `cfg.table(N)` their boxes); without
    one, the paper's study (options by colour, the two-option kernel).

    `breaks` injects safety interruptions, as a rig's safe stops: (trial, attempt) → seconds
    after that attempt's setup at which a safe stop breaks it. The session then pauses, as the
    conductor's does, until the rig has been safe for `safe_again_s` (the stop's own length and
    the conductor's settling time), and repeats the trial or moves on as the protocol says.

    `hands` replaces the simulated participant with a recorded hand: per trial, its poses timed
    from that trial's "go" (`services.model.replayed_hand`; `services.recording.reaches` reads
    them from a recording).

    `policy` chooses each trial's b*, gaze level and u_r as the trial begins, inside the
    envelope `cfg.policy` (`services.model.policy`; a `PolicyRun` to freeze it or read its
    history); None, like `PaperPolicy`, runs today's robot. The paper's table only.
    """
    hand = ReplayedHand(hands) if hands is not None else None
    run = policy if isinstance(policy, PolicyRun) or policy is None else PolicyRun(
        policy, cfg.policy)
    if schedule is None:
        return _run(_PaperLoop(cfg, seed, cohort, clicks, record, hand, run), rate_hz, breaks,
                    safe_again_s)
    if run is not None:
        raise ValueError("a robot policy runs on the paper's two-option table only")
    return _run(_OptionsLoop(cfg, schedule, seed, cohort, clicks, record, hand), rate_hz, breaks,
                safe_again_s)


def _run(
    loop: _Loop[Opt],
    rate_hz: float,
    breaks: Mapping[tuple[int, int], float] | None,
    safe_again_s: float,
) -> list[OfflineTrial[Opt]]:
    """Run the loop's session to its end at `rate_hz`, breaking the attempts `breaks` names."""
    breaks = dict(breaks or {})
    dt = 1.0 / rate_hz
    t = 0.0
    t_setup = 0.0
    broken_at: float | None = None
    loop.on_cues(t, loop.protocol.start(t))
    while not loop.protocol.done:
        t += dt
        loop.frame(t)
        proto = loop.protocol
        if proto.waiting_for_operator:  # a gated protocol: the simulated operator starts at once
            cues = proto.open_gate(t)
        elif proto.phase == "paused":
            assert broken_at is not None
            cues = proto.resume(t) if t - broken_at >= safe_again_s else []
        elif (
            breaks  # none (a cohort's sessions): nothing to look up, every frame
            and proto.running_trial
            and proto.trial is not None
            and t - t_setup >= breaks.get((proto.trial.index, proto.attempt), math.inf)
        ):
            broken_at = t
            cues = proto.interrupt(t, "simulated safe stop")
        else:
            cues = proto.advance(
                t,
                human_pressed=loop.human is not None,
                robot_pressed=loop.robot.pressed is not None,
            )
        if cues:  # most frames have none
            if any(c.kind == "setup" for c in cues):
                t_setup = t
            loop.on_cues(t, cues)
    return loop.results
