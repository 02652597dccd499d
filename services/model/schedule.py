"""The trial schedule (paper Sec 3.2, SPEC §6) over N ≥ 2 options: the trials, times, timelines.

What a session runs — each trial's mode, O, gaze level, the protocol's times and bounds, the
order of O a participant gets, and each trial's timeline (gaze, countdown, "go") — as plain
data and pure functions. `services.model.protocol.SessionProtocol` runs it.

One schedule for any option set (docs/multi-option.md): `OptionsSchedule` holds the option
names (box j of the row, left to right, is `names[j]`) and its `OptionsTrial`s, each naming O
by index. The paper's study is its two-option case, `OptionsSchedule.default(2)`: the options
red and blue and the paper's 8 trials (1-3 dissensus, 4-8 consensus on B R R B R). The clock
runs `TrialSpec`s, the paper's trial form (O a colour, the gaze its printed row):
`paper_specs` gives them for the paper's colours and `default_schedule` is that of the
paper's schedule; `timing_specs` gives the clock's trials on any table (index, gaze toward O,
gesture, level; the N-option runner reads mode and O from the schedule by index). Both trial
forms are checked by the same rules (`check_trial`, `check_trial_numbers`).

A TOML params file selects an option set with a list in `[protocol]`
(`services.core.config.load_with_options`):

    [protocol]
    options = ["red", "blue", "green"]
    trials = [                        # optional; default: `default_options_trials`
        { index = 1, mode = "dissensus" },
        { index = 4, mode = "consensus", option = "green", gaze_level = "minimal",
          attention_gesture = true },
        ...
    ]
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Literal, TypeAlias

from services.model.gaze import (
    GAZE_LEVEL_NAMES,
    AttentionGestureParams,
    GazeCommand,
    attention_gesture,
    gaze_level,
    gaze_toward,
)
from services.model.geometry import Colour, OptionsLayout

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
MAX_OPTIONS = 8  # boxes on one table edge: past this the row's boxes are too narrow to press
OPTION_NAMES = ("red", "blue", "green", "yellow", "white", "black", "orange", "purple")
# The paper's consensus gaze levels in its rising order, trial 4 with the attention gesture
_CONSENSUS_LEVELS = ("minimal", "low", "moderate", "significant", "extreme")
# The paper's O of its consensus trials 4-8 (B R R B R) as indices into its (red, blue)
_PAPER_ORDER = (1, 0, 0, 1, 0)


def check_trial(index: object, mode: object, option: object, level: object) -> None:
    """What a trial must be over any option set, so both trial forms refuse the same rows.

    An integer index >= 1, a known mode, an O in a consensus trial and none in a dissensus
    one, a known gaze level. Whether O is one of the options is the caller's: a colour for
    `TrialSpec`, an index below N_o for `OptionsSchedule`.
    """
    if isinstance(index, bool) or not isinstance(index, int) or index < 1:
        raise ValueError(f"trial index must be an integer >= 1, got {index!r}")
    if mode not in MODES:
        raise ValueError(f"trial {index}: mode must be one of {MODES}, got {mode!r}")
    if (mode == "consensus") != (option is not None):
        raise ValueError(
            f"trial {index}: a consensus trial needs an option O and a dissensus trial "
            f"none, got mode {mode!r} with option {option!r}"
        )
    if level not in GAZE_LEVEL_NAMES:
        raise ValueError(
            f"trial {index}: unknown gaze level {level!r}; expected one of {GAZE_LEVEL_NAMES}"
        )


def check_trial_numbers(indices: Sequence[int], where: str) -> None:
    """A session's trials: 1 to `MAX_TRIALS` of them, numbered 1..n in order."""
    if not 1 <= len(indices) <= MAX_TRIALS:
        raise ValueError(f"{where} must hold 1 to {MAX_TRIALS} trials, got {len(indices)}")
    if list(indices) != list(range(1, len(indices) + 1)):
        raise ValueError(f"{where} must be numbered 1..n in order, got {list(indices)}")


@dataclass(frozen=True, slots=True)
class TrialSpec:
    """What one trial does, as the clock runs it: the paper's trial form (O red or blue).

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
        check_trial(self.index, self.mode, self.option, self.gaze_level)
        if self.option is not None and self.option not in ("red", "blue"):
            raise ValueError(
                f"trial {self.index}: a trial's option O is 'red' or 'blue', got {self.option!r}"
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


@dataclass(frozen=True, slots=True)
class OptionsTrial:
    """One trial over N_o options: its mode, O (an option index; consensus only), its gaze."""

    index: int  # 1-based trial number
    mode: Mode
    option: int | None = None  # O, the consensus option; None in a dissensus trial
    gaze_level: str = "neutral"
    attention_gesture: bool = False

    def __post_init__(self) -> None:
        check_trial(self.index, self.mode, self.option, self.gaze_level)


def default_options_trials(n_options: int) -> tuple[OptionsTrial, ...]:
    """The paper's 8 trials over N_o options: 1-3 dissensus, 4-8 consensus.

    Trials 1-3 have the neutral gaze, 4-8 the paper's levels in its rising order (the attention
    gesture before trial 4). At N_o = 2 the consensus trials converge on the paper's order
    (B R R B R over red, blue: the two-option kernel, so the paper's study is this schedule's
    two-option case). For more, the k-th consensus trial (k = 0…4) converges on option
    k mod N_o, so with up to 5 options every option is O at least once; the paper's order does
    not generalise; a study counterbalances it (`services.model.counterbalance`: rotations
    under the cyclic relabellings of the options).
    """
    trials = [OptionsTrial(i, "dissensus") for i in (1, 2, 3)]
    for k, level in enumerate(_CONSENSUS_LEVELS):
        option = _PAPER_ORDER[k] if n_options == 2 else k % n_options
        trials.append(OptionsTrial(4 + k, "consensus", option, level, k == 0))
    return tuple(trials)


@dataclass(frozen=True, slots=True)
class OptionsSchedule:
    """A session over N_o options: the option names (box j is `names[j]`) and the trials."""

    names: tuple[str, ...]
    trials: tuple[OptionsTrial, ...]

    def __post_init__(self) -> None:
        n = len(self.names)
        if not 2 <= n <= MAX_OPTIONS:
            raise ValueError(f"[protocol] options needs 2 to {MAX_OPTIONS} names, got {n}")
        if any(not isinstance(s, str) or not s for s in self.names) or len(set(self.names)) != n:
            raise ValueError(
                f"[protocol] options must be distinct non-empty names, got {list(self.names)}"
            )
        check_trial_numbers([t.index for t in self.trials], "trials")
        for t in self.trials:
            if t.option is not None and not 0 <= t.option < n:
                raise ValueError(f"trial {t.index}: option {t.option} is not one of the {n}")

    @property
    def n_options(self) -> int:
        """How many options (boxes) the table has."""
        return len(self.names)

    @classmethod
    def default(cls, n_options: int) -> OptionsSchedule:
        """The default names (red, blue, green, …) and `default_options_trials`.

        `default(2)` is the paper's schedule: red, blue and its 8 trials.
        """
        if not 2 <= n_options <= MAX_OPTIONS:
            raise ValueError(f"--options must be in 2..{MAX_OPTIONS}, got {n_options}")
        return cls(OPTION_NAMES[:n_options], default_options_trials(n_options))

    def name(self, option: int | None) -> str | None:
        """The name of an option index (None stays None)."""
        return None if option is None else self.names[option]

    def index_of(self, name: str) -> int:
        """The index of an option name, with the list of names when it is none of them."""
        try:
            return self.names.index(name)
        except ValueError:
            raise ValueError(
                f"unknown option {name!r}; [protocol] options are {list(self.names)}"
            ) from None

    def trial(self, index: int) -> OptionsTrial:
        """Trial `index` (1-based)."""
        return self.trials[index - 1]

    def paper_specs(self) -> tuple[TrialSpec, ...]:
        """The trials in the paper's form: each O by its colour, its gaze the printed row.

        Defined for a schedule whose options are the paper's colours (red, blue): what the
        paper's clock and decision model read, O named as they name it.
        """
        colours: dict[str, Colour] = {"red": "red", "blue": "blue"}
        if set(self.names) != set(colours):
            raise ValueError(
                f"the paper's trial form names O red or blue, not {list(self.names)}"
            )
        return tuple(
            TrialSpec(t.index, t.mode, None if t.option is None else colours[self.names[t.option]],
                      t.gaze_level, attention_gesture=t.attention_gesture)
            for t in self.trials
        )

    def timing_specs(self, layout: OptionsLayout) -> tuple[TrialSpec, ...]:
        """One `TrialSpec` per trial for `SessionProtocol`'s clock on any table (module doc).

        Each carries the trial's index, gaze command (toward its O on this table), level name
        and gesture; its mode is the clock's placeholder: the runner reads mode and O here.
        """
        if layout.n_options != self.n_options:
            raise ValueError(
                f"the table has {layout.n_options} boxes but the schedule {self.n_options} options"
            )
        specs = []
        for t in self.trials:
            gaze = gaze_toward(layout, t.option, t.gaze_level)
            specs.append(
                TrialSpec(t.index, "dissensus", None, t.gaze_level, gaze.yaw, gaze.pitch,
                          t.attention_gesture)
            )
        return tuple(specs)


_TRIAL_KEYS = {"index", "mode", "option", "gaze_level", "attention_gesture"}


def schedule_from_table(protocol: Mapping[str, Any]) -> OptionsSchedule:
    """The schedule of a params file's `[protocol]` table holding `options` (module doc)."""
    names = protocol["options"]
    if not isinstance(names, Sequence) or isinstance(names, str):
        raise ValueError(f"[protocol] options must be an array of names, got {names!r}")
    names = tuple(names)
    raw = protocol.get("trials")
    if raw is None:
        return OptionsSchedule(names, default_options_trials(len(names)))
    trials = []
    for row in raw:
        if not isinstance(row, Mapping):
            raise ValueError(f"[protocol] trials: each trial is a table, got {row!r}")
        unknown = sorted(set(row) - _TRIAL_KEYS)
        if unknown:
            raise ValueError(
                f"[protocol] trials: unknown key(s) {unknown}; known keys are {sorted(_TRIAL_KEYS)}"
            )
        fields = dict(row)
        option = fields.pop("option", None)
        if option is not None:
            if option not in names:
                raise ValueError(f"[protocol] trials: option {option!r} is not in {list(names)}")
            option = names.index(option)
        try:
            trials.append(OptionsTrial(option=option, **fields))
        except TypeError as exc:  # a missing index or mode
            raise ValueError(f"[protocol] trials: {row!r}: {exc}") from None
    return OptionsSchedule(names, tuple(trials))


def default_schedule() -> tuple[TrialSpec, ...]:
    """The paper's 8 trials (SPEC §5/§6) in its trial form: the two-option default schedule.

    1–3 dissensus with neutral gaze, 4–8 consensus on B R R B R at rising gaze levels, the
    attention gesture before trial 4.
    """
    return OptionsSchedule.default(2).paper_specs()


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
        check_trial_numbers([t.index for t in self.trials], "ProtocolParams.trials")


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
