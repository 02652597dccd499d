"""The trial schedule over N options and one trial's timeline (SPEC §5/§6).

The paper's 8 trials are the schedule's two-option case (`OptionsSchedule.default(2)`).
"""

from __future__ import annotations

import dataclasses

import pytest

from services.core.config import ConfigError, from_mapping
from services.model.gaze import GAZE_LEVELS, AttentionGestureParams, GazeCommand, gaze_toward
from services.model.geometry import OptionsLayout, TableLayout
from services.model.protocol import (
    ProtocolParams,
    TrialSpec,
    default_schedule,
    trial_timeline,
)
from services.model.schedule import OptionsSchedule, OptionsTrial, schedule_from_table

EXPECTED = [
    # index, mode, option, level, yaw, pitch, gesture
    (1, "dissensus", None, "neutral", 0.0, 0.0, False),
    (2, "dissensus", None, "neutral", 0.0, 0.0, False),
    (3, "dissensus", None, "neutral", 0.0, 0.0, False),
    (4, "consensus", "blue", "minimal", -0.47, 0.31, True),
    (5, "consensus", "red", "low", 0.53, -0.53, False),
    (6, "consensus", "red", "moderate", 0.62, -0.62, False),
    (7, "consensus", "blue", "significant", -0.72, 0.72, False),
    (8, "consensus", "red", "extreme", 1.09, -0.94, False),
]


def test_default_schedule_is_the_spec() -> None:
    got = [dataclasses.astuple(t) for t in default_schedule()]
    assert got == EXPECTED


def test_schedule_agrees_with_the_gaze_table() -> None:
    for spec in default_schedule():
        level = GAZE_LEVELS[spec.gaze_level]  # type: ignore[index]
        assert level.toward(spec.option) == spec.gaze
        # The gaze points at the option: positive yaw is red.
        if spec.option is not None:
            assert (spec.yaw > 0) == (spec.option == "red")


def test_the_papers_schedule_is_the_two_option_default() -> None:
    paper = OptionsSchedule.default(2)
    assert paper.names == ("red", "blue")
    assert paper.paper_specs() == default_schedule()
    # On the paper's table the clock's trials look where the paper's do (gaze's 2-option kernel)
    timing = paper.timing_specs(OptionsLayout.from_table(TableLayout()))
    for spec, clock in zip(default_schedule(), timing, strict=True):
        assert (clock.index, clock.gaze_level, clock.attention_gesture, clock.gaze) == (
            spec.index, spec.gaze_level, spec.attention_gesture, spec.gaze)
    with pytest.raises(ValueError, match="red or blue"):
        OptionsSchedule.default(3).paper_specs()


@pytest.mark.parametrize("n", [3, 4, 5])
def test_the_default_schedule_of_n_options_has_every_option_as_o(n: int) -> None:
    s = OptionsSchedule.default(n)
    assert s.names == ("red", "blue", "green", "yellow", "white")[:n]
    assert [t.mode for t in s.trials] == ["dissensus"] * 3 + ["consensus"] * 5
    assert {t.option for t in s.trials if t.option is not None} == set(range(n))
    assert s.trials[3].attention_gesture and s.trials[3].gaze_level == "minimal"
    specs = s.timing_specs(OptionsLayout.row(n))
    assert [sp.index for sp in specs] == list(range(1, 9))
    assert specs[0].yaw == 0.0
    assert specs[5].gaze == gaze_toward(OptionsLayout.row(n), 2 % n, "moderate")


def test_a_params_table_names_options_and_trials() -> None:
    s = schedule_from_table({
        "options": ["left", "mid", "right"],
        "trials": [{"index": 1, "mode": "dissensus"},
                   {"index": 2, "mode": "consensus", "option": "right", "gaze_level": "low"}],
    })
    assert s.n_options == 3 and s.trial(2).option == 2 and s.name(2) == "right"
    with pytest.raises(ValueError, match="'far' is not in"):
        schedule_from_table({"options": ["a", "b"], "trials": [
            {"index": 1, "mode": "consensus", "option": "far"}]})
    with pytest.raises(ValueError, match="unknown key"):
        schedule_from_table({"options": ["a", "b"], "trials": [{"index": 1, "mood": "x"}]})
    with pytest.raises(ValueError, match="distinct"):
        schedule_from_table({"options": ["a", "a"]})
    with pytest.raises(ValueError, match="numbered"):
        schedule_from_table({"options": ["a", "b"], "trials": [{"index": 2, "mode": "dissensus"}]})
    with pytest.raises(ValueError, match="2..8"):
        OptionsSchedule.default(9)


# The paper's trial form (O a colour) and the N-option form (O an index) refuse the same rows
FORMS = {"paper": (TrialSpec, "red"), "options": (OptionsTrial, 0)}


@pytest.mark.parametrize("form", sorted(FORMS))
@pytest.mark.parametrize(
    "kwargs",
    [
        {"index": 0},
        {"index": True},
        {"mode": "chaos"},
        {"mode": "consensus", "option": None},
        {"mode": "dissensus", "option": "O"},
        {"gaze_level": "furious"},
    ],
)
def test_both_trial_forms_refuse_the_same_rows(form: str, kwargs: dict[str, object]) -> None:
    make, option = FORMS[form]
    row: dict[str, object] = {"index": 1, "mode": "dissensus", "option": None,
                              "gaze_level": "neutral"}
    row.update({k: option if v == "O" else v for k, v in kwargs.items()})
    make(index=1, mode="consensus", option=option)  # the valid row each form starts from
    with pytest.raises(ValueError):
        make(**row)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    "kwargs", [{"mode": "consensus", "option": "green"}, {"yaw": float("nan")}, {"pitch": 4.0}]
)
def test_trial_spec_validation(kwargs: dict[str, object]) -> None:
    """What only the paper's form checks: O a colour, the gaze angles it carries."""
    base: dict[str, object] = {
        "index": 1,
        "mode": "dissensus",
        "option": None,
        "gaze_level": "neutral",
        "yaw": 0.0,
        "pitch": 0.0,
    }
    base.update(kwargs)
    with pytest.raises(ValueError):
        TrialSpec(**base)  # type: ignore[arg-type]


def test_protocol_params_defaults_and_validation() -> None:
    p = ProtocolParams()
    assert p.countdown == ("1", "2", "3", "go")
    assert p.countdown_interval_s == 0.75 and p.trial_timeout_s == 10.0
    assert p.trials == default_schedule() and p.target_clicks == 10
    with pytest.raises(ValueError):
        ProtocolParams(countdown=())
    with pytest.raises(ValueError):
        ProtocolParams(countdown_interval_s=0)
    with pytest.raises(ValueError):
        ProtocolParams(trial_timeout_s=-1)
    with pytest.raises(ValueError, match="numbered"):
        ProtocolParams(trials=default_schedule()[1:])


def test_protocol_params_load_from_toml_mapping() -> None:
    p = from_mapping(
        ProtocolParams,
        {
            "countdown_interval_s": 1,
            "trials": [
                {
                    "index": 1,
                    "mode": "dissensus",
                    "option": None,
                    "gaze_level": "neutral",
                    "yaw": 0,
                    "pitch": 0,
                },
                {
                    "index": 2,
                    "mode": "consensus",
                    "option": "red",
                    "gaze_level": "low",
                    "yaw": 0.53,
                    "pitch": -0.53,
                    "attention_gesture": True,
                },
            ],
        },
    )
    assert p.countdown_interval_s == 1.0 and len(p.trials) == 2
    assert p.trials[1].attention_gesture and p.trials[1].option == "red"
    with pytest.raises(ConfigError):
        from_mapping(ProtocolParams, {"trials": [{"index": 1, "mode": "x"}]})


def test_timeline_without_gesture() -> None:
    spec = default_schedule()[4]  # trial 5
    tl = trial_timeline(spec, 100.0, ProtocolParams())
    assert tl.gaze == ((100.0, GazeCommand(0.53, -0.53)),)
    assert tl.gaze_set_t == 100.0
    assert [w for _, w in tl.countdown] == ["1", "2", "3", "go"]
    assert [t for t, _ in tl.countdown] == pytest.approx([101.0, 101.75, 102.5, 103.25])
    assert tl.go_t == pytest.approx(103.25)
    assert tl.timeout_t == pytest.approx(113.25)


def test_timeline_with_attention_gesture_sets_gaze_before_countdown() -> None:
    spec = default_schedule()[3]  # trial 4
    p = ProtocolParams(gesture=AttentionGestureParams(hold_s=0.6), gaze_lead_s=0.5)
    tl = trial_timeline(spec, 0.0, p)
    assert tl.gaze[0][1].yaw > 1.0  # the gesture looks hard toward red first
    assert tl.gaze[-1] == (pytest.approx(0.6), GazeCommand(-0.47, 0.31))
    assert tl.countdown[0][0] == pytest.approx(1.1)
    assert all(t < tl.countdown[0][0] for t, _ in tl.gaze)  # gaze set before the countdown
