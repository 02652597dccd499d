"""Where the cue tones go: nowhere (`sim`), into a WAV file (`wav`) or out of a sound card.

A driver plays one tone and returns its onset on the rig clock — when the sound started, as
near to the loudspeaker as the driver can know it:

- `sim`: nothing is played; the onset is when the play call ran (tests, `nod run --sim`);
- `wav`: the tone is written into a mono 16-bit WAV file at its offset from the driver's start
  (silence between the cues), so a run leaves an audio artefact to listen to or measure; the
  onset is when the play call ran, and the file's header is valid after every cue;
- `sounddevice`: the sound card through PortAudio (`pip install 'nod-hri[audio]'`; PortAudio
  itself: `apt install libportaudio2` on Debian/Ubuntu). The onset is the output time of the
  tone's first sample (PortAudio's `outputBufferDacTime`) mapped to the rig clock.
"""

from __future__ import annotations

import logging
import threading
import wave
from pathlib import Path
from typing import Any

import numpy as np

from services.core.clock import Clock
from services.speaker.tones import SAMPLE_RATE, Samples

log = logging.getLogger("nod.speaker")
DRIVERS = ("sim", "wav", "sounddevice")
START_TIMEOUT_S = 1.0  # a sound card that has not started a tone within this is stuck


class SpeakerDriver:
    """Plays tones; `play` returns the onset (rig-clock ns). A context manager."""

    def connect(self, clock: Clock) -> None:
        """Open the output; the rig clock the onsets are measured on."""
        self.clock = clock

    def play(self, samples: Samples) -> int:
        """Start playing `samples` (mono, SAMPLE_RATE Hz); the onset on the rig clock."""
        return self.clock.now_ns()

    def close(self) -> None:
        """Release the output (idempotent)."""

    def __enter__(self) -> SpeakerDriver:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class SimSpeaker(SpeakerDriver):
    """No sound: "played" the moment it is asked."""


class WavSpeaker(SpeakerDriver):
    """Every tone written into one WAV file at its offset from the driver's start."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._wav: wave.Wave_write | None = None
        self._written = 0  # samples in the file so far
        self._start_ns = 0

    def connect(self, clock: Clock) -> None:
        """Create the file (its folder must exist); offset 0 is now."""
        super().connect(clock)
        wav = wave.open(str(self.path), "wb")  # noqa: SIM115  # closed in close()
        wav.setnchannels(1)
        wav.setsampwidth(2)
        wav.setframerate(SAMPLE_RATE)
        self._wav = wav
        self._start_ns = clock.now_ns()

    def play(self, samples: Samples) -> int:
        """Append silence up to the tone's offset, then the tone (never overlapping the last)."""
        onset = self.clock.now_ns()
        if self._wav is None:
            raise OSError(f"{self.path}: the WAV driver is not connected")
        at = round((onset - self._start_ns) * 1e-9 * SAMPLE_RATE)
        gap = max(0, at - self._written)
        pcm = np.concatenate([np.zeros(gap, np.float32), samples])
        self._wav.writeframes((np.clip(pcm, -1.0, 1.0) * 32767).astype("<i2").tobytes())
        self._written += len(pcm)
        fh: Any = getattr(self._wav, "_file", None)  # the header was patched: on disk now
        if fh is not None:
            fh.flush()
        return onset

    def close(self) -> None:
        """Close the file (its header says how many samples it holds)."""
        if self._wav is not None:
            self._wav.close()
            self._wav = None


class SoundDeviceSpeaker(SpeakerDriver):
    """The sound card, through the `sounddevice` library (PortAudio), one output stream."""

    def __init__(self, device: str | None = None) -> None:
        self.device = int(device) if device is not None and device.isdigit() else device
        self._lock = threading.Lock()
        self._tone: Samples | None = None
        self._pos = 0
        self._onset_s: float | None = None  # stream time of the current tone's first sample
        self._started = threading.Event()
        self._stream: Any = None

    def connect(self, clock: Clock) -> None:
        """Open and start the output stream; OSError in one line if it cannot be."""
        super().connect(clock)
        try:
            import sounddevice as sd  # lazily: an optional extra, and it loads PortAudio
        except (ImportError, OSError) as exc:
            raise OSError(
                f"the sounddevice driver needs the audio extra and PortAudio ({exc}): "
                "pip install 'nod-hri[audio]' and apt install libportaudio2"
            ) from None
        try:
            self._stream = sd.OutputStream(
                samplerate=SAMPLE_RATE, channels=1, dtype="float32", device=self.device,
                callback=self._fill, latency="low",
            )
            self._stream.start()
        except Exception as exc:  # PortAudioError and ValueError (no such device) alike
            where = self.device if self.device is not None else "default"
            raise OSError(f"cannot open the sound output {where}: {exc}") from None

    def _fill(self, outdata: Any, frames: int, time: Any, status: Any) -> None:
        """PortAudio's callback: the current tone's next samples, else silence."""
        out = outdata[:, 0]
        out[:] = 0.0
        with self._lock:
            tone = self._tone
            if tone is None:
                return
            if self._pos == 0:
                self._onset_s = float(time.outputBufferDacTime)
                self._started.set()
            chunk = tone[self._pos : self._pos + frames]
            out[: len(chunk)] = chunk
            self._pos += len(chunk)
            if self._pos >= len(tone):
                self._tone = None

    def play(self, samples: Samples) -> int:
        """Queue the tone; wait until the card takes its first sample; that sample's onset."""
        if self._stream is None:
            raise OSError("the sounddevice driver is not connected")
        with self._lock:
            self._tone, self._pos, self._onset_s = samples, 0, None
            self._started.clear()
            # The stream's clock and the rig's, read together: the offset between them.
            ref_s, ref_ns = float(self._stream.time), self.clock.now_ns()
        if not self._started.wait(START_TIMEOUT_S) or self._onset_s is None:
            raise OSError(f"the sound card did not start a tone within {START_TIMEOUT_S} s")
        return ref_ns + round((self._onset_s - ref_s) * 1e9 * self.clock.speed)

    def close(self) -> None:
        """Stop and close the stream."""
        if self._stream is not None:
            self._stream.stop()
            self._stream.close()
            self._stream = None


def make_speaker(driver: str, out: Path | None = None, device: str | None = None) -> SpeakerDriver:
    """The driver by name; ValueError saying what is missing."""
    if driver == "sim":
        return SimSpeaker()
    if driver == "wav":
        if out is None:
            raise ValueError("the wav driver needs --out FILE.wav")
        return WavSpeaker(out)
    if driver == "sounddevice":
        return SoundDeviceSpeaker(device)
    raise ValueError(f"unknown speaker driver {driver!r}; known: {', '.join(DRIVERS)}")
