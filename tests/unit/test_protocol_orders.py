"""A session's O order: with_order turns each consensus trial's gaze toward its O, parse_order reads
`--order`, and the attention gesture starts opposite the cue (services/model/protocol.py)."""

from __future__ import annotations

import pytest

from services.model.gaze import GAZE_LEVELS, GazeCommand
from services.model.protocol import (
    ProtocolParams,
    default_schedule,
    order_of,
    parse_order,
    trial_timeline,
    with_order,
)


def test_with_order_sets_o_and_turns_the_gaze_toward_it():
    trials = with_order(default_schedule(), ("red", "blue", "blue", "red", "blue"))
    assert order_of(trials) == ("red", "blue", "blue", "red", "blue")
    for old, new in zip(default_schedule(), trials, strict=True):
        assert (new.index, new.mode, new.gaze_level) == (old.index, old.mode, old.gaze_level)
        assert new.attention_gesture == old.attention_gesture
        level = GAZE_LEVELS[new.gaze_level]  # type: ignore[index]
        assert new.gaze == level.toward(new.option)  # the table's row, toward the new O
        if new.option is not None:
            assert (new.yaw > 0) == (new.option == "red")  # positive yaw looks toward red
    assert with_order(default_schedule(), order_of(default_schedule())) == default_schedule()
    ProtocolParams(trials=trials)  # still a valid schedule


@pytest.mark.parametrize("order", [(), ("red",) * 4, ("red",) * 6, ("red", "green") * 2 + ("red",)])
def test_with_order_needs_one_o_per_consensus_trial(order):
    with pytest.raises(ValueError, match="each of the schedule's 5 consensus trials"):
        with_order(default_schedule(), order)


def test_parse_order_takes_names_or_letters():
    want = ("blue", "red", "red", "blue", "red")
    assert parse_order("blue,red,red,blue,red", 5) == want
    assert parse_order("BRRBR", 5) == want == parse_order(" b, R ,r,b,RED ", 5)
    assert parse_order("red", 1) == ("red",) == parse_order("R", 1)
    for bad in ("BRRB", "BRRBRX", "blue,red", "", "B,R,R,B,G"):
        with pytest.raises(ValueError, match="--order needs O for each of the 5"):
            parse_order(bad, 5)


def test_the_attention_gesture_starts_opposite_the_cue():
    params = ProtocolParams()
    paper = trial_timeline(default_schedule()[3], 0.0, params)  # trial 4, O blue
    limit = params.gesture.limit_yaw
    assert [c.yaw for _, c in paper.gaze] == [limit, -0.47]  # toward red, then settle on blue
    red = with_order(default_schedule(), ("red", "red", "red", "blue", "red"))[3]
    mirrored = trial_timeline(red, 0.0, params)
    assert [c.yaw for _, c in mirrored.gaze] == [-limit, 0.47]  # toward blue, then red
    assert mirrored.gaze[-1][1] == GazeCommand(0.47, -0.31)
    assert [t for t, _ in mirrored.gaze] == [t for t, _ in paper.gaze]
