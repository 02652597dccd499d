"""The participant's audio cue on a real rig of processes: `nod speaker --driver wav` plays a tone
per countdown word and a go tone, reports each onset on speaker/played, and the conductor stores
them with the trials (table `cues`, `nod export`'s cues.csv)."""

from __future__ import annotations

import csv
import sqlite3
import time
import wave

import numpy as np
import pytest

from services.core import messages as m
from services.core.keys import Keys
from services.speaker.tones import GO, SAMPLE_RATE, WORD
from tests.processes import run_nod

from .conftest import SHORT, Collector, wait_for

pytestmark = pytest.mark.integration
KEYS = Keys("rig1")
SPEED = 2.0
LATE_MS = 200.0  # played − planned, wall time


def _bursts(path) -> list[tuple[float, float]]:
    """(onset s, length s) of every tone in a WAV file, found by its energy (1 ms frames)."""
    with wave.open(str(path)) as w:
        assert w.getframerate() == SAMPLE_RATE
        pcm = np.frombuffer(w.readframes(w.getnframes()), "<i2").astype(float) / 32767
    frame = SAMPLE_RATE // 1000
    n = len(pcm) // frame
    rms = np.sqrt(np.mean(pcm[: n * frame].reshape(n, frame) ** 2, axis=1))
    loud = np.concatenate([[False], rms > 0.05, [False]])
    edges = np.flatnonzero(np.diff(loud.astype(int)))
    return [(a / 1000, (b - a) / 1000) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def test_every_countdown_word_and_go_is_played_reported_stored_and_exported(
    router, endpoint, client, spawn, tmp_path
):
    params = tmp_path / "short.toml"
    params.write_text(SHORT)
    clock = ["--speed", str(SPEED), "--epoch-ns", str(time.time_ns()), "--params", str(params)]
    for service in ("decision", "actuation", "eyes", "sim"):
        spawn(service, *clock)
    wav = tmp_path / "cues.wav"
    speaker = spawn("speaker", *clock[:4], "--driver", "wav", "--out", str(wav))
    played = Collector(client, KEYS.topic("speaker/played"), m.CuePlayed)
    events = Collector(client, KEYS.topic("experiment/trial"), m.TrialEvent)
    wait_for(lambda: any(r.ok is not None for r in client.liveliness().get(
        KEYS.alive("speaker"), timeout=0.3)), 30, "the speaker up")
    db = tmp_path / "s.sqlite"
    conductor = spawn("experiment", *clock, "--db", str(db), "--clicks", "10",
                      "--participant", "P03", "--console", "lines")
    assert conductor.wait(180) == 0, conductor.log_path.read_text()[-2000:]

    cues = [(e.trial, e.text, e.t_ns) for e in events.messages if e.phase in ("countdown", "go")]
    # Each attempt counts 1, 2, 3 and says go. A loaded host may break an attempt (a stale
    # input) and the paper's rule repeats it, so a trial's countdown may start again.
    for trial in (1, 2, 3):
        words = [w for t, w, _ in cues if t == trial]
        assert words[-4:] == ["1", "2", "3", "go"], (trial, words)
    assert {t for t, _, _ in cues} == {1, 2, 3}, cues
    wait_for(lambda: len(played.messages) >= len(cues), 10, "every cue reported")
    got = [(p.trial, p.cue, p.planned_ns) for p in played.messages]
    assert got == cues, got
    speaker.terminate()
    assert speaker.wait(10) == 0, speaker.log_path.read_text()[-2000:]

    late_ms = [(p.played_ns - p.planned_ns) / 1e6 / SPEED for p in played.messages]
    assert all(0 <= x <= LATE_MS for x in late_ms), late_ms
    print(f"played − planned (wall ms): median {np.median(late_ms):.2f}, max {max(late_ms):.2f}")

    # The WAV file: one tone per cue, words short and go long, at the reported onsets.
    bursts = _bursts(wav)
    assert len(bursts) == len(cues), bursts
    for (_, length), (_, word, _) in zip(bursts, cues, strict=True):
        expected = GO.duration_s if word == "go" else WORD.duration_s
        assert abs(length - expected) < 0.015, (word, length)
    onsets = np.array([b[0] for b in bursts])
    reported = np.array([p.played_ns for p in played.messages]) * 1e-9
    assert np.allclose(onsets - onsets[0], reported - reported[0], atol=0.005), (
        onsets - onsets[0], reported - reported[0])

    # The store: every cue with its trial; the export: cues.csv.
    db_rows = sqlite3.connect(db).execute(
        "SELECT trial, attempt, cue, planned_ns, played_ns FROM cues ORDER BY planned_ns"
    ).fetchall()
    assert [(t, c, p) for t, _, c, p, _ in db_rows] == cues
    assert all(a >= 1 for _, a, _, _, _ in db_rows)
    assert all(0 <= (played - planned) / 1e6 / SPEED <= LATE_MS
               for *_, planned, played in db_rows)
    out = tmp_path / "csv"
    res = run_nod("export", "--db", str(db), "--out", str(out), timeout=60)
    assert res.returncode == 0, res.stderr
    with (out / "cues.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert [(int(r["trial"]), r["cue"], int(r["planned_ns"]), int(r["played_ns"]))
            for r in rows] == [(t, c, p, q) for t, _, c, p, q in db_rows]
    assert {r["participant"] for r in rows} == {"P03"}
