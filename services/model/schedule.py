"""The trial schedule (paper Sec 3.2, SPEC §6): the 8 trials, their parameters and timelines.

What a session runs — each trial's mode, O, gaze level, the protocol's times and bounds, the
order of O a participant gets, and each trial's timeline (gaze, countdown, "go") — as plain
data and pure functions. `services.model.protocol.SessionProtocol` runs it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Literal, TypeAlias

from services.model.gaze import (
    GAZE_LEVEL_NAMES,
    AttentionGestureParams,
    GazeCommand,
    attention_gesture,
    gaze_level,
)
from services.model.geometry import Colour

Mode: TypeAlias = Literal["dissensus", "consensus"]
ControlLabels: TypeAlias = Literal["agreement", "switches"]
CONTROL_LABELS: tuple[ControlLabels, ...] = ("agreement", "switches")
MODES: tuple[Mode, Mode] = ("dissensus", "consensus")
# Upper bounds of the protocol's times (s). Each is far beyond any sensible setting and below
# what its default becomes when typed in milliseconds (0.75 -> 750, 10 -> 10000, 1 -> 1000,
# 5 -> 5000): a unit slip or an overflow (rest_s = 1e12) is refused at start, not a session that
# waits for hours while looking healthy. rest_s: 10 minutes is more than any rest between two
# trials (a longer break is a stopped session, resumed with `nod experiment --resume`).
MAX_S = {
    "countdown_interval_s": 10.0,  # one spoken word to the next
    "trial_timeout_s": 120.0,  # the person's time to press (the robot presses at it too)
    "gaze_lead_s": 60.0,
    "robot_wait_s": 60.0,  # the arm needs 1-3 s
    "rest_s": 600.0,
}
MAX_ATTEMPTS = 10  # starts of one trial: a trial interrupted 10 times is a rig fault to fix
MAX_TARGET_CLICKS = 1000
MAX_TRIALS = 10_000  # the wire's trial number (services.core.messages.Trial) goes no higher
MAX_GAZE_RAD = math.pi  # the wire's gaze angles (messages.Radians): beyond, the eyes refuse it


@dataclass(frozen=True, slots=True)
class TrialSpec:
    """What one trial does.

    `yaw`/`pitch` default to the gaze table's row for `gaze_level`, turned toward `option`
    (`services.model.gaze.GAZE_LEVELS`); give them only to override the table.
    """

    index: int  # 1-based trial number within a session
    mode: Mode  # "dissensus": b_r ≡ 0, controller off; "consensus": bias controller toward option
    option: Colour | None = None  # the convergence option O (consensus only; None: dissensus)
    gaze_level: str = "neutral"  # name of the gaze level (services.model.gaze.GAZE_LEVEL_NAMES)
    yaw: float | None = None  # gaze yaw (rad), > 0 toward red; None: from the gaze table
    pitch: float | None = None  # gaze pitch (rad); None: from the gaze table
    attention_gesture: bool = False  # run the attention gesture before setting the gaze

    def __post_init__(self) -> None:
        if isinstance(self.index, bool) or not isinstance(self.index, int) or self.index < 1:
            raise ValueError(f"TrialSpec.index must be an integer >= 1, got {self.index!r}")
        if self.mode not in MODES:
            raise ValueError(
                f"TrialSpec.mode must be 'dissensus' or 'consensus', got {self.mode!r}"
            )
        if self.mode == "consensus" and self.option not in ("red", "blue"):
            raise ValueError(f"trial {self.index}: consensus mode needs option 'red' or 'blue'")
        if self.mode == "dissensus" and self.option is not None:
            raise ValueError(f"trial {self.index}: dissensus mode has no option, got {self.option}")
        if self.gaze_level not in GAZE_LEVEL_NAMES:
            raise ValueError(
                f"trial {self.index}: unknown gaze level {self.gaze_level!r}; "
                f"expected one of {GAZE_LEVEL_NAMES}"
            )
        table = gaze_level(self.gaze_level).toward(self.option)
        if self.yaw is None:
            object.__setattr__(self, "yaw", table.yaw)
        if self.pitch is None:
            object.__setattr__(self, "pitch", table.pitch)
        for name in ("yaw", "pitch"):
            value = getattr(self, name)
            if not (math.isfinite(value) and abs(value) <= MAX_GAZE_RAD):
                raise ValueError(
                    f"trial {self.index}: gaze {name} must be in [-pi, pi] rad, got {value!r}"
                )

    @property
    def gaze(self) -> GazeCommand:
        """The gaze held from before the countdown to the end of the trial."""
        return GazeCommand(self.yaw, self.pitch)  # type: ignore[arg-type]

    @property
    def consensus_option(self) -> Colour | None:
        """O in a consensus trial, None in a dissensus trial (what the decision model takes)."""
        return self.option if self.mode == "consensus" else None


def default_schedule() -> tuple[TrialSpec, ...]:
    """The paper's 8 trials (SPEC §5/§6): 1–3 dissensus with neutral gaze, 4–8 consensus."""
    return (
        TrialSpec(1, "dissensus", None, "neutral"),
        TrialSpec(2, "dissensus", None, "neutral"),
        TrialSpec(3, "dissensus", None, "neutral"),
        TrialSpec(4, "consensus", "blue", "minimal", attention_gesture=True),
        TrialSpec(5, "consensus", "red", "low"),
        TrialSpec(6, "consensus", "red", "moderate"),
        TrialSpec(7, "consensus", "blue", "significant"),
        TrialSpec(8, "consensus", "red", "extreme"),
    )


Order: TypeAlias = tuple[Colour, ...]  # O of each consensus trial of a schedule, in trial order


def order_of(trials: Sequence[TrialSpec]) -> Order:
    """The O order of a schedule: the option of each consensus trial, in trial order."""
    return tuple(t.option for t in trials if t.mode == "consensus" and t.option is not None)


def with_order(trials: Sequence[TrialSpec], order: Sequence[Colour]) -> tuple[TrialSpec, ...]:
    """The schedule with its consensus trials' O replaced by `order`, each gaze turned toward O.

    A participant's counterbalanced order (`services.model.counterbalance`): the trials, their
    modes and gaze levels stay; a trial whose O changes has its gaze mirrored (yaw and pitch, as
    `GazeLevel.toward` mirrors a table row), so the eyes look toward the new O at the same level.
    """
    n = len(order_of(trials))
    if len(order) != n or any(o not in ("red", "blue") for o in order):
        raise ValueError(
            f"an order gives O (red or blue) for each of the schedule's {n} consensus trials, "
            f"got {list(order)}"
        )
    it = iter(order)
    out: list[TrialSpec] = []
    for spec in trials:
        if spec.mode != "consensus":
            out.append(spec)
            continue
        option = next(it)
        if option == spec.option:
            out.append(spec)
        else:
            assert spec.yaw is not None and spec.pitch is not None  # set by __post_init__
            out.append(replace(spec, option=option, yaw=-spec.yaw, pitch=-spec.pitch))
    return tuple(out)


def parse_order(text: str, n: int) -> Order:
    """An order from the command line: `red,blue,…` or letters `RBRRB` (n consensus trials)."""
    names: dict[str, Colour] = {"r": "red", "b": "blue", "red": "red", "blue": "blue"}
    raw = text.strip().lower()
    parts = [w.strip() for w in raw.split(",")] if "," in raw or raw in names else list(raw)
    if len(parts) != n or any(w not in names for w in parts):
        raise ValueError(
            f"--order needs O for each of the {n} consensus trials, as red,blue,… or letters "
            f"such as {'BRRBR'[:n] or 'R'}; got {text!r}"
        )
    return tuple(names[w] for w in parts)


@dataclass(frozen=True, slots=True)
class ProtocolParams:
    """Session protocol settings (SPEC §6 defaults)."""

    # Words spoken by the speaker, the last one being the start signal.
    countdown: tuple[str, ...] = ("1", "2", "3", "go")
    # Time between consecutive countdown words (s); > 0.
    countdown_interval_s: float = 0.75
    # The human's time to press after "go" (s); > 0. At the timeout the robot presses the nearest
    # buzzer (Algorithm 2 reads this same value: there is one trial timeout).
    trial_timeout_s: float = 10.0
    # Pause between setting the gaze and the first countdown word (s); ≥ 0. Lets the eyes settle
    # and the participant see them before the countdown.
    gaze_lead_s: float = 1.0
    # How long the conductor waits for the robot's press after the human's press (or the
    # timeout) before ending the trial without it (s); > 0. The arm needs ≈ 1–3 s to get there.
    robot_wait_s: float = 5.0
    # Rest after a trial is stored, before the next trial's gaze (s); ≥ 0: the hand returns.
    rest_s: float = 1.0
    # A trial interrupted by a safe stop or an e-stop is repeated after the rig is safe again
    # (true), or stored as interrupted and skipped (false). Either way it is never scored.
    repeat_interrupted: bool = True
    # How many times one trial may be started before it is skipped as interrupted; ≥ 1.
    max_attempts: int = 3
    # Counter clicks the participant must make for the counter point.
    target_clicks: int = 10
    # The operator's start gate: each trial waits, after the rest, until the operator starts it
    # (`nod experiment next`), so no trial begins before the participant is ready. Without the
    # gate trials follow each other; the operator can still hold the next one
    # (`nod experiment pause`).
    gate: bool = False
    # How control (dissensus) trials are labelled (SPEC §6): "agreement" — C or D by the buzzers
    # alone, whatever the switches (the paper's Fig 8a has no DH and almost no CH in trials 1-3
    # although its participants switched there); "switches" — the C/CH/D/DH rule of the
    # consensus trials. Switches and violations are counted and stored either way.
    control_labels: ControlLabels = "agreement"
    # The trials of a session, in order (indices 1..n).
    trials: tuple[TrialSpec, ...] = field(default_factory=default_schedule)
    # The attention gesture run before a trial that asks for it.
    gesture: AttentionGestureParams = field(default_factory=AttentionGestureParams)

    def __post_init__(self) -> None:
        if self.control_labels not in CONTROL_LABELS:
            raise ValueError(
                f"ProtocolParams.control_labels must be one of {', '.join(CONTROL_LABELS)}, "
                f"got {self.control_labels!r}"
            )
        if not self.countdown or not all(isinstance(w, str) and w for w in self.countdown):
            raise ValueError("ProtocolParams.countdown needs at least one non-empty word")
        for name, top in MAX_S.items():
            value = getattr(self, name)
            zero_ok = name in ("gaze_lead_s", "rest_s")  # the others must be > 0
            above = value >= 0 if zero_ok else value > 0
            if not (math.isfinite(value) and above and value <= top):
                low = "[0" if zero_ok else "(0"
                raise ValueError(
                    f"ProtocolParams.{name} must be in {low}, {top:g}] s, got {value!r}"
                )
        for name, top in (("target_clicks", MAX_TARGET_CLICKS), ("max_attempts", MAX_ATTEMPTS)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= top:
                raise ValueError(
                    f"ProtocolParams.{name} must be an integer in [1, {top}], got {value!r}"
                )
        if not 1 <= len(self.trials) <= MAX_TRIALS:
            raise ValueError(f"ProtocolParams.trials must hold 1 to {MAX_TRIALS} trials")
        indices = [t.index for t in self.trials]
        if indices != list(range(1, len(indices) + 1)):
            raise ValueError(f"ProtocolParams.trials must be numbered 1..n in order, got {indices}")


@dataclass(frozen=True, slots=True)
class TrialTimeline:
    """When each scripted event of one trial happens (s, absolute)."""

    gaze: tuple[tuple[float, GazeCommand], ...]  # gaze commands (gesture first, if any)
    countdown: tuple[tuple[float, str], ...]  # (time, word); the last word is "go"
    go_t: float  # the start signal: both agents may move
    timeout_t: float  # the robot presses the nearest buzzer if the human has not pressed

    @property
    def gaze_set_t(self) -> float:
        """Time the trial's own gaze is commanded (after any gesture)."""
        return self.gaze[-1][0]


def trial_timeline(spec: TrialSpec, start_t: float, params: ProtocolParams) -> TrialTimeline:
    """The schedule of one trial starting at `start_t` (s).

    The gaze (or the attention gesture ending in it) starts at `start_t`; the countdown's first
    word follows `gaze_lead_s` after the gaze is set, then one word per `countdown_interval_s`.
    """
    if not math.isfinite(start_t):
        raise ValueError(f"start_t must be finite, got {start_t!r}")
    if spec.attention_gesture:
        gaze = tuple(attention_gesture(start_t, spec.gaze, params.gesture))
        if spec.gaze.yaw * params.gesture.limit_yaw > 0:
            # The gesture starts on the side opposite the trial's cue, as the paper's trial 4
            # (limit toward red, settle toward O = blue): a counterbalanced O = red mirrors it,
            # or its limit pose (1.4 rad) would be a cue for O stronger than "extreme".
            gaze = (*((t, GazeCommand(-c.yaw, -c.pitch)) for t, c in gaze[:-1]), gaze[-1])
    else:
        gaze = ((start_t, spec.gaze),)
    first_word = gaze[-1][0] + params.gaze_lead_s
    words = tuple(
        (first_word + i * params.countdown_interval_s, w) for i, w in enumerate(params.countdown)
    )
    go_t = words[-1][0]
    return TrialTimeline(gaze, words, go_t, go_t + params.trial_timeout_s)
