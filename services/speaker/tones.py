"""The cue tones, generated with numpy (nothing is fetched or shipped): a sine with short fades.

A countdown word ("1", "2", "3") is a short high beep, "go" a longer, higher one, so the
participant tells them apart by ear. The fades (raised-cosine ramps) keep the onset and the end
free of clicks.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

SAMPLE_RATE = 48_000  # Hz: what every sound card plays natively

Samples = npt.NDArray[np.float32]  # mono, in [-1, 1]


@dataclass(frozen=True, slots=True)
class Tone:
    """One cue's sound."""

    freq_hz: float  # the sine's frequency
    duration_s: float  # its whole length, fades included
    fade_s: float = 0.005  # raised-cosine ramp at each end (no click)
    level: float = 0.5  # peak amplitude, of full scale 1.0

    def __post_init__(self) -> None:
        if not 20.0 <= self.freq_hz <= 20_000.0:
            raise ValueError(f"tone frequency {self.freq_hz} Hz is outside 20 Hz-20 kHz")
        if not 0.01 <= self.duration_s <= 2.0:
            raise ValueError(f"tone duration {self.duration_s} s is outside 0.01-2 s")
        if not 0.0 <= 2 * self.fade_s <= self.duration_s:
            raise ValueError("the two fades must fit in the tone")
        if not 0.0 < self.level <= 1.0:
            raise ValueError(f"tone level {self.level} is outside (0, 1]")


WORD = Tone(660.0, 0.080)  # "1", "2", "3"
GO = Tone(990.0, 0.200)  # "go"


def tone_for(phase: str) -> Tone:
    """The tone of a countdown word or of go."""
    return GO if phase == "go" else WORD


def render(tone: Tone, rate: int = SAMPLE_RATE) -> Samples:
    """The tone's samples at `rate` Hz: the sine times its fade-in/fade-out envelope."""
    n = round(tone.duration_s * rate)
    t = np.arange(n) / rate
    wave = tone.level * np.sin(2 * np.pi * tone.freq_hz * t)
    k = round(tone.fade_s * rate)
    if k > 0:
        ramp = 0.5 - 0.5 * np.cos(np.pi * np.arange(k) / k)  # 0 → 1, raised cosine
        wave[:k] *= ramp
        wave[n - k :] *= ramp[::-1]
    return wave.astype(np.float32)
