"""A session's summary statistics: what `nod fit` reads of a person from their 8 trials.

One function, `summarise`, from one form, `TrialPath`: a stored trial (its record and its hand's
samples, `services.fit.data`) and a simulated one (`from_offline`, the same fields the cohort
stores) give the same numbers, so the estimator trained on simulations reads real people.

Per trial (k = 1..8, NaN when the trial is missing, interrupted or the hand never moved):
- `onset_k`: seconds from "go" until the hand is `ONSET_DISTANCE` from where it rested
  (reaction time, plus the hand's acceleration);
- `speed_k`: the 90th percentile of the hand centre's speed between onset and press, over
  `SPEED_WINDOW_S` (longer than a frame: the tracker's jitter would dominate a frame's step);
- `press_k`: seconds from "go" to the human's press (the hand centre within reach of the
  pressed box);
- `agree_k`: 1 if the human pressed the robot's buzzer, else 0;
- `switch_k`: the stored switches (the judge's count);
- `turn_k`: 1 if the hand first headed for the other buzzer than the one it pressed;
- consensus trials only: `gaze_first_k` (first heading toward the side the eyes looked at, 1/0)
  and `gaze_press_k` (pressed that side).
Per session: the medians and shares of the same, by phase (control trials, then consensus), and
`late_turns`, turns whose reversal came within `LATE_MARGIN` of the commit line.

Pure: numbers in, numbers out.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from services.model.closed_loop import OfflineTrial
from services.model.geometry import HAND_TEMPLATE, Colour, TableLayout

TRIALS = tuple(range(1, 9))  # the protocol's 8 trials (SPEC §5): 1-3 control, 4-8 consensus
ONSET_DISTANCE = 0.03  # normalised units: ~10 tracker-jitter sds, well before a reach is decided
HEADING_DISTANCE = 0.08  # how far the hand goes before its heading counts as its first choice
SPEED_WINDOW_S = 0.2
LATE_MARGIN = 0.1  # a reversal this close to the commit line (y units) is a late switch
# A press is a landmark inside the box: the hand centre within the hand's extent of it.
PRESS_REACH = float(np.abs(HAND_TEMPLATE).max()) * 0.03


@dataclass(frozen=True, slots=True)
class TrialPath:
    """One trial as the summaries read it: its record's fields and the hand centre's path."""

    trial: int
    mode: str  # "dissensus" (control) or "consensus"
    yaw: float  # the gaze cue (> 0 toward red; 0: no cue)
    human: Colour | None
    robot: Colour | None
    switches: int
    interrupted: bool
    t_s: tuple[float, ...]  # seconds since "go", detected frames only, increasing
    x: tuple[float, ...]
    y: tuple[float, ...]


def colour_of(name: str | None) -> Colour | None:
    """A stored or published press by name, as the summaries read it (not red or blue: none)."""
    return "red" if name == "red" else "blue" if name == "blue" else None


@dataclass
class HandPath:
    """A trial's hand path as it is read, frame by frame: what `TrialPath` keeps of it.

    One rule for a stored trial (`services.fit.data.trial_path`) and a live one (`nod
    estimate`): a detected centre from the trial's "go" on, each later than the last.
    """

    t_s: list[float] = field(default_factory=list)
    x: list[float] = field(default_factory=list)
    y: list[float] = field(default_factory=list)

    def add(self, t_s: float, x: float, y: float) -> None:
        """A detected hand centre `t_s` seconds after "go" (before it, or not later: skipped)."""
        if t_s < 0 or (self.t_s and t_s <= self.t_s[-1]):
            return
        self.t_s.append(t_s)
        self.x.append(x)
        self.y.append(y)

    def trial(self, trial: int, mode: str, yaw: float, human: str | None, robot: str | None,
              switches: int, interrupted: bool) -> TrialPath:
        """The trial's `TrialPath`, presses by name."""
        return TrialPath(trial, mode, yaw, colour_of(human), colour_of(robot), switches,
                         interrupted, tuple(self.t_s), tuple(self.x), tuple(self.y))


def from_offline(trials: Sequence[OfflineTrial]) -> list[TrialPath]:
    """A simulated session's trials as paths, timed as `nod cohort` stores them.

    The cohort stores a simulated trial's "go" at its first sample, so its times start there.
    """
    out = []
    for t in trials:
        t0 = t.samples[0].t_ns if t.samples else 0
        out.append(TrialPath(
            t.trial, t.mode, _yaw_of(t), t.human, t.robot, t.switches, t.interrupted,
            tuple((s.t_ns - t0) / 1e9 for s in t.samples),
            tuple(s.hand_x for s in t.samples), tuple(s.hand_y for s in t.samples),
        ))
    return out


def _yaw_of(t: OfflineTrial) -> float:
    """The trial's gaze side as a yaw sign: the consensus option is where the eyes look."""
    if t.option is None:
        return 0.0
    return 1.0 if t.option == "red" else -1.0


def summary_names() -> tuple[str, ...]:
    """The summaries' names, in the order `summarise` returns them."""
    per_trial = ["onset", "speed", "press", "agree", "switch", "turn", "travel", "slow", "reversal"]
    names = [f"{n}_{k}" for k in TRIALS for n in per_trial]
    names += [f"{n}_{k}" for k in TRIALS[3:] for n in ("gaze_first", "gaze_press")]
    for phase in ("control", "consensus"):
        names += [f"{n}_{phase}" for n in ("onset", "speed", "press", "agree", "switch", "turn",
                                           "travel", "slow", "reversal")]
    names += ["speed_max", "gaze_first", "gaze_press", "late_turns"]
    return tuple(names)


@dataclass(frozen=True, slots=True)
class _Reading:
    onset: float
    speed: float
    press: float
    agree: float
    switch: float
    turn: float
    gaze_first: float
    gaze_press: float
    late: float
    travel: float
    slow: float
    reversal: float


NAN = math.nan


def _side(dx: float, layout: TableLayout) -> Colour:
    """The buzzer a lateral move heads for."""
    red_dx = layout.red.center[0] - layout.blue.center[0]
    return "red" if dx * red_dx > 0 else "blue"


def _press_time(t: np.ndarray, x: np.ndarray, y: np.ndarray, box_of: Colour | None,
                layout: TableLayout) -> float:
    if box_of is None:
        return NAN
    b = layout.box(box_of)
    r = PRESS_REACH
    inside = (x >= b.x1 - r) & (x <= b.x2 + r) & (y >= b.y1 - r) & (y <= b.y2 + r)
    hits = np.flatnonzero(inside)
    return float(t[hits[0]]) if hits.size else NAN


def _speeds(t: np.ndarray, x: np.ndarray, y: np.ndarray, start: float,
            stop: float) -> tuple[float, float]:
    """The 90th and 10th percentiles of the windowed speed between two times."""
    later = np.searchsorted(t, t + SPEED_WINDOW_S)
    ok = (later < t.size) & (t >= start) & (t + SPEED_WINDOW_S <= stop)
    i = np.flatnonzero(ok)
    if i.size == 0:
        return NAN, NAN
    j = later[i]
    v = np.hypot(x[j] - x[i], y[j] - y[i]) / (t[j] - t[i])
    return float(np.percentile(v, 90)), float(np.percentile(v, 10))


def read_trial(p: TrialPath, layout: TableLayout) -> _Reading | None:
    """One trial's readings, or None if it tells nothing (interrupted, no hand)."""
    if p.interrupted or len(p.t_s) < 3:
        return None
    t, x, y = (np.asarray(v, dtype=float) for v in (p.t_s, p.x, p.y))
    dist = np.hypot(x - x[0], y - y[0])
    moved = np.flatnonzero(dist > ONSET_DISTANCE)
    onset = float(t[moved[0]]) if moved.size else NAN
    press = _press_time(t, x, y, p.human, layout)
    speed, slow = _speeds(t, x, y, onset, press if math.isfinite(press) else float(t[-1]))
    far = np.flatnonzero(dist > HEADING_DISTANCE)
    first = _side(float(x[far[0]] - x[0]), layout) if far.size else None
    turn = NAN if first is None or p.human is None else float(first != p.human)
    late = 0.0
    reversal = NAN
    if turn == 1.0:
        # The reversal: the hand's furthest point toward its first side, before the press.
        stop = np.flatnonzero(t <= press)[-1] + 1 if math.isfinite(press) else t.size
        lateral = (x[:stop] - x[0]) * (1 if _side(1.0, layout) == first else -1)
        k = int(np.argmax(lateral))
        late = float(abs(y[k] - layout.commit.y) <= LATE_MARGIN)
        reversal = float(t[k] - onset)
    agree = NAN if p.human is None or p.robot is None else float(p.human == p.robot)
    gaze = "red" if p.yaw > 0 else "blue" if p.yaw < 0 else None
    consensus = p.mode == "consensus" and gaze is not None
    gaze_first = float(first == gaze) if consensus and first is not None else NAN
    gaze_press = float(p.human == gaze) if consensus and p.human is not None else NAN
    return _Reading(onset, speed, press, agree, float(p.switches), turn, gaze_first,
                    gaze_press, late, press - onset, slow, reversal)


def _median(values: Sequence[float]) -> float:
    v = [a for a in values if math.isfinite(a)]
    return float(np.median(v)) if v else NAN


def _mean(values: Sequence[float]) -> float:
    v = [a for a in values if math.isfinite(a)]
    return float(np.mean(v)) if v else NAN


def summarise(paths: Sequence[TrialPath], layout: TableLayout) -> np.ndarray:
    """A session's summaries (`summary_names()` order); NaN where a value cannot be read."""
    readings: dict[int, _Reading] = {}
    modes: dict[int, str] = {}
    for p in paths:
        r = read_trial(p, layout)
        if r is not None and p.trial in TRIALS:
            readings[p.trial] = r
            modes[p.trial] = p.mode
    return _vector(readings, modes)


_FIELDS = ("onset", "speed", "press", "agree", "switch", "turn", "travel", "slow", "reversal")
CONTROL_TRIALS = TRIALS[:3]  # the protocol's phases by trial (SPEC §5)


def _vector(readings: dict[int, _Reading], modes: dict[int, str]) -> np.ndarray:
    """The summaries of a session's readings (trial → reading) and the trials' phases."""
    out: list[float] = []
    for k in TRIALS:
        r = readings.get(k)
        out += [getattr(r, f) if r else NAN for f in _FIELDS]
    for k in TRIALS[3:]:
        r = readings.get(k)
        out += [r.gaze_first if r else NAN, r.gaze_press if r else NAN]
    for phase in ("dissensus", "consensus"):
        rs = [r for k, r in readings.items() if modes[k] == phase]
        for f in _FIELDS:
            values = [getattr(r, f) for r in rs]
            out.append(_mean(values) if f in ("agree", "switch", "turn") else _median(values))
    rs = list(readings.values())
    speeds = [r.speed for r in rs if math.isfinite(r.speed)]
    out += [max(speeds) if speeds else NAN, _mean([r.gaze_first for r in rs]),
            _mean([r.gaze_press for r in rs]), float(sum(r.late for r in rs)) if rs else NAN]
    return np.asarray(out, dtype=float)


def first_trials(summaries: np.ndarray, k: int) -> np.ndarray:
    """Sessions' summaries (F or n × F) as if only their first k trials had been played.

    The per-trial summaries of later trials become NaN (missing, as an unplayed trial is), and
    the phase and session summaries are taken again over the first k trials' per-trial ones by
    the code `summarise` takes them with (phases by trial number, SPEC §5). One exception:
    `late_turns` counts a per-trial reading the vector does not keep, so before the 8th trial
    it is NaN, for simulated and real sessions alike (`services.fit.estimator.estimate_after`
    reads a real session through this function too); at k = 8 it is kept. A session's own
    summaries come back unchanged at k = 8.
    """
    if not 1 <= k <= len(TRIALS):
        raise ValueError(f"a session has 1-{len(TRIALS)} trials, not {k}")
    x = np.asarray(summaries, dtype=float)
    rows = np.atleast_2d(x)
    per = len(_FIELDS)
    gaze_at = per * len(TRIALS)
    out = []
    for row in rows:
        readings: dict[int, _Reading] = {}
        for t in TRIALS[:k]:
            values = dict(zip(_FIELDS, row[per * (t - 1):per * t], strict=True))
            if not np.isfinite(list(values.values())).any():
                continue  # a trial with nothing to read (interrupted, no hand)
            gaze = row[gaze_at + 2 * (t - 4):gaze_at + 2 * (t - 3)] if t > 3 else (NAN, NAN)
            readings[t] = _Reading(gaze_first=float(gaze[0]), gaze_press=float(gaze[1]),
                                   late=NAN, **{f: float(v) for f, v in values.items()})
        modes = {t: "dissensus" if t in CONTROL_TRIALS else "consensus" for t in readings}
        out.append(_vector(readings, modes))
        if k == len(TRIALS):
            out[-1][-1] = row[-1]  # late_turns: the whole session's, as read
    return np.stack(out) if x.ndim == 2 else out[0]


def complete_trials(paths: Sequence[TrialPath]) -> int:
    """How many trials have something to read (not interrupted, a hand on record)."""
    return sum(1 for p in paths if not p.interrupted and len(p.t_s) >= 3)
