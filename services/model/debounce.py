"""The one debounce of the project: the leading option of a noisy stream, changed only by a run.

Algorithm 2 turns the robot only after `c_max` consecutive samples of a new leading option of
z_r, and SPEC §6 counts the human's switches of ẑ_h "debounced like Algorithm 2": both use this
debounce with the same `DebounceParams`, for any number of options.

- The first sample with a leading option sets it (it is not a change).
- A change needs `c_max` consecutive samples leading one same other option; a sample of the
  current leader interrupts the run, a sample leading a third option restarts it toward that
  one.
- A sample with no leading option (a tie, a zero) carries none: it neither counts toward a run
  nor breaks one.

`LeaderDebouncer` is the general form (option indices). `SignDebouncer` is its two-option
reading, the paper's: the sign of a number, +1 the option 0 (red) and −1 the option 1 (blue),
zero none. It is the same counter fed through that map, not a second one, so the robot and the
switch count of the paper's study are the N-option code at N = 2 (tests/unit/test_debounce.py
holds the two to the same changes, signs and onsets on random streams).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from services.model.dynamics import leading_option


@dataclass(frozen=True, slots=True)
class DebounceParams:
    """How many samples confirm a change of sign (SPEC §4: C_max = 4)."""

    # Consecutive samples of the opposite sign needed to confirm a change; ≥ 1. Larger = steadier
    # (robot and switch count), slower to follow a genuine change of opinion.
    c_max: int = 4

    def __post_init__(self) -> None:
        if isinstance(self.c_max, bool) or not isinstance(self.c_max, int) or self.c_max < 1:
            raise ValueError(f"debounce c_max must be an integer >= 1, got {self.c_max!r}")


class LeaderDebouncer:
    """The debounced leading option of a stream of samples; `feed_leader` one at a time."""

    def __init__(self, c_max: int = DebounceParams().c_max) -> None:
        """Debounce with `c_max` consecutive samples (validated as DebounceParams)."""
        self.c_max = DebounceParams(c_max).c_max
        self.reset()

    def reset(self) -> None:
        """Forget everything: no leader yet, no samples."""
        self._leader: int | None = None
        self._first: int | None = None
        self._candidate: int | None = None  # the option the current run leads toward
        self._run = 0  # consecutive samples of the candidate
        self._n = 0
        self._onset = 0  # index of the first sample of that run

    @property
    def leader(self) -> int | None:
        """The debounced leading option, None before the first sample that had one."""
        return self._leader

    @property
    def first(self) -> int | None:
        """The leader set by the first sample that had one."""
        return self._first

    @property
    def samples(self) -> int:
        """How many samples were fed (those with no leading option included)."""
        return self._n

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


def sign_option(x: float) -> int | None:
    """The option a number's sign leads with two options: 0 (red) if > 0, 1 (blue) if < 0."""
    return 0 if x > 0 else 1 if x < 0 else None


def option_sign(option: int | None) -> int:
    """The sign of a two-option leader: +1 for option 0 (red), −1 for option 1, 0 for none."""
    return 0 if option is None else 1 - 2 * option


class SignDebouncer:
    """The debounced sign of a stream of numbers: `LeaderDebouncer` over two options."""

    def __init__(self, c_max: int = DebounceParams().c_max) -> None:
        """Debounce with `c_max` consecutive samples (validated as DebounceParams)."""
        self._leader = LeaderDebouncer(c_max)
        self.c_max = self._leader.c_max

    def reset(self) -> None:
        """Forget everything: no sign yet, no samples."""
        self._leader.reset()

    @property
    def sign(self) -> int:
        """The debounced sign: +1, −1, or 0 before the first non-zero sample."""
        return option_sign(self._leader.leader)

    @property
    def first_sign(self) -> int:
        """The sign set by the first non-zero sample (0 if none yet)."""
        return option_sign(self._leader.first)

    @property
    def samples(self) -> int:
        """How many samples were fed (zeros included)."""
        return self._leader.samples

    @property
    def onset(self) -> int:
        """Index of the first sample of the run that confirmed the latest change."""
        return self._leader.onset

    def feed(self, x: float) -> bool:
        """Take one sample; True when it confirms a change of sign (never for the first sign)."""
        return self._leader.feed_leader(sign_option(x))
