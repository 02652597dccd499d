"""The trial schedule over N_o options: the option set, each trial's mode, O and gaze.

The paper's schedule (`services.model.schedule`) names O red or blue; this one names options
by index into `OptionsSchedule.names` (box j of the row, left to right, is `names[j]`). A TOML
params file selects it with an option list in `[protocol]`:

    [protocol]
    options = ["red", "blue", "green"]
    trials = [                        # optional; default: `default_options_trials`
        { index = 1, mode = "dissensus" },
        { index = 4, mode = "consensus", option = "green", gaze_level = "minimal",
          attention_gesture = true },
        ...
    ]

The session's clock (gaze, countdown, "go", timeout, rest) is the paper's `SessionProtocol`
unchanged: `timing_specs` gives it one `TrialSpec` per trial carrying only what it times (the
index, the gaze command from `gaze.gaze_toward`, the gesture, the level's name); the N_o-option
runner looks each trial's mode and O up here by index.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from services.model.gaze import GAZE_LEVEL_NAMES, gaze_toward
from services.model.geometry import OptionsLayout
from services.model.schedule import MAX_TRIALS, MODES, Mode, TrialSpec

MAX_OPTIONS = 8  # boxes on one table edge: past this the row's boxes are too narrow to press
OPTION_NAMES = ("red", "blue", "green", "yellow", "white", "black", "orange", "purple")
# The paper's consensus gaze levels in its rising order, trial 4 with the attention gesture
_CONSENSUS_LEVELS = ("minimal", "low", "moderate", "significant", "extreme")


@dataclass(frozen=True, slots=True)
class OptionsTrial:
    """One trial over N_o options: its mode, O (an option index; consensus only), its gaze."""

    index: int  # 1-based trial number
    mode: Mode
    option: int | None = None  # O, the consensus option; None in a dissensus trial
    gaze_level: str = "neutral"
    attention_gesture: bool = False

    def __post_init__(self) -> None:
        if isinstance(self.index, bool) or not isinstance(self.index, int) or self.index < 1:
            raise ValueError(f"trial index must be an integer >= 1, got {self.index!r}")
        if self.mode not in MODES:
            raise ValueError(f"trial {self.index}: mode must be one of {MODES}, got {self.mode!r}")
        if (self.mode == "consensus") != (self.option is not None):
            raise ValueError(
                f"trial {self.index}: a consensus trial needs an option O and a dissensus trial "
                f"none, got mode {self.mode!r} with option {self.option!r}"
            )
        if self.gaze_level not in GAZE_LEVEL_NAMES:
            raise ValueError(
                f"trial {self.index}: unknown gaze level {self.gaze_level!r}; expected one of "
                f"{GAZE_LEVEL_NAMES}"
            )


def default_options_trials(n_options: int) -> tuple[OptionsTrial, ...]:
    """The paper's 8 trials over N_o options: 1-3 dissensus, 4-8 consensus with O = k mod N_o.

    Trials 1-3 have the neutral gaze, 4-8 the paper's levels in its rising order (the attention
    gesture before trial 4). The k-th consensus trial (k = 0…4) converges on option k mod N_o,
    so with up to 5 options every option is O at least once; the paper's own order (B R R B R)
    does not generalise, and counterbalancing N_o options is left to the study design.
    """
    trials = [OptionsTrial(i, "dissensus") for i in (1, 2, 3)]
    for k, level in enumerate(_CONSENSUS_LEVELS):
        trials.append(OptionsTrial(4 + k, "consensus", k % n_options, level, k == 0))
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
        if not 1 <= len(self.trials) <= MAX_TRIALS:
            raise ValueError(f"a schedule holds 1 to {MAX_TRIALS} trials, got {len(self.trials)}")
        indices = [t.index for t in self.trials]
        if indices != list(range(1, len(indices) + 1)):
            raise ValueError(f"trials must be numbered 1..n in order, got {indices}")
        for t in self.trials:
            if t.option is not None and not 0 <= t.option < n:
                raise ValueError(f"trial {t.index}: option {t.option} is not one of the {n}")

    @property
    def n_options(self) -> int:
        """How many options (boxes) the table has."""
        return len(self.names)

    @classmethod
    def default(cls, n_options: int) -> OptionsSchedule:
        """The default names (red, blue, green, …) and `default_options_trials`."""
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

    def timing_specs(self, layout: OptionsLayout) -> tuple[TrialSpec, ...]:
        """One `TrialSpec` per trial for `SessionProtocol`'s clock (see the module doc).

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
