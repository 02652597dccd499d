"""The 8-trial schedule and one trial's timeline (SPEC §5/§6)."""

from __future__ import annotations

import dataclasses

import pytest

from services.core.config import ConfigError, from_mapping
from services.model.gaze import GAZE_LEVELS, AttentionGestureParams, GazeCommand
from services.model.protocol import (
    ProtocolParams,
    TrialSpec,
    default_schedule,
    trial_timeline,
)

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


@pytest.mark.parametrize(
    "kwargs",
    [
        {"index": 0},
        {"mode": "chaos"},
        {"mode": "consensus", "option": None},
        {"mode": "dissensus", "option": "red"},
        {"gaze_level": "furious"},
        {"yaw": float("nan")},
    ],
)
def test_trial_spec_validation(kwargs: dict[str, object]) -> None:
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
