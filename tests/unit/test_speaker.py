"""The participant's cue: the tones, the drivers, the conductor's cue log, the store and CSV."""

from __future__ import annotations

import csv
import wave
from pathlib import Path

import msgspec
import numpy as np
import pytest

from services.core import messages as m
from services.core.clock import Clock
from services.experiment.cues import CueLog
from services.experiment.export import main as export
from services.speaker.drivers import SimSpeaker, SoundDeviceSpeaker, WavSpeaker, make_speaker
from services.speaker.tones import GO, SAMPLE_RATE, WORD, Tone, render, tone_for
from services.store import CueRecord, Interruption, Store, TrialRecord


def _peak_hz(samples: np.ndarray) -> float:
    spectrum = np.abs(np.fft.rfft(samples * np.hanning(len(samples)), n=1 << 16))
    return float(np.fft.rfftfreq(1 << 16, 1 / SAMPLE_RATE)[np.argmax(spectrum)])


def test_a_word_is_a_short_660_hz_beep_and_go_a_longer_990_hz_tone() -> None:
    word, go = render(tone_for("countdown")), render(tone_for("go"))
    assert len(word) == round(0.080 * SAMPLE_RATE) and len(go) == round(0.200 * SAMPLE_RATE)
    assert word.dtype == np.float32 and np.max(np.abs(go)) <= WORD.level + 1e-6
    assert abs(_peak_hz(word) - 660.0) < 5 and abs(_peak_hz(go) - 990.0) < 5
    assert tone_for("go") is GO and tone_for("countdown") is WORD


def test_the_fades_start_and_end_at_silence_and_reach_full_level() -> None:
    samples = render(Tone(1000.0, 0.1, fade_s=0.005, level=0.5))
    k = round(0.005 * SAMPLE_RATE)
    assert samples[0] == 0.0 and abs(samples[-1]) < 0.5 * 0.01
    # A ramp, not a step (no click): a quarter into the fade the envelope is at 15 %.
    assert np.max(np.abs(samples[: k // 4])) < 0.15 * 0.5
    assert np.max(np.abs(samples[k : len(samples) - k])) == pytest.approx(0.5, abs=1e-3)
    assert np.max(np.abs(samples[-(k // 4) :])) < 0.15 * 0.5


@pytest.mark.parametrize("bad", [{"freq_hz": 5.0}, {"duration_s": 5.0}, {"fade_s": 0.06},
                                 {"level": 1.5}])
def test_a_tone_out_of_range_is_refused(bad: dict) -> None:
    with pytest.raises(ValueError):
        Tone(**{"freq_hz": 660.0, "duration_s": 0.08, **bad})


def test_the_wav_driver_writes_each_tone_at_its_offset(tmp_path: Path) -> None:
    clock = Clock()
    out = tmp_path / "cues.wav"
    with WavSpeaker(out) as speaker:
        speaker.connect(clock)
        start = speaker._start_ns
        first = speaker.play(render(WORD))
        second = speaker.play(render(GO))  # at once: right after the first, never over it
        with wave.open(str(out)) as w:  # valid while still open
            assert w.getnframes() >= len(render(WORD)) + len(render(GO))
    assert start <= first <= second <= clock.now_ns()
    with wave.open(str(out)) as w:
        assert (w.getnchannels(), w.getsampwidth(), w.getframerate()) == (1, 2, SAMPLE_RATE)
        pcm = np.frombuffer(w.readframes(w.getnframes()), "<i2").astype(float) / 32767
    at = round((first - start) * 1e-9 * SAMPLE_RATE)
    assert np.all(pcm[:at] == 0.0)
    assert np.max(np.abs(pcm[at : at + len(render(WORD))])) == pytest.approx(0.5, abs=1e-3)


def test_the_sim_driver_plays_at_once_and_the_names_are_checked() -> None:
    clock = Clock()
    speaker = make_speaker("sim")
    assert isinstance(speaker, SimSpeaker)
    speaker.connect(clock)
    before = clock.now_ns()
    assert before <= speaker.play(render(WORD)) <= clock.now_ns()
    with pytest.raises(ValueError, match="--out"):
        make_speaker("wav")
    with pytest.raises(ValueError, match="known: sim, wav, sounddevice"):
        make_speaker("alsa")


def test_the_sounddevice_driver_says_in_one_line_what_is_missing() -> None:
    try:
        import sounddevice  # noqa: F401
    except (ImportError, OSError):
        pass
    else:
        pytest.skip("sounddevice is installed here")
    with pytest.raises(OSError, match=r"nod-hri\[audio\].*libportaudio2") as err:
        SoundDeviceSpeaker().connect(Clock())
    assert "\n" not in str(err.value)


def _played(trial: int, cue: str, planned: int, played: int) -> m.CuePlayed:
    return m.CuePlayed(seq=0, t_ns=played, trial=trial, cue=cue, planned_ns=planned,
                       played_ns=played)


def test_the_cue_log_files_each_onset_under_its_trial_and_attempt() -> None:
    log = CueLog()
    log.begin(2, 1)
    log.on_played(_played(2, "1", 100, 105))
    log.on_played(_played(1, "go", 50, 60))  # late, from the trial before
    assert log.take() == [CueRecord(2, 1, "1", 100, 105), CueRecord(1, 0, "go", 50, 60)]
    assert log.take() == []


def _trial() -> TrialRecord:
    return TrialRecord(
        trial=1, mode="dissensus", option=None, gaze_level="neutral", yaw=0.0, pitch=0.0,
        t_go_ns=10, t_end_ns=20, human="red", robot="blue", outcome="D", switches=0,
        violations=0, clicks=None, score=-1, end_reason="human pressed",
    )


def test_cues_are_stored_with_their_trial_and_exported_as_cues_csv(tmp_path: Path) -> None:
    db = tmp_path / "s.sqlite"
    store = Store(db)
    store.begin_session("a", "P07", "rig1", 1, 0, {})
    store.write_interruption("a", Interruption(1, 1, 0, 5, "e-stop"),
                             cues=[CueRecord(1, 1, "1", 1, 2)])
    cues = [CueRecord(1, 2, w, 10 * i, 10 * i + 3) for i, w in enumerate(("1", "2", "3", "go"))]
    store.write_trial("a", _trial(), [], cues=cues)
    store.close()
    assert export(["--db", str(db), "--out", str(tmp_path / "csv")]) == 0
    with (tmp_path / "csv" / "cues.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == ["session", "participant", "trial", "attempt", "cue", "planned_ns",
                             "played_ns"]
    assert [(r["attempt"], r["cue"], r["played_ns"]) for r in rows] == [
        ("1", "1", "2"), ("2", "1", "3"), ("2", "2", "13"), ("2", "3", "23"), ("2", "go", "33")
    ]
    assert {r["participant"] for r in rows} == {"P07"}


@pytest.mark.parametrize("bad", [{"planned_ns": -1}, {"played_ns": 2**63}, {"cue": ""},
                                 {"trial": 10_001}, {"cue": "x" * 33}])
def test_a_cue_message_is_ranged(bad: dict) -> None:
    fields = {"v": m.SCHEMA_VERSION, "seq": 0, "t_ns": 0, "trial": 1, "cue": "go", "planned_ns": 0,
              "played_ns": 1}
    assert m.decode(m.CuePlayed, msgspec.msgpack.encode(fields)).cue == "go"
    with pytest.raises(m.MessageError):
        m.decode(m.CuePlayed, msgspec.msgpack.encode({**fields, **bad}))


class _FakeStream:
    """A PortAudio output stream: 10 ms buffers whose first sample leaves 20 ms later."""

    def __init__(self, *, callback, samplerate: int, **_: object) -> None:
        import threading
        import time as _time

        self.callback, self.rate, self._t0 = callback, samplerate, _time.monotonic()
        self._clock = _time.monotonic
        self.out: list[np.ndarray] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    @property
    def time(self) -> float:
        return self._clock() - self._t0

    def _run(self) -> None:
        from types import SimpleNamespace

        frames = self.rate // 100
        while not self._stop.wait(0.01):
            buf = np.zeros((frames, 1), np.float32)
            self.callback(buf, frames, SimpleNamespace(outputBufferDacTime=self.time + 0.02), None)
            self.out.append(buf[:, 0].copy())

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()

    def close(self) -> None:
        pass


def test_the_sounddevice_driver_reports_the_first_samples_output_time(monkeypatch) -> None:
    import sys
    from types import SimpleNamespace

    streams: list[_FakeStream] = []

    def output_stream(**kw):
        streams.append(_FakeStream(**kw))
        return streams[-1]

    monkeypatch.setitem(sys.modules, "sounddevice", SimpleNamespace(OutputStream=output_stream))
    clock = Clock(speed=2.0)
    with SoundDeviceSpeaker() as speaker:
        speaker.connect(clock)
        before = clock.now_ns()
        onset = speaker.play(render(GO))
        after = clock.now_ns()
    # The tone leaves 20 ms (wall) after the buffer that takes it, which comes within ~10 ms:
    # on a clock at 2x, 40-60 ms of rig time after the call (less the lock hand-over).
    assert before + 39e6 <= onset <= after + 45e6, (onset - before) / 1e6
    # The tone went out from the start of one buffer, silence before it (the stream was closed
    # at its onset: only its first buffers went out).
    played, tone = np.concatenate(streams[0].out), render(GO)
    start = (int(np.flatnonzero(played)[0]) - 1) // 480 * 480
    n = min(len(tone), len(played) - start)
    assert n >= 480 and np.array_equal(played[start : start + n], tone[:n])
    assert not np.any(played[:start])
