"""The trial protocol (paper Sec 3.2, SPEC §6): the session's state machine.

The schedule it runs (trials, parameters, timelines) is `services.model.schedule`, importable
from here too.

Each trial: gaze set (after the attention gesture in trial 4) → countdown "1, 2, 3, go" → both
move → the human presses (or the timeout) → the robot presses → outcome and score recorded → a
short rest → the next trial.

`SessionProtocol` is that sequence as a state machine over time and two observations (did the
human press, did the robot press). It returns `Cue`s — what the conductor must do now — and
knows nothing of the fabric: the live conductor (`nod experiment`) and the offline closed loop
(`services.model.closed_loop`) drive the same machine. Times are seconds (float) from any monotonic
origin, always passed in.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal, TypeAlias

from services.model.gaze import GazeCommand
from services.model.geometry import Colour
from services.model.schedule import (  # the schedule the machine runs, importable here too
    MAX_ATTEMPTS,
    MAX_GAZE_RAD,
    MAX_S,
    MAX_TARGET_CLICKS,
    MAX_TRIALS,
    MODES,
    Mode,
    Order,
    ProtocolParams,
    TrialSpec,
    TrialTimeline,
    default_schedule,
    order_of,
    parse_order,
    trial_timeline,
    with_order,
)

__all__ = [
    "Cue",
    "CueKind",
    "MAX_ATTEMPTS",
    "MAX_GAZE_RAD",
    "MAX_S",
    "MAX_TARGET_CLICKS",
    "MAX_TRIALS",
    "MODES",
    "Mode",
    "Order",
    "Phase",
    "ProtocolParams",
    "SessionProtocol",
    "TrialEnd",
    "TrialSpec",
    "TrialTimeline",
    "default_schedule",
    "order_of",
    "parse_order",
    "trial_timeline",
    "with_order",
]

CueKind: TypeAlias = Literal[
    "gaze", "setup", "countdown", "go", "end", "interrupted", "session_end"
]
Phase: TypeAlias = Literal[
    "idle", "gated", "cueing", "running", "robot", "judging", "paused", "rest", "done"
]


@dataclass(frozen=True, slots=True)
class Cue:
    """One thing the conductor must do now; `advance` returns them in the order to do them.

    - "gaze": command `gaze` (`gesture`: a pose of the attention gesture, not the trial's cue);
    - "setup": announce the trial (`text` = gaze level): decision and actuation reset;
    - "countdown": say `text`; "go": say the last word — both agents may move;
    - "end": the trial is over (`text` = why); judge and store it, then call `judged`;
    - "interrupted": a safe stop or e-stop broke the trial (`text` = why): store the attempt as
      interrupted (never scored); the session is paused until `resume`;
    - "session_end": every trial is done (`trial` is None).
    """

    kind: CueKind
    trial: TrialSpec | None
    text: str = ""
    gaze: GazeCommand | None = None
    gesture: bool = False


@dataclass(frozen=True, slots=True)
class TrialEnd:
    """How a trial ended, as the machine saw it."""

    human_pressed: bool  # False: the timeout ended the human's part
    robot_pressed: bool  # False: the robot did not press within `robot_wait_s`
    t: float  # when the "end" cue was given

    def counted_press(self, human: Colour | None) -> Colour | None:
        """The human's press as the trial counts it: none when the timeout ended their part.

        The arm goes on to press after the timeout, and a hand that reaches a box meanwhile is
        seen; that late press is not the person's choice in time, so the trial is a timeout.
        """
        return human if self.human_pressed else None

    @property
    def reason(self) -> str:
        """One line for the store: what ended the trial."""
        text = "human pressed" if self.human_pressed else "timeout"
        return text if self.robot_pressed else text + "; robot did not press"


class SessionProtocol:
    """The session as a state machine: idle → (cueing → running → robot → judging → rest)* → done.

    `interrupt(t, why)` from cueing, running or robot pauses the session; `resume(t)` repeats
    the trial (a new attempt, up to `max_attempts`) or moves on, as `repeat_interrupted` says.

    Call `start(t)`, then `advance(t, human_pressed=…, robot_pressed=…)` as often as convenient
    (every frame, every few ms): it returns the cues that fell due since the last call, in
    order, each scripted cue exactly once however coarse the calls. After an "end" cue the
    machine waits in "judging" until `judged(t)`: the conductor may take as long as it needs
    (the operator types the counter value) without eating into the rest before the next trial.
    """

    def __init__(
        self,
        params: ProtocolParams,
        first_trial: int = 1,
        attempts_before: int = 0,
        planner: Callable[[TrialSpec], TrialSpec] | None = None,
    ) -> None:
        """A session over `params.trials`, starting at trial `first_trial` (resume: > 1).

        `attempts_before`: starts of `first_trial` already made and lost (a resumed session
        whose conductor died mid-trial); the first start counts on from them. `planner`: each
        trial's spec passes through it as the trial begins (a robot policy's gaze level,
        `services.model.policy`), after the trials before it have ended.
        """
        self._planner = planner
        if not 1 <= first_trial <= len(params.trials):
            raise ValueError(
                f"first_trial must be in 1..{len(params.trials)}, got {first_trial!r}"
            )
        if not 0 <= attempts_before < params.max_attempts:
            raise ValueError(
                f"attempts_before must be in 0..{params.max_attempts - 1}, got {attempts_before!r}"
            )
        self.params = params
        self._next_index = first_trial - 1
        self._phase: Phase = "idle"
        self._trial: TrialSpec | None = None
        self._script: list[tuple[float, Cue]] = []
        self._timeline: TrialTimeline | None = None
        self._robot_deadline = math.inf
        self._human_pressed = False
        self._rest_until = math.inf
        self._end: TrialEnd | None = None
        self._attempt = attempts_before  # attempts of the current trial so far (1 = its first)
        self._hold = params.gate  # the next trial waits for the operator's `open_gate`

    # -- read-only state -------------------------------------------------------------------

    @property
    def phase(self) -> Phase:
        """Where the session is."""
        return self._phase

    @property
    def trial(self) -> TrialSpec | None:
        """The current trial (None before the start and after the last one)."""
        return self._trial

    @property
    def timeline(self) -> TrialTimeline | None:
        """The current trial's scripted times."""
        return self._timeline

    @property
    def end(self) -> TrialEnd | None:
        """How the current trial ended (set with its "end" cue)."""
        return self._end

    @property
    def attempt(self) -> int:
        """Which start of the current trial this is (1, or more after interruptions)."""
        return self._attempt

    @property
    def running_trial(self) -> bool:
        """Whether a trial is under way (from its setup to its end): what an interruption breaks."""
        return self._phase in ("cueing", "running", "robot")

    @property
    def waiting_for_operator(self) -> bool:
        """Whether the next trial is set and waits for the operator to start it."""
        return self._phase == "gated"

    @property
    def done(self) -> bool:
        """True once every trial was judged."""
        return self._phase == "done"

    def next_due(self) -> float:
        """The earliest time at which `advance` will change something by time alone (or inf)."""
        if self._phase == "cueing" and self._script:
            return self._script[0][0]
        if self._phase == "running" and self._timeline is not None:
            return self._timeline.timeout_t
        if self._phase == "robot":
            return self._robot_deadline
        if self._phase == "rest":
            return self._rest_until
        return math.inf

    # -- transitions -----------------------------------------------------------------------

    def start(self, t: float) -> list[Cue]:
        """Begin the session at time t: the first trial's cues that are due at once."""
        if self._phase != "idle":
            raise RuntimeError(f"start() in phase {self._phase!r}: a session starts once")
        out: list[Cue] = []
        self._begin_trial(t, out, repeat=self._attempt > 0)
        return out + self.advance(t)

    def advance(
        self, t: float, *, human_pressed: bool = False, robot_pressed: bool = False
    ) -> list[Cue]:
        """Move to time t, given whether the human and the robot have pressed (this trial)."""
        if not math.isfinite(t):
            raise ValueError(f"time must be finite, got {t!r}")
        out: list[Cue] = []
        if self._phase == "cueing":
            while self._script and self._script[0][0] <= t:
                out.append(self._script.pop(0)[1])
            if not self._script:
                self._phase = "running"
        if self._phase == "running":
            assert self._timeline is not None
            if human_pressed or t >= self._timeline.timeout_t:
                self._human_pressed = human_pressed
                self._phase = "robot"
                self._robot_deadline = t + self.params.robot_wait_s
        if self._phase == "robot" and (robot_pressed or t >= self._robot_deadline):
            self._end = TrialEnd(self._human_pressed, robot_pressed, t)
            self._phase = "judging"
            out.append(Cue("end", self._trial, self._end.reason))
        if self._phase == "rest" and t >= self._rest_until:
            self._begin_trial(t, out)
            out += self.advance(t)
        return out

    def judged(self, t: float) -> list[Cue]:
        """The conductor has judged and stored the trial at time t: rest, then the next one."""
        if self._phase != "judging":
            raise RuntimeError(f"judged() in phase {self._phase!r}: only after an 'end' cue")
        self._rest_until = t + self.params.rest_s
        self._phase = "rest"
        return self.advance(t)

    def interrupt(self, t: float, why: str) -> list[Cue]:
        """A safe stop or e-stop broke the current trial at time t: pause the session."""
        if not self.running_trial:
            raise RuntimeError(f"interrupt() in phase {self._phase!r}: no trial is under way")
        self._phase = "paused"
        self._script = []
        return [Cue("interrupted", self._trial, why)]

    def resume(self, t: float) -> list[Cue]:
        """The rig is safe again at time t: repeat the interrupted trial, or go on to the next.

        A trial is repeated while `repeat_interrupted` and it has had fewer than `max_attempts`
        starts; otherwise the session moves on (the trial stays stored as interrupted).
        """
        if self._phase != "paused":
            raise RuntimeError(f"resume() in phase {self._phase!r}: only after an interruption")
        repeat = self.params.repeat_interrupted and self._attempt < self.params.max_attempts
        if repeat:
            self._next_index -= 1
        out: list[Cue] = []
        self._begin_trial(t, out, repeat=repeat)
        return out + self.advance(t)

    def _begin_trial(self, t: float, out: list[Cue], repeat: bool = False) -> None:
        if self._next_index >= len(self.params.trials):
            self._phase = "done"
            self._trial = None
            out.append(Cue("session_end", None, "complete"))
            return
        spec = self.params.trials[self._next_index]
        if self._planner is not None:
            spec = self._planner(spec)
        self._next_index += 1
        self._attempt = self._attempt + 1 if repeat else 1
        self._trial = spec
        self._end = None
        self._human_pressed = False
        self._robot_deadline = math.inf
        if self._hold:  # the operator starts it: nothing is cued until `open_gate`
            self._phase = "gated"
            self._timeline = None
            self._script = []
            return
        self._script_trial(t)

    def hold(self) -> None:
        """The operator's pause: the next trial waits for `open_gate` (the current one goes on)."""
        self._hold = True

    def open_gate(self, t: float) -> list[Cue]:
        """The operator starts the waiting trial at time t (its cues from now on).

        Called when no trial waits, it lifts a `hold` so the next trial follows on its own.
        """
        self._hold = self.params.gate
        if self._phase != "gated":
            return []
        self._script_trial(t)
        return self.advance(t)

    def _script_trial(self, t: float) -> None:
        spec = self._trial
        assert spec is not None  # set by _begin_trial
        tl = trial_timeline(spec, t, self.params)
        self._timeline = tl
        gesture = spec.attention_gesture
        script: list[tuple[float, Cue]] = []
        for i, (when, cmd) in enumerate(tl.gaze):
            is_cue = i == len(tl.gaze) - 1
            script.append((when, Cue("gaze", spec, spec.gaze_level, cmd, gesture and not is_cue)))
            if i == 0:  # the trial is announced with its first gaze command
                script.append((when, Cue("setup", spec, spec.gaze_level)))
        for when, word in tl.countdown[:-1]:
            script.append((when, Cue("countdown", spec, word)))
        script.append((tl.go_t, Cue("go", spec, tl.countdown[-1][1])))
        # Stable sort by time: equal times keep the order above (gaze, setup, words, go).
        self._script = sorted(script, key=lambda item: item[0])
        self._phase = "cueing"
