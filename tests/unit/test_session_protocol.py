"""The protocol state machine the conductor and the offline loop both drive (SPEC §6)."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.model.gaze import GAZE_LEVELS
from services.model.protocol import ProtocolParams, SessionProtocol, trial_timeline

P = ProtocolParams()


def run(
    protocol: SessionProtocol,
    dt: float,
    human_after: float | None = 2.0,
    robot_after: float | None = 0.5,
    t0: float = 0.0,
) -> list[tuple[float, str, int | None, str]]:
    """Drive a whole session in steps of dt; the human presses `human_after` s after go, the
    robot `robot_after` s after the human (None: never). Returns (t, kind, trial, text)."""
    log: list[tuple[float, str, int | None, str]] = []
    t = t0
    go_t = human_t = None
    cues = protocol.start(t)
    while True:
        for cue in cues:
            log.append((t, cue.kind, cue.trial.index if cue.trial else None, cue.text))
            if cue.kind == "go":
                go_t, human_t = t, None
            if cue.kind == "end":  # presses belong to one trial, as the conductor's recorder
                go_t = human_t = None
                cues += protocol.judged(t)
        if protocol.done:
            return log
        t += dt
        human = human_after is not None and go_t is not None and t >= go_t + human_after
        if human and human_t is None:
            human_t = t
        robot = robot_after is not None and human_t is not None and t >= human_t + robot_after
        cues = protocol.advance(t, human_pressed=human, robot_pressed=robot)
        assert t < 1e4


def test_a_session_gives_every_cue_in_order():
    log = run(SessionProtocol(P), 0.01)
    kinds = [k for _, k, _, _ in log]
    assert kinds[-1] == "session_end"
    per_trial = [[k for _, k, i, _ in log if i == n] for n in range(1, 9)]
    for n, kinds in enumerate(per_trial, start=1):
        gazes = 2 if n == 4 else 1  # trial 4: the attention gesture's limit pose, then the cue
        assert kinds == ["gaze", "setup"] + ["gaze"] * (gazes - 1) + [
            "countdown", "countdown", "countdown", "go", "end"
        ]
    words = [text for _, k, i, text in log if i == 1 and k in ("countdown", "go")]
    assert words == ["1", "2", "3", "go"]


def test_go_comes_after_the_gaze_lead_and_the_countdown():
    log = run(SessionProtocol(P), 0.001)
    for n in (1, 4):
        start = next(t for t, k, i, _ in log if i == n and k == "setup")
        go = next(t for t, k, i, _ in log if i == n and k == "go")
        gesture = P.gesture.duration_s if n == 4 else 0.0
        expected = gesture + P.gaze_lead_s + 3 * P.countdown_interval_s
        assert go - start == pytest.approx(expected, abs=0.0015)


def test_the_gesture_poses_come_before_the_trials_gaze():
    protocol = SessionProtocol(P, first_trial=4)
    cues = protocol.start(0.0)
    assert [(c.kind, c.gesture) for c in cues] == [("gaze", True), ("setup", False)]
    assert cues[0].gaze is not None and cues[0].gaze.yaw == pytest.approx(P.gesture.limit_yaw)
    later = protocol.advance(P.gesture.hold_s)
    assert [(c.kind, c.gesture) for c in later] == [("gaze", False)]
    assert later[0].gaze == GAZE_LEVELS["minimal"].toward("blue")


def test_timeout_then_robot_wait_end_the_trial_without_presses():
    protocol = SessionProtocol(P)
    protocol.start(0.0)
    go = trial_timeline(P.trials[0], 0.0, P).go_t
    cues = protocol.advance(go + P.trial_timeout_s - 1e-6)
    assert [c.kind for c in cues] == ["countdown"] * 3 + ["go"]
    assert protocol.phase == "running"
    assert protocol.advance(go + P.trial_timeout_s) == []
    assert protocol.phase == "robot"
    end = protocol.advance(go + P.trial_timeout_s + P.robot_wait_s)
    assert [c.kind for c in end] == ["end"]
    assert protocol.end is not None and protocol.end.reason == "timeout; robot did not press"



def test_a_press_after_the_timeout_does_not_count_as_the_humans():
    protocol = SessionProtocol(P)
    protocol.start(0.0)
    go = trial_timeline(P.trials[0], 0.0, P).go_t
    protocol.advance(go + P.trial_timeout_s)  # the timeout: the arm goes to press
    protocol.advance(go + P.trial_timeout_s + 0.5, human_pressed=True)  # a hand arrives late
    protocol.advance(go + P.trial_timeout_s + 1.0, human_pressed=True, robot_pressed=True)
    end = protocol.end
    assert end is not None and not end.human_pressed and end.reason == "timeout"
    assert end.counted_press("red") is None


def test_a_press_in_time_counts():
    protocol = SessionProtocol(P)
    protocol.start(0.0)
    go = trial_timeline(P.trials[0], 0.0, P).go_t
    protocol.advance(go + 2.0, human_pressed=True)
    protocol.advance(go + 3.0, human_pressed=True, robot_pressed=True)
    assert protocol.end is not None and protocol.end.counted_press("blue") == "blue"

def test_a_press_at_the_timeouts_instant_is_the_humans_once_timed_out_none_is():
    # "A press after the timeout is not the person's": one seen at the timeout's very instant
    # is in time (the press wins the tie); once a step has reached the timeout without a press,
    # a press a hair later is not.
    go = trial_timeline(P.trials[0], 0.0, P).go_t
    timeout = go + P.trial_timeout_s
    for pressed_at_timeout, counted in ((True, "blue"), (False, None)):
        protocol = SessionProtocol(P)
        protocol.start(0.0)
        protocol.advance(math.nextafter(timeout, -math.inf))  # the last instant before it
        assert protocol.phase == "running"
        protocol.advance(timeout, human_pressed=pressed_at_timeout)
        assert protocol.phase == "robot"
        protocol.advance(math.nextafter(timeout, math.inf), human_pressed=True)
        protocol.advance(timeout + 1.0, human_pressed=True, robot_pressed=True)
        end = protocol.end
        assert end is not None and end.human_pressed == (counted is not None)
        assert end.counted_press("blue") == counted


def test_the_next_trial_waits_for_judged_then_rests():
    protocol = SessionProtocol(P)
    protocol.start(0.0)
    protocol.advance(100.0, human_pressed=True, robot_pressed=True)  # catches up: go, then end
    assert protocol.phase == "judging"
    assert protocol.advance(500.0) == []  # the operator takes their time
    with pytest.raises(RuntimeError):
        protocol.start(0.0)
    assert protocol.judged(500.0) == []
    assert protocol.next_due() == 500.0 + P.rest_s
    nxt = protocol.advance(500.0 + P.rest_s)
    assert [c.kind for c in nxt] == ["gaze", "setup"] and nxt[0].trial is P.trials[1]
    with pytest.raises(RuntimeError):
        protocol.judged(501.0)


@settings(max_examples=40, deadline=None)
@given(dt=st.floats(0.003, 0.9), human_after=st.one_of(st.none(), st.floats(0.0, 9.0)))
def test_coarse_steps_never_skip_or_repeat_a_cue(dt, human_after):
    fine = run(SessionProtocol(P), 0.01, human_after=human_after)
    coarse = run(SessionProtocol(P), dt, human_after=human_after)
    assert [(k, i, x) for _, k, i, x in coarse] == [(k, i, x) for _, k, i, x in fine]


def test_resume_starts_at_the_given_trial_and_validates():
    log = run(SessionProtocol(P, first_trial=7), 0.02)
    assert {i for _, _, i, _ in log if i is not None} == {7, 8}
    with pytest.raises(ValueError):
        SessionProtocol(P, first_trial=9)
    with pytest.raises(ValueError):
        SessionProtocol(P).advance(math.nan)


def test_next_due_is_the_next_scripted_time():
    protocol = SessionProtocol(P)
    protocol.start(10.0)
    assert protocol.next_due() == pytest.approx(10.0 + P.gaze_lead_s)  # the first word


def test_an_interrupted_trial_is_repeated_after_resume():
    protocol = SessionProtocol(P, first_trial=2)
    protocol.start(0.0)
    go = protocol.timeline.go_t
    protocol.advance(go + 0.5)
    assert protocol.running_trial and protocol.attempt == 1
    cues = protocol.interrupt(go + 0.6, "actuation: e-stop: operator")
    assert [(c.kind, c.trial.index, c.text) for c in cues] == [
        ("interrupted", 2, "actuation: e-stop: operator")
    ]
    assert protocol.phase == "paused" and not protocol.running_trial
    assert protocol.advance(1000.0, human_pressed=True, robot_pressed=True) == []  # held
    again = protocol.resume(1000.0)
    assert [c.kind for c in again] == ["gaze", "setup"] and again[1].trial.index == 2
    assert protocol.attempt == 2
    with pytest.raises(RuntimeError):
        protocol.resume(1001.0)


def test_a_trial_is_skipped_after_max_attempts_or_when_repeats_are_off():
    cases = ((ProtocolParams(max_attempts=2), 2), (ProtocolParams(repeat_interrupted=False), 1))
    for params, attempts in cases:
        protocol = SessionProtocol(params)
        protocol.start(0.0)
        for _ in range(attempts):
            assert protocol.trial.index == 1
            protocol.interrupt(1.0, "eyes: gaze stale")
            cues = protocol.resume(2.0)
        assert cues[1].trial.index == 2 and protocol.attempt == 1
    with pytest.raises(RuntimeError):
        SessionProtocol(P).interrupt(0.0, "nothing under way")


@pytest.mark.parametrize("max_attempts", [1, 2, 3, 5])
def test_starts_made_before_a_resume_count_against_max_attempts(max_attempts):
    # A resumed session's trial had `before` starts already (interrupted, or lost with a dead
    # conductor): its first start now is attempt before + 1, and it gets only the starts left,
    # so over the crash the trial is started exactly max_attempts times, never one more.
    params = ProtocolParams(max_attempts=max_attempts)
    for before in range(max_attempts):
        protocol = SessionProtocol(params, first_trial=3, attempts_before=before)
        protocol.start(0.0)
        starts = []
        while protocol.trial is not None and protocol.trial.index == 3:
            starts.append(protocol.attempt)
            protocol.interrupt(1.0, "eyes: gaze stale")
            protocol.resume(2.0)
        assert starts == list(range(before + 1, max_attempts + 1))
        assert protocol.trial.index == 4 and protocol.attempt == 1
    with pytest.raises(ValueError, match="attempts_before"):  # none left: nothing to resume
        SessionProtocol(params, first_trial=3, attempts_before=max_attempts)


def test_a_gated_trial_waits_for_the_operator_and_cues_from_the_start():
    from dataclasses import replace as _replace

    gated = SessionProtocol(_replace(P, gate=True))
    assert gated.start(0.0) == [] and gated.waiting_for_operator
    assert gated.next_due() == math.inf and gated.advance(500.0) == []  # time alone: nothing
    cues = gated.open_gate(600.0)  # the operator: the trial's script starts now
    assert [c.kind for c in cues][:2] == ["gaze", "setup"] and gated.phase == "cueing"
    assert gated.timeline is not None and gated.timeline.go_t > 600.0
    assert gated.open_gate(601.0) == []  # a second start changes nothing


def test_the_operators_pause_holds_the_next_trial_only():
    protocol = SessionProtocol(P)
    assert any(c.kind == "setup" for c in protocol.start(0.0))
    protocol.hold()  # during trial 1: it goes on, trial 2 will wait
    go = protocol.timeline.go_t
    protocol.advance(go + 1.0, human_pressed=True, robot_pressed=True)
    protocol.judged(go + 1.5)
    assert protocol.advance(go + 100.0) == [] and protocol.waiting_for_operator
    assert protocol.trial.index == 2
    cues = protocol.open_gate(go + 200.0)
    assert any(c.kind == "setup" and c.trial.index == 2 for c in cues)
    # Ungated again: trial 3 follows trial 2 by itself.
    go2 = protocol.timeline.go_t
    protocol.advance(go2 + 1.0, human_pressed=True, robot_pressed=True)
    protocol.judged(go2 + 1.5)
    assert any(c.kind == "setup" for c in protocol.advance(go2 + 100.0))
