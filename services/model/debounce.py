"""The one debounce of the project: the sign of a noisy stream, changed only by a run of samples.

Algorithm 2 turns the robot only after `c_max` consecutive samples of the new sign of z_r, and
SPEC §6 counts the human's switches of ẑ_h "debounced like Algorithm 2": both use this class
with the same `DebounceParams`.

- The first non-zero sample sets the sign (it is not a change).
- A change needs `c_max` consecutive samples of the other sign; a sample of the current sign
  interrupts the run and it starts over.
- A zero sample carries no sign: it neither counts toward a run nor breaks one.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class DebounceParams:
    """How many samples confirm a change of sign (SPEC §4: C_max = 4)."""

    # Consecutive samples of the opposite sign needed to confirm a change; ≥ 1. Larger = steadier
    # (robot and switch count), slower to follow a genuine change of opinion.
    c_max: int = 4

    def __post_init__(self) -> None:
        if isinstance(self.c_max, bool) or not isinstance(self.c_max, int) or self.c_max < 1:
            raise ValueError(f"debounce c_max must be an integer >= 1, got {self.c_max!r}")


class SignDebouncer:
    """The debounced sign of a stream of samples; `feed` one sample at a time."""

    def __init__(self, c_max: int = DebounceParams().c_max) -> None:
        """Debounce with `c_max` consecutive samples (validated as DebounceParams)."""
        self.c_max = DebounceParams(c_max).c_max
        self.reset()

    def reset(self) -> None:
        """Forget everything: no sign yet, no samples."""
        self._sign = 0
        self._first = 0
        self._n = 0
        self._run = 0  # consecutive samples against the current sign
        self._onset = 0  # index of the first sample of that run

    @property
    def sign(self) -> int:
        """The debounced sign: +1, −1, or 0 before the first non-zero sample."""
        return self._sign

    @property
    def first_sign(self) -> int:
        """The sign set by the first non-zero sample (0 if none yet)."""
        return self._first

    @property
    def samples(self) -> int:
        """How many samples were fed (zeros included)."""
        return self._n

    @property
    def onset(self) -> int:
        """Index of the first sample of the run that confirmed the latest change."""
        return self._onset

    def feed(self, x: float) -> bool:
        """Take one sample; True when it confirms a change of sign (never for the first sign)."""
        i = self._n
        self._n += 1
        s = (x > 0) - (x < 0)
        if s == 0:
            return False
        if self._sign == 0:
            self._sign = self._first = s
            return False
        if s == self._sign:
            self._run = 0
            return False
        if self._run == 0:
            self._onset = i
        self._run += 1
        if self._run < self.c_max:
            return False
        self._run = 0
        self._sign = s
        return True
