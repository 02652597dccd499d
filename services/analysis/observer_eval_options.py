"""How well the N_o-box observer reads a real hand: paths over N boxes, camera jitter, scores.

The paths are made here, independently of the simulated participant and of the two-option
paths (`services.analysis.observer_eval`, whose camera and jitter model this shares):
minimum-jerk reaches (the velocity profile of human point-to-point movements) over a row of
N_o boxes on the paper's table (`OptionsLayout.row`), seen by a 640×480 camera at 30 or 60 Hz,
21 landmarks jittering together (1–3 px) and apart (0.5 px each). Per target box: a straight
reach, a pause mid-reach, an off-centre start, a slow (3 s) reach; per ordered pair of boxes, a
hand that starts toward one and turns to the other (a genuine change of mind).

Scores, per path: **wrong-argmax frames** (ẑ_h read and leading an option that is not the
truth, counted from `GRACE_S` after each change of the truth), **unread frames** (ẑ_h still
zero then), **extra changes** (changes of ẑ_h's leading option beyond the path's genuine ones)
and the **latency** from each change of the truth until ẑ_h leads the new option for good.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from services.analysis.observer_eval import GRACE_S, HAND_RADIUS, HEIGHT, LANDMARK_PX, WIDTH
from services.model.dynamics import leading_option
from services.model.geometry import HAND_TEMPLATE, OptionsLayout, Point
from services.model.observer import ObserverParams
from services.model.options_observer import OptionsObserver

REST: Point = (0.5, 0.85)  # where the hand waits, on the participant's side of the table


@dataclass(frozen=True)
class Leg:
    """A minimum-jerk move of the hand centre to `to` over `duration` s (None: stay put)."""

    to: Point | None
    duration: float
    heading: int | None = None  # the box the person heads for from this leg on (None: as before)


@dataclass(frozen=True)
class Reach:
    """A scripted hand: start, legs, and how many genuine changes of mind it holds."""

    name: str
    start: Point
    legs: tuple[Leg, ...]
    changes: int = 0

    def sample(self, hz: float) -> Iterator[tuple[float, Point, int | None]]:
        """(t, centre, the box the person heads for) at each camera frame."""
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


def reaches(layout: OptionsLayout) -> list[Reach]:
    """The realistic paths over a layout's boxes (see module doc)."""
    centres = [box.center for box in layout.boxes]
    out: list[Reach] = []
    for j, box in enumerate(centres):
        side = 1.0 if box[0] >= REST[0] else -1.0
        out += [
            Reach(f"straight reach to {j}", REST,
                  (Leg(None, 0.5), Leg(box, 1.2, j), Leg(None, 0.3))),
            Reach(f"pause mid-reach to {j}", REST,
                  (Leg(None, 0.5), Leg(_toward(REST, box, 0.45), 0.7, j), Leg(None, 0.6),
                   Leg(box, 0.8), Leg(None, 0.3))),
            Reach(f"off-centre start to {j}", (REST[0] - side * 0.22, 0.88),
                  (Leg(None, 0.5), Leg(box, 1.4, j), Leg(None, 0.3))),
            Reach(f"slow reach to {j}", REST, (Leg(None, 0.5), Leg(box, 3.0, j), Leg(None, 0.3))),
        ]
        for i, first in enumerate(centres):
            if i != j:
                turn = _toward(REST, first, 0.35)
                out.append(Reach(f"starts to {i}, turns to {j}", REST,
                                 (Leg(None, 0.5), Leg(turn, 0.6, i), Leg(box, 1.0, j),
                                  Leg(None, 0.3)), changes=1))
    return out


def jittered(
    reach: Reach, hz: float, jitter_px: float, rng: np.random.Generator
) -> Iterator[tuple[float, list[Point], int | None]]:
    """The landmarks a tracker reports for each frame (common + each landmark's own jitter)."""
    scale = np.array([1.0 / WIDTH, 1.0 / HEIGHT])
    for t, (x, y), truth in reach.sample(hz):
        common = rng.normal(0.0, jitter_px, 2) * scale
        own = rng.normal(0.0, LANDMARK_PX, HAND_TEMPLATE.shape) * scale
        pts = np.array([x, y]) + HAND_TEMPLATE * HAND_RADIUS + common + own
        yield t, [(float(a), float(b)) for a, b in pts], truth


@dataclass(frozen=True)
class ReachScore:
    """How the observer read one jittered reach."""

    name: str
    counted: int  # frames after the grace of each change of the truth
    wrong: int  # of those: read, and leading another option
    unread: int  # of those: ẑ_h still zero
    extra_changes: int
    latencies: tuple[float, ...]  # per change of the truth; inf if never read for good


def score(
    reach: Reach,
    layout: OptionsLayout,
    params: ObserverParams,
    hz: float,
    jitter_px: float,
    seed: int,
    observer: OptionsObserver | None = None,
) -> ReachScore:
    """Run one observer (a fresh default one unless given) over one jittered reach, score it."""
    observer = observer if observer is not None else OptionsObserver(layout, params)
    rows: list[tuple[float, int | None, int | None]] = []  # (t, leading option read, truth)
    for t, landmarks, truth in jittered(reach, hz, jitter_px, np.random.default_rng(seed)):
        rows.append((t, leading_option(observer.update(landmarks, t).z_hat), truth))
    reads = [lead for _, lead, _ in rows if lead is not None]
    changes = sum(1 for a, b in zip(reads, reads[1:], strict=False) if a != b)
    starts = [i for i, row in enumerate(rows) if row[2] is not None and
              (i == 0 or rows[i - 1][2] != row[2])]
    counted = wrong = unread = 0
    latencies: list[float] = []
    for k, i in enumerate(starts):
        end = starts[k + 1] if k + 1 < len(starts) else len(rows)
        t0, want = rows[i][0], rows[i][2]
        for t, lead, _ in rows[i:end]:
            if t - t0 >= GRACE_S:
                counted += 1
                wrong += lead is not None and lead != want
                unread += lead is None
        good = None
        for j in range(end - 1, i - 1, -1):
            if rows[j][1] != want:
                break
            good = j
        latencies.append(rows[good][0] - t0 if good is not None else math.inf)
    return ReachScore(reach.name, counted, wrong, unread, max(0, changes - reach.changes),
                      tuple(latencies))


@dataclass(frozen=True)
class Summary:
    """Every reach × jitter × seed at one frame rate."""

    n_options: int
    hz: float
    wrong_frac: float
    unread_frac: float
    extra_per_reach: float
    latency_median: float
    latency_p90: float
    worst: str  # the reach with the largest share of wrong-argmax frames
    worst_frac: float


def evaluate(
    n_options: int,
    params: ObserverParams,
    hz: float,
    jitters: tuple[float, ...] = (1.0, 2.0, 3.0),
    seeds: int = 5,
) -> Summary:
    """Score the observer on every reach over `OptionsLayout.row(n_options)` at one rate."""
    layout = OptionsLayout.row(n_options)
    scores = [
        score(reach, layout, params, hz, jitter, seed)
        for reach in reaches(layout)
        for jitter in jitters
        for seed in range(seeds)
    ]
    counted = sum(s.counted for s in scores)
    latencies = sorted(v for s in scores for v in s.latencies)
    by_name: dict[str, list[ReachScore]] = {}
    for s in scores:
        by_name.setdefault(s.name, []).append(s)

    def share(name: str) -> float:
        group = by_name[name]
        return sum(s.wrong for s in group) / max(1, sum(s.counted for s in group))

    worst = max(by_name, key=share)
    return Summary(
        n_options,
        hz,
        sum(s.wrong for s in scores) / max(1, counted),
        sum(s.unread for s in scores) / max(1, counted),
        sum(s.extra_changes for s in scores) / len(scores),
        latencies[len(latencies) // 2],
        latencies[int(0.9 * (len(latencies) - 1))],
        worst,
        share(worst),
    )


def frame_to_frame(params: ObserverParams | None = None) -> ObserverParams:
    """The baseline reading: frame-to-frame motion against the bearings.

    No smoothing, no hold, no hysteresis: Algorithm 1's frame-to-frame M, with the robust
    observer's bearings to the boxes.
    """
    base = params if params is not None else ObserverParams()
    return ObserverParams(a=base.a, k=base.k, smooth_s=0.0, window_s=1e-3, min_speed=0.0,
                          max_angle_deg=89.9, switch_margin=0.0)
