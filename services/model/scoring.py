"""The participant's score (paper Sec 3.2 Step 4/6, SPEC §6).

Per trial: +1 for pressing the same buzzer as the robot, +1 for exactly `target_clicks` (10)
counter clicks, and −1 if either task failed (one point, however many failed — the reading that
gives the paper's stated session range), and −1 per rule violation:

    both tasks done          +2
    one task done, one not    0
    neither done             −1

so 8 trials without violations score between −8 and 16 (`score_range`). Violations can take a
session below −8.

The counter is entered by the operator (the system does not see it). When it was not entered
(`clicks=None`), the counter task is *unknown*: it earns no point and is not counted as a failure,
so such a trial scores +1 (same buzzer) or −1 (different).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class TrialScore:
    """The parts of one trial's score."""

    buzzer: int  # +1 same buzzer as the robot, else 0
    counter: int  # +1 exactly the target clicks, else 0 (also 0 when unknown)
    failure: int  # −1 if a task is known to have failed, else 0
    penalty: int  # −1 per rule violation (≤ 0)
    counter_known: bool  # False when the operator did not enter the clicks

    @property
    def total(self) -> int:
        """The trial's points."""
        return self.buzzer + self.counter + self.failure + self.penalty


def score_trial(
    same_buzzer: bool, clicks: int | None, violations: int = 0, target_clicks: int = 10
) -> TrialScore:
    """Score one trial from its result, the counter clicks (None: not entered) and violations."""
    if violations < 0:
        raise ValueError(f"violations must be >= 0, got {violations}")
    if clicks is not None and clicks < 0:
        raise ValueError(f"clicks must be >= 0 (or None when not entered), got {clicks}")
    if target_clicks < 1:
        raise ValueError(f"target_clicks must be >= 1, got {target_clicks}")
    counter_ok = clicks is not None and clicks == target_clicks
    counter_failed = clicks is not None and clicks != target_clicks
    failed = (not same_buzzer) or counter_failed
    return TrialScore(
        buzzer=1 if same_buzzer else 0,
        counter=1 if counter_ok else 0,
        failure=-1 if failed else 0,
        penalty=-violations,
        counter_known=clicks is not None,
    )


def trial_points(
    human: object | None, robot: object | None, violations: int, clicks: int | None,
    target_clicks: int = 10,
) -> int:
    """A stored trial's points from its buzzers, violations and clicks (as the judge scores it).

    For clicks entered after the trial was stored: the same buzzer only when both pressed it.
    The buzzers are colours (the paper's two options) or box indices (N options).
    """
    same = human is not None and robot is not None and human == robot
    return score_trial(same, clicks, violations, target_clicks).total


def points_said(
    human: object | None, robot: object | None, violations: int, clicks: int | None,
    target_clicks: int = 10,
) -> str:
    """The points the participant will see, and why, in one line for the operator."""
    same = human is not None and robot is not None and human == robot
    s = score_trial(same, clicks, violations, target_clicks)
    parts = ["same buzzer +1" if same else "not the same buzzer"]
    if clicks is None:
        parts.append("counter not entered")
    elif clicks == target_clicks:
        parts.append(f"counter {clicks} = {target_clicks} +1")
    else:
        parts.append(f"counter {clicks} ≠ {target_clicks}")
    if s.failure:
        parts.append("a task failed −1")
    if violations:
        parts.append(f"{violations} violation(s) −{violations}")
    return f"{s.total} point(s) ({', '.join(parts)})"


def session_score(scores: Iterable[TrialScore]) -> int:
    """The session total: the sum of the trials' points."""
    return sum(s.total for s in scores)


def score_range(n_trials: int = 8) -> tuple[int, int]:
    """(minimum, maximum) session score over n trials without violations: (−n, 2n)."""
    if n_trials < 0:
        raise ValueError(f"n_trials must be >= 0, got {n_trials}")
    return -n_trials, 2 * n_trials
