"""How well an observer reads a real hand: realistic paths, camera jitter, and their scores.

The paths are made here, independently of the simulated participant: minimum-jerk reaches (the
velocity profile of human point-to-point movements) on the paper's table, seen by a 640×480
camera at 30 or 60 Hz, with 21 landmarks that jitter together (1–3 px, the tracker's frame to
frame error) and apart (0.5 px each). Each path says, frame by frame, which box the person is
heading for (the truth), and how many genuine changes of mind it holds. A path is one type for
any number of boxes: its truth is a colour on the paper's two-box table (`paths`) and a box
index on a row of N_o boxes (`reaches`, over `OptionsLayout.row`).

Scores of the paper's two-box observer, per path and mode (`score`, `evaluate`):
- wrong-side frames: frames where ẑ_h has the sign of the other box, counted from `GRACE_S`
  after each change of the truth (the first movement, a change of mind) to the end;
- spurious switches: debounced sign changes of ẑ_h (the outcome's switch count) beyond the
  path's genuine ones;
- latency: from each change of the truth to the first frame from which ẑ_h has the new sign
  for good; *added* latency is that minus the paper's own latency on the same path without
  jitter (Algorithm 1 reads a clean movement at once: the delay any windowing adds).

Scores of the N_o-box observer (`score_options`, `evaluate_options`), the same ideas on an
argmax: **wrong-argmax frames** (ẑ_h read and leading an option that is not the truth, from
`GRACE_S` after each change of the truth), **unread frames** (ẑ_h still zero then), **extra
changes** (changes of ẑ_h's leading option beyond the path's genuine ones) and the **latency**
until ẑ_h leads the new option for good. The N_o-box paths are, per target box: a straight
reach, a pause mid-reach, an off-centre start, a slow (3 s) reach; per ordered pair of boxes, a
hand that starts toward one and turns to the other (a genuine change of mind).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Generic, TypeVar

import numpy as np

from services.model.debounce import DebounceParams
from services.model.dynamics import leading_option
from services.model.geometry import (
    HAND_TEMPLATE,
    Colour,
    OptionsLayout,
    Point,
    TableLayout,
    colour_sign,
)
from services.model.observer import ObserverParams
from services.model.observer_robust import OptionsObserver, make_observer
from services.model.outcome import OutcomeTracker

WIDTH, HEIGHT = 640, 480
GRACE_S = 0.15  # time given to read a change of the truth before a wrong side counts
HAND_RADIUS = 0.03
LANDMARK_PX = 0.5  # each landmark's own jitter (px), on top of the common one
REST: Point = (0.5, 0.85)  # where the hand waits, on the participant's side of the table

H = TypeVar("H")  # what a path's truth names: a Colour (two boxes) or a box index (N_o boxes)


@dataclass(frozen=True)
class Leg(Generic[H]):
    """A move of the hand centre to `to` over `duration` s (minimum jerk), then a hold."""

    to: Point | None  # None: stay where the hand is (a pause)
    duration: float
    heading: H | None = None  # the box the person heads for from this leg on (None: as before)


@dataclass(frozen=True)
class Path(Generic[H]):
    """A scripted hand: start point, legs, and the genuine changes of mind it holds."""

    name: str
    start: Point
    legs: tuple[Leg[H], ...]
    switches: int = 0

    def sample(self, hz: float) -> Iterator[tuple[float, Point, H | None]]:
        """(t, centre, truth) at each camera frame."""
        t0, pos, heading = 0.0, self.start, None
        spans = []
        for leg in self.legs:
            to = leg.to if leg.to is not None else pos
            heading = leg.heading if leg.heading is not None else heading
            spans.append((t0, t0 + leg.duration, pos, to, heading))
            t0, pos = t0 + leg.duration, to
        for i in range(int(t0 * hz) + 1):
            now = i / hz
            a0, a1, a, b, head = next((s for s in spans if now <= s[1]), spans[-1])
            u = min(1.0, max(0.0, (now - a0) / max(a1 - a0, 1e-9)))
            s = u**3 * (10 - 15 * u + 6 * u * u)  # minimum jerk
            yield now, (a[0] + (b[0] - a[0]) * s, a[1] + (b[1] - a[1]) * s), head


def _toward(a: Point, b: Point, frac: float) -> Point:
    return (a[0] + (b[0] - a[0]) * frac, a[1] + (b[1] - a[1]) * frac)


def paths(layout: TableLayout | None = None) -> list[Path[Colour]]:
    """The realistic paths on the paper's table: each toward red and mirrored toward blue."""
    lay = layout or TableLayout()
    out: list[Path[Colour]] = []
    for colour in ("red", "blue"):
        box = lay.box(colour).center
        side = colour_sign(colour) * (1 if lay.red_on_right else -1)  # +1: the box is on the right
        other: Colour = "blue" if colour == "red" else "red"
        other_box = lay.box(other).center
        turn = _toward(REST, other_box, 0.35)
        sag = _toward(REST, box, 0.4)
        out += [
            Path(f"straight reach to {colour}", REST,
                 (Leg(None, 0.5), Leg(box, 1.2, colour), Leg(None, 0.3))),
            Path(f"pause mid-reach to {colour}", REST,
                 (Leg(None, 0.5), Leg(_toward(REST, box, 0.45), 0.7, colour), Leg(None, 0.6),
                  Leg(box, 0.8), Leg(None, 0.3))),
            Path(f"sag back on the way to {colour}", REST,
                 (Leg(None, 0.5), Leg(sag, 0.6, colour), Leg((sag[0], sag[1] + 0.035), 0.3),
                  Leg(box, 0.9), Leg(None, 0.3))),
            Path(f"change of mind: {other} via a sideways leg to {colour}", REST,
                 (Leg(None, 0.5), Leg(turn, 0.6, other),
                  Leg((0.5 + side * 0.12, turn[1] + 0.02), 0.5, colour),
                  Leg(box, 0.8), Leg(None, 0.3)),
                 switches=1),
            Path(f"off-centre start to {colour}", (0.5 - side * 0.22, 0.88),
                 (Leg(None, 0.5), Leg(box, 1.4, colour), Leg(None, 0.3))),
            Path(f"slow reach to {colour}", REST,
                 (Leg(None, 0.5), Leg(box, 3.0, colour), Leg(None, 0.3))),
        ]
    return out


def reaches(layout: OptionsLayout) -> list[Path[int]]:
    """The realistic paths over a layout's N_o boxes (see module doc)."""
    centres = [box.center for box in layout.boxes]
    out: list[Path[int]] = []
    for j, box in enumerate(centres):
        side = 1.0 if box[0] >= REST[0] else -1.0
        out += [
            Path(f"straight reach to {j}", REST,
                 (Leg(None, 0.5), Leg(box, 1.2, j), Leg(None, 0.3))),
            Path(f"pause mid-reach to {j}", REST,
                 (Leg(None, 0.5), Leg(_toward(REST, box, 0.45), 0.7, j), Leg(None, 0.6),
                  Leg(box, 0.8), Leg(None, 0.3))),
            Path(f"off-centre start to {j}", (REST[0] - side * 0.22, 0.88),
                 (Leg(None, 0.5), Leg(box, 1.4, j), Leg(None, 0.3))),
            Path(f"slow reach to {j}", REST, (Leg(None, 0.5), Leg(box, 3.0, j), Leg(None, 0.3))),
        ]
        for i, first in enumerate(centres):
            if i != j:
                turn = _toward(REST, first, 0.35)
                out.append(Path(f"starts to {i}, turns to {j}", REST,
                                (Leg(None, 0.5), Leg(turn, 0.6, i), Leg(box, 1.0, j),
                                 Leg(None, 0.3)), switches=1))
    return out


def frames(
    path: Path[H], hz: float, jitter_px: float, rng: np.random.Generator
) -> Iterator[tuple[float, list[Point], H | None]]:
    """The landmarks a tracker reports for each frame of a path (common + own jitter)."""
    scale = np.array([1.0 / WIDTH, 1.0 / HEIGHT])
    for t, (x, y), truth in path.sample(hz):
        common = rng.normal(0.0, jitter_px, 2) * scale
        own = rng.normal(0.0, LANDMARK_PX, HAND_TEMPLATE.shape) * scale
        pts = np.array([x, y]) + HAND_TEMPLATE * HAND_RADIUS + common + own
        yield t, [(float(a), float(b)) for a, b in pts], truth


def _truth_changes(rows: Sequence[tuple[float, object, H | None]]) -> list[tuple[int, int, H]]:
    """(first row, end row, the new truth) for each stretch of rows after a change of the truth."""
    starts = [(i, truth) for i, (_, _, truth) in enumerate(rows)
              if truth is not None and (i == 0 or rows[i - 1][2] != truth)]
    return [(i, starts[k + 1][0] if k + 1 < len(starts) else len(rows), truth)
            for k, (i, truth) in enumerate(starts)]


def _latency(t0: float, right: list[tuple[float, bool]]) -> float:
    """From t0 to the first of the final stretch of right readings (inf if the last is wrong)."""
    good = None
    for j in range(len(right) - 1, -1, -1):
        if not right[j][1]:
            break
        good = j
    return right[good][0] - t0 if good is not None else math.inf


# -- the paper's two boxes ---------------------------------------------------------------------


@dataclass(frozen=True)
class Score:
    """How one observer read one path at one frame rate and jitter."""

    path: str
    frames: int
    counted: int  # frames where a wrong side counts (after the grace of each truth change)
    wrong: int
    spurious: int
    latencies: tuple[float, ...]  # one per change of the truth; inf if never read


def score(
    path: Path[Colour],
    params: ObserverParams,
    hz: float,
    jitter_px: float,
    seed: int,
    layout: TableLayout | None = None,
) -> Score:
    """Run one observer over one jittered path and score it."""
    lay = layout or TableLayout()
    observer = make_observer(params, lay)
    tracker = OutcomeTracker(DebounceParams(), lay.commit, params.switch_dead_band)
    rng = np.random.default_rng(seed)
    rows: list[tuple[float, float, Colour | None]] = []
    for t, landmarks, truth in frames(path, hz, jitter_px, rng):
        z = observer.update(landmarks, t).z_hat
        tracker.add(z, None)
        rows.append((t, z, truth))
    counted = wrong = 0
    latencies: list[float] = []
    changes: list[tuple[int, int, Colour]] = _truth_changes(rows)
    for i, end, heading in changes:
        t0 = rows[i][0]
        want = colour_sign(heading)
        for t, z, _ in rows[i:end]:
            if t - t0 >= GRACE_S:
                counted += 1
                wrong += z * want < 0
        latencies.append(_latency(t0, [(t, z * want > 0) for t, z, _ in rows[i:end]]))
    spurious = max(0, tracker.switches - path.switches)
    return Score(path.name, len(rows), counted, wrong, spurious, tuple(latencies))


@dataclass(frozen=True)
class Summary:
    """One observer mode over every path, frame rate, jitter and seed."""

    mode: str
    hz: float
    wrong_frac: float
    spurious_per_reach: float
    latency_median: float
    latency_p90: float
    added_median: float  # latency beyond the paper's on the clean path
    added_p90: float
    worst_path: str  # the path with the largest share of wrong-side frames


def _median_p90(values: list[float]) -> tuple[float, float]:
    ordered = sorted(values)
    return ordered[len(ordered) // 2], ordered[int(0.9 * (len(ordered) - 1))]


def evaluate(
    params: ObserverParams,
    hz: float,
    jitters: tuple[float, ...] = (1.0, 2.0, 3.0),
    seeds: int = 5,
    progress: Callable[[], None] | None = None,
) -> Summary:
    """Score a mode on every path × jitter × seed at one frame rate."""
    scores: list[Score] = []
    added: list[float] = []
    paper = ObserverParams(mode="paper")
    for path in paths():
        clean = score(path, paper, hz, 0.0, 0).latencies
        for jitter in jitters:
            for seed in range(seeds):
                s = score(path, params, hz, jitter, seed)
                scores.append(s)
                added += [a - b for a, b in zip(s.latencies, clean, strict=True)]
                if progress:
                    progress()
    counted = sum(s.counted for s in scores)
    wrong = sum(s.wrong for s in scores)
    by_path: dict[str, list[Score]] = {}
    for s in scores:
        by_path.setdefault(s.path, []).append(s)

    def share(p: str) -> float:
        return sum(s.wrong for s in by_path[p]) / max(1, sum(s.counted for s in by_path[p]))

    return Summary(
        params.mode,
        hz,
        wrong / max(1, counted),
        sum(s.spurious for s in scores) / len(scores),
        *_median_p90([v for s in scores for v in s.latencies]),
        *_median_p90(added),
        max(by_path, key=share),
    )


# -- N_o boxes ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class ReachScore:
    """How the N_o-box observer read one jittered path."""

    name: str
    counted: int  # frames after the grace of each change of the truth
    wrong: int  # of those: read, and leading another option
    unread: int  # of those: ẑ_h still zero
    extra_changes: int
    latencies: tuple[float, ...]  # per change of the truth; inf if never read for good


def score_options(
    reach: Path[int],
    layout: OptionsLayout,
    params: ObserverParams,
    hz: float,
    jitter_px: float,
    seed: int,
    observer: OptionsObserver | None = None,
) -> ReachScore:
    """Run one observer (a fresh default one unless given) over one jittered path, score it."""
    observer = observer if observer is not None else OptionsObserver(layout, params)
    rows: list[tuple[float, int | None, int | None]] = []  # (t, leading option read, truth)
    for t, landmarks, truth in frames(reach, hz, jitter_px, np.random.default_rng(seed)):
        rows.append((t, leading_option(observer.update(landmarks, t).z_hat), truth))
    reads = [lead for _, lead, _ in rows if lead is not None]
    changes = sum(1 for a, b in zip(reads, reads[1:], strict=False) if a != b)
    counted = wrong = unread = 0
    latencies: list[float] = []
    for i, end, want in _truth_changes(rows):
        t0 = rows[i][0]
        for t, lead, _ in rows[i:end]:
            if t - t0 >= GRACE_S:
                counted += 1
                wrong += lead is not None and lead != want
                unread += lead is None
        latencies.append(_latency(t0, [(t, lead == want) for t, lead, _ in rows[i:end]]))
    return ReachScore(reach.name, counted, wrong, unread, max(0, changes - reach.switches),
                      tuple(latencies))


@dataclass(frozen=True)
class OptionsSummary:
    """The N_o-box observer over every path × jitter × seed at one frame rate."""

    n_options: int
    hz: float
    wrong_frac: float
    unread_frac: float
    extra_per_reach: float
    latency_median: float
    latency_p90: float
    worst: str  # the path with the largest share of wrong-argmax frames
    worst_frac: float


def evaluate_options(
    n_options: int,
    params: ObserverParams,
    hz: float,
    jitters: tuple[float, ...] = (1.0, 2.0, 3.0),
    seeds: int = 5,
) -> OptionsSummary:
    """Score the observer on every path over `OptionsLayout.row(n_options)` at one rate."""
    layout = OptionsLayout.row(n_options)
    scores = [
        score_options(reach, layout, params, hz, jitter, seed)
        for reach in reaches(layout)
        for jitter in jitters
        for seed in range(seeds)
    ]
    counted = sum(s.counted for s in scores)
    by_name: dict[str, list[ReachScore]] = {}
    for s in scores:
        by_name.setdefault(s.name, []).append(s)

    def share(name: str) -> float:
        group = by_name[name]
        return sum(s.wrong for s in group) / max(1, sum(s.counted for s in group))

    worst = max(by_name, key=share)
    return OptionsSummary(
        n_options,
        hz,
        sum(s.wrong for s in scores) / max(1, counted),
        sum(s.unread for s in scores) / max(1, counted),
        sum(s.extra_changes for s in scores) / len(scores),
        *_median_p90([v for s in scores for v in s.latencies]),
        worst,
        share(worst),
    )


def frame_to_frame(params: ObserverParams | None = None) -> ObserverParams:
    """The baseline reading of the N_o-box benchmark: frame-to-frame motion against bearings.

    No smoothing, no hold, no hysteresis: Algorithm 1's frame-to-frame M, with the robust
    observer's bearings to the boxes.
    """
    base = params if params is not None else ObserverParams()
    return ObserverParams(a=base.a, k=base.k, smooth_s=0.0, window_s=1e-3, min_speed=0.0,
                          max_angle_deg=89.9, switch_margin=0.0)
