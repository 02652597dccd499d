"""How well an observer reads a real hand: realistic paths, camera jitter, and three scores.

The paths are made here, independently of the simulated participant: minimum-jerk reaches (the
velocity profile of human point-to-point movements) on the paper's table, seen by a 640×480
camera at 30 or 60 Hz, with 21 landmarks that jitter together (1–3 px, the tracker's frame to
frame error) and apart (0.5 px each). Each path says, frame by frame, which box the person is
heading for (the truth), and how many genuine changes of mind it holds.

Scores, per path and mode:
- wrong-side frames: frames where ẑ_h has the sign of the other box, counted from `GRACE_S`
  after each change of the truth (the first movement, a change of mind) to the end;
- spurious switches: debounced sign changes of ẑ_h (the outcome's switch count) beyond the
  path's genuine ones;
- latency: from each change of the truth to the first frame from which ẑ_h has the new sign
  for good; *added* latency is that minus the paper's own latency on the same path without
  jitter (Algorithm 1 reads a clean movement at once: the delay any windowing adds).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np

from services.model.debounce import DebounceParams
from services.model.geometry import HAND_TEMPLATE, Colour, Point, TableLayout, colour_sign
from services.model.observer import ObserverParams
from services.model.observer_robust import make_observer
from services.model.outcome import OutcomeTracker

WIDTH, HEIGHT = 640, 480
GRACE_S = 0.15  # time given to read a change of the truth before a wrong side counts
HAND_RADIUS = 0.03
LANDMARK_PX = 0.5  # each landmark's own jitter (px), on top of the common one


@dataclass(frozen=True)
class Leg:
    """A move of the hand centre to `to` over `duration` s (minimum jerk), then a hold."""

    to: Point | None  # None: stay where the hand is (a pause)
    duration: float
    heading: Colour | None = None  # the box the person heads for during and after this leg


@dataclass(frozen=True)
class Path:
    """A scripted hand: start point, legs, and the genuine changes of mind it holds."""

    name: str
    start: Point
    legs: tuple[Leg, ...]
    switches: int = 0

    def sample(self, hz: float) -> Iterator[tuple[float, Point, Colour | None]]:
        """(t, centre, truth) at each camera frame."""
        t_end = sum(leg.duration for leg in self.legs)
        t = 0.0
        pos, heading = self.start, None
        bounds = []
        for leg in self.legs:
            target = leg.to if leg.to is not None else pos
            bounds.append((t, t + leg.duration, pos, target, leg.heading or heading))
            t += leg.duration
            pos, heading = target, leg.heading or heading
        n = int(t_end * hz) + 1
        for i in range(n):
            now = i / hz
            for t0, t1, a, b, head in bounds:
                if now <= t1 or (t0, t1) == bounds[-1][:2]:
                    u = min(1.0, max(0.0, (now - t0) / max(t1 - t0, 1e-9)))
                    s = u**3 * (10 - 15 * u + 6 * u * u)  # minimum jerk
                    yield now, (a[0] + (b[0] - a[0]) * s, a[1] + (b[1] - a[1]) * s), head
                    break


def paths(layout: TableLayout | None = None) -> list[Path]:
    """The realistic paths: each toward red and mirrored toward blue."""
    lay = layout or TableLayout()
    out: list[Path] = []
    for colour in ("red", "blue"):
        box = lay.box(colour).center
        side = colour_sign(colour) * (1 if lay.red_on_right else -1)  # +1: the box is on the right
        other: Colour = "blue" if colour == "red" else "red"
        other_box = lay.box(other).center
        rest = (0.5, 0.85)

        def toward(frac: float, a: Point = rest, b: Point = box) -> Point:
            return (a[0] + (b[0] - a[0]) * frac, a[1] + (b[1] - a[1]) * frac)

        out += [
            Path(f"straight reach to {colour}", rest,
                 (Leg(None, 0.5), Leg(box, 1.2, colour), Leg(None, 0.3))),
            Path(f"pause mid-reach to {colour}", rest,
                 (Leg(None, 0.5), Leg(toward(0.45), 0.7, colour), Leg(None, 0.6),
                  Leg(box, 0.8), Leg(None, 0.3))),
            Path(f"sag back on the way to {colour}", rest,
                 (Leg(None, 0.5), Leg(toward(0.4), 0.6, colour),
                  Leg((toward(0.4)[0], toward(0.4)[1] + 0.035), 0.3), Leg(box, 0.9),
                  Leg(None, 0.3))),
            Path(f"change of mind: {other} via a sideways leg to {colour}", rest,
                 (Leg(None, 0.5), Leg(toward(0.35, rest, other_box), 0.6, other),
                  Leg((0.5 + side * 0.12, toward(0.35, rest, other_box)[1] + 0.02), 0.5, colour),
                  Leg(box, 0.8), Leg(None, 0.3)),
                 switches=1),
            Path(f"off-centre start to {colour}", (0.5 - side * 0.22, 0.88),
                 (Leg(None, 0.5), Leg(box, 1.4, colour), Leg(None, 0.3))),
            Path(f"slow reach to {colour}", rest,
                 (Leg(None, 0.5), Leg(box, 3.0, colour), Leg(None, 0.3))),
        ]
    return out


@dataclass(frozen=True)
class Score:
    """How one observer read one path at one frame rate and jitter."""

    path: str
    frames: int
    counted: int  # frames where a wrong side counts (after the grace of each truth change)
    wrong: int
    spurious: int
    latencies: tuple[float, ...]  # one per change of the truth; inf if never read


def frames(
    path: Path, hz: float, jitter_px: float, rng: np.random.Generator
) -> Iterator[tuple[float, list[Point], Colour | None]]:
    """The landmarks a tracker reports for each frame of a path (common + own jitter)."""
    scale = np.array([1.0 / WIDTH, 1.0 / HEIGHT])
    for t, (x, y), truth in path.sample(hz):
        common = rng.normal(0.0, jitter_px, 2) * scale
        own = rng.normal(0.0, LANDMARK_PX, HAND_TEMPLATE.shape) * scale
        pts = np.array([x, y]) + HAND_TEMPLATE * HAND_RADIUS + common + own
        yield t, [(float(a), float(b)) for a, b in pts], truth


def score(
    path: Path,
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
    changes = [  # (row, the new truth) where the truth changes to a colour
        (i, truth)
        for i, (_, _, truth) in enumerate(rows)
        if truth is not None and (i == 0 or rows[i - 1][2] != truth)
    ]
    counted = wrong = 0
    latencies: list[float] = []
    for k, (i, truth) in enumerate(changes):
        end = changes[k + 1][0] if k + 1 < len(changes) else len(rows)
        t0 = rows[i][0]
        want = colour_sign(truth)
        for t, z, _ in rows[i:end]:
            if t - t0 >= GRACE_S:
                counted += 1
                wrong += z * want < 0
        good = None
        for j in range(end - 1, i - 1, -1):  # the start of the final stretch of right readings
            if rows[j][1] * want > 0:
                good = j
            else:
                break
        latencies.append(rows[good][0] - t0 if good is not None else math.inf)
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
    lat = sorted(v for s in scores for v in s.latencies)
    by_path: dict[str, list[Score]] = {}
    for s in scores:
        by_path.setdefault(s.path, []).append(s)
    def share(p: str) -> float:
        return sum(s.wrong for s in by_path[p]) / max(1, sum(s.counted for s in by_path[p]))

    added.sort()
    return Summary(
        params.mode,
        hz,
        wrong / max(1, counted),
        sum(s.spurious for s in scores) / len(scores),
        lat[len(lat) // 2],
        lat[int(0.9 * (len(lat) - 1))],
        added[len(added) // 2],
        added[int(0.9 * (len(added) - 1))],
        max(by_path, key=share),
    )
