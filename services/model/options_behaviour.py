"""Algorithm 2 over N_o boxes: follow the robot's leading option, debounced (docs/multi-option.md).

`services.model.behaviour` with an option index where it has a sign:

- after "go", start moving toward the box of z_r's leading option once it has one;
- a change of the leading option needs C_max consecutive samples leading the same new option
  (`LeaderDebouncer`, the argmax form of `SignDebouncer`); then stop, pause `pause_s`, and move
  toward the new box. A tie for the largest opinion carries no option: it neither counts toward
  nor breaks a change, as a zero z_r carries no sign;
- when the human pressed (a hand landmark inside a box) or the trial timed out, stop at once and
  press the box nearest the end effector (`OptionsLayout.nearest`).

With two boxes and z_r = (x, −x) it gives `RobotBehaviour`'s commands on x, option 0 for red
(a test checks it on random streams). Pure: time is an argument in seconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from services.model.behaviour import Action, BehaviourParams, Phase
from services.model.debounce import DebounceParams
from services.model.dynamics import leading_option
from services.model.geometry import TIE, OptionsLayout, Point


class LeaderDebouncer:
    """The debounced leading option of a stream of opinion vectors; `feed` one at a time.

    The first sample with a leading option sets it (not a change). A change needs `c_max`
    consecutive samples leading one same other option: a sample of the current leader
    interrupts the run, a sample leading a third option restarts it toward that one.
    """

    def __init__(self, c_max: int = DebounceParams().c_max) -> None:
        """Debounce with `c_max` consecutive samples (validated as DebounceParams)."""
        self.c_max = DebounceParams(c_max).c_max
        self.reset()

    def reset(self) -> None:
        """Forget everything: no leader yet, no samples."""
        self._leader: int | None = None
        self._first: int | None = None
        self._candidate: int | None = None
        self._run = 0
        self._n = 0
        self._onset = 0

    @property
    def leader(self) -> int | None:
        """The debounced leading option, None before the first sample that had one."""
        return self._leader

    @property
    def first(self) -> int | None:
        """The leader set by the first sample that had one."""
        return self._first

    @property
    def onset(self) -> int:
        """Index of the first sample of the run that confirmed the latest change."""
        return self._onset

    def feed(self, z: np.ndarray) -> bool:
        """Take one opinion vector; True when it confirms a change of the leading option."""
        return self.feed_leader(leading_option(z))

    def feed_leader(self, lead: int | None) -> bool:
        """Take one sample's leading option (None: none); True when it confirms a change."""
        i = self._n
        self._n += 1
        if lead is None:
            return False
        if self._leader is None:
            self._leader = self._first = lead
            return False
        if lead == self._leader:
            self._run = 0
            return False
        if lead != self._candidate or self._run == 0:
            self._candidate, self._run, self._onset = lead, 0, i
        self._run += 1
        if self._run < self.c_max:
            return False
        self._run = 0
        self._leader = lead
        return True


@dataclass(frozen=True, slots=True)
class OptionsCommand:
    """One arm command: idle, stop, move toward box `target`, or press box `target`."""

    action: Action
    target: int | None = None
    reason: str = ""

    def __post_init__(self) -> None:
        if self.action not in ("idle", "stop", "move", "press"):
            raise ValueError(f"unknown arm action {self.action!r}")
        if (self.action in ("move", "press")) != (self.target is not None):
            raise ValueError(f"a move or a press needs a target box, idle and stop none: {self}")


# Opinions within this of z_r's largest are tied for it (`leader_or_nearest_tie`): an exact tie
# among the options other than the human's, which the dynamics keep by symmetry, comes out of
# the integrator ~1e-16 apart (the last option is minus the sum of the others), and those ulps
# must not pick the robot's box. Opinions are O(0.1-1), so 1e-9 is far above the rounding and
# far below any real lead.
TIE_TOLERANCE = 1e-9


def leader_or_nearest_tie(
    z: np.ndarray, layout: OptionsLayout, ee: Point, tol: float = TIE_TOLERANCE
) -> int | None:
    """The leading option of z; when several but not all tie for the top, the nearest of them.

    The tie rule of a dissensus robot (docs/multi-option.md): with the controller off and the
    human on h, γ < 0 raises every other option equally, so z_r ties among them; the robot
    follows the tied box nearest its end effector (a tie in distance to the lower index, as
    `OptionsLayout.nearest`). Once it moves there that box gets nearer, so the choice holds.
    All options tied (z = 0) is no leader, as a zero z_r carries no sign; with two options a
    tie is always that, so two boxes read exactly as `leading_option` outside ±tol.
    """
    flat = np.asarray(z, dtype=float)
    top = float(flat.max())
    tied = [j for j in range(flat.size) if flat[j] >= top - tol]
    if len(tied) == 1:
        return tied[0]
    if len(tied) == flat.size:
        return None
    best, best_d = tied[0], math.dist(ee, layout.boxes[tied[0]].center)
    for j in tied[1:]:
        d = math.dist(ee, layout.boxes[j].center)
        if d < best_d - TIE:
            best, best_d = j, d
    return best


class OptionsBehaviour:
    """Algorithm 2 as a state machine over (t, z_r, human press, end effector), N_o boxes."""

    def __init__(
        self,
        layout: OptionsLayout,
        params: BehaviourParams | None = None,
        debounce: DebounceParams | None = None,
        break_ties: bool = False,
    ) -> None:
        """Create the machine for a table of N_o boxes (needed to find the nearest one).

        `break_ties`: a tie for z_r's largest among some options leads with the nearest of
        them (`leader_or_nearest_tie`); off, a tie carries no option (`leading_option`).
        """
        self.layout = layout
        self.params = params if params is not None else BehaviourParams()
        self.debounce = debounce if debounce is not None else DebounceParams()
        self.break_ties = break_ties
        self.reset()

    def reset(self) -> None:
        """Forget the previous trial: back to idle, waiting for `start`."""
        self._phase: Phase = "idle"
        self._t_go: float | None = None
        self._timeout_s = math.inf
        self._t_last: float | None = None
        self._leader = LeaderDebouncer(self.debounce.c_max)
        self._pause_until = 0.0
        self._target: int | None = None
        self._last = OptionsCommand("idle", reason="not started")

    @property
    def phase(self) -> Phase:
        """The current phase name."""
        return self._phase

    @property
    def heading(self) -> int | None:
        """The debounced option the robot follows (None before its first move)."""
        return self._leader.leader

    @property
    def pressed_option(self) -> int | None:
        """The box the robot committed to press, or None."""
        return self._target

    def start(self, t: float, timeout_s: float) -> OptionsCommand:
        """The countdown said "go" at time t (s); the robot presses at `timeout_s` at the latest."""
        if self._phase != "idle":
            raise RuntimeError(f"start() in phase {self._phase!r}; call reset() between trials")
        if not (math.isfinite(timeout_s) and timeout_s > 0):
            raise ValueError(f"timeout_s must be finite and > 0, got {timeout_s!r}")
        self._check_time(t)
        self._t_go, self._timeout_s, self._phase = t, timeout_s, "waiting"
        return self._emit(OptionsCommand("idle", reason="go: waiting for a leading option"))

    def complete(self) -> None:
        """The arm reports the press finished: pressing → done."""
        if self._phase == "pressing":
            self._phase = "done"

    def step(
        self, t: float, z_r: np.ndarray | None, pressed: int | None, ee: Point
    ) -> OptionsCommand:
        """Advance to t (s) and return the command to apply.

        `z_r` is the robot's opinion vector (None: no new sample), `pressed` the box the human
        is pressing (None: none), `ee` the end effector (for the nearest box at the end).
        """
        self._check_time(t)
        if z_r is not None and not np.all(np.isfinite(z_r)):
            raise ValueError(f"z_r must be finite, got {z_r!r}")
        if self._phase == "idle":
            return self._emit(OptionsCommand("idle", reason="not started"))
        if self._phase in ("pressing", "done"):
            return self._emit(self._last)  # repeated, so a driver that missed it converges
        assert self._t_go is not None
        if pressed is not None or t - self._t_go >= self._timeout_s:
            box = self.layout.nearest(ee)
            self._target, self._phase = box, "pressing"
            why = f"human pressed {pressed}" if pressed is not None else "timeout"
            return self._emit(OptionsCommand("press", box, f"{why}: nearest box is {box}"))
        changed = False
        if z_r is not None:
            if self.break_ties:
                lead = leader_or_nearest_tie(z_r, self.layout, ee)
            else:
                lead = leading_option(z_r)
            changed = self._leader.feed_leader(lead)
        leader = self._leader.leader
        if self._phase == "waiting":
            if leader is None:
                return self._emit(OptionsCommand("idle", reason="waiting for a leading option"))
            self._phase = "moving"
            return self._emit(OptionsCommand("move", leader, "first leading option"))
        assert leader is not None  # set before leaving "waiting"
        if changed:
            self._phase, self._pause_until = "pausing", t + self.params.pause_s
            return self._emit(OptionsCommand("stop", reason=f"leader confirmed {leader}: pause"))
        if self._phase == "pausing":
            if t < self._pause_until:
                return self._emit(OptionsCommand("stop", reason="pausing before turning"))
            self._phase = "moving"
            return self._emit(OptionsCommand("move", leader, "pause over"))
        return self._emit(OptionsCommand("move", leader, "continue"))

    def _check_time(self, t: float) -> None:
        if not math.isfinite(t):
            raise ValueError(f"time must be finite, got {t!r}")
        if self._t_last is not None and t < self._t_last:
            raise ValueError(f"time went backwards: {t} < {self._t_last}; pass monotonic time")
        self._t_last = t

    def _emit(self, cmd: OptionsCommand) -> OptionsCommand:
        self._last = cmd
        return cmd
