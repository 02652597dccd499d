"""One stored session as BIDS sees it, and its events on one clock (`nod export --bids`).

Pure: a `StoredSession` is what the store keeps of a session (read by `services.experiment.bids`),
and `session_events` lists what happened in it, each at a time the store holds or derives from
what it holds. Every onset is rig-clock ns; `bids` writes them as seconds from the session's
start. Each event says where its time comes from (`Event.source`):

- "played": a countdown word or "go" as `nod speaker` played it (the store's `cues`);
- "stored": a time the store keeps as it is (a trial's go and end, an interruption, a safety
  or rig event);
- "schedule": the protocol's schedule around a stored time — the trial's own gaze cue (set
  `gaze_lead_s` before the first countdown word, `services.model.schedule.trial_timeline`), and
  the countdown words of a session that stored no played cues (the offline loop has no speaker),
  `countdown_interval_s` apart, ending on its go;
- "samples": the first stored sample of the trial that shows a press: a hand landmark inside
  the box the person pressed (the judge's rule, `services.model.judge`), or the arm's end
  effector inside the box the robot pressed. Only as fine as the samples (≤ 60 Hz), in the
  session's configured table layout, and absent where the samples cannot show it (an offline
  session keeps no landmarks).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from services.model.geometry import Box, OptionsLayout
from services.model.schedule import ProtocolParams
from services.store.estimates import TrialEstimate
from services.store.policies import SessionPolicy
from services.store.records import (
    CueRecord,
    Interruption,
    RigEventRecord,
    SafetyEvent,
    Sample,
    TrialRecord,
    unpack_landmarks,
)

# trial_type of each event, with its meaning (events.json's Levels)
EVENT_TYPES: dict[str, str] = {
    "gaze": "the robot's eyes are set to the trial's gaze cue (value: its level)",
    "countdown": "a countdown word is said (value: the word)",
    "go": "the last countdown word, the start signal: both may move (value: the word)",
    "human_press": "the person presses a buzzer (value: its option)",
    "robot_press": "the robot's arm reaches the buzzer it presses (value: its option)",
    "trial_end": "the trial ends (value: why)",
    "interruption": "a start of the trial broken by a safe stop or an e-stop, from its setup to "
    "the break (value: why); never scored",
    "safe_stop": "a device (value: which, and why) stops safely",
    "safe_clear": "a device's safe stop is cleared (value: which)",
    "estop": "the emergency stop is pressed (value: by what, and why)",
    "estop_release": "the emergency stop is released (value: by what)",
    "rig_event": "the rig's launcher reports a service (value: kind, service, host, text)",
}
SOURCES: dict[str, str] = {
    "played": "when the speaker played it (the store's cues)",
    "stored": "a time the store keeps as it is",
    "schedule": "the protocol's schedule (gaze_lead_s, countdown_interval_s) around a stored time",
    "samples": "the first stored sample of the trial that shows it (as fine as the samples)",
}
SAFETY_TYPES = {"safe_stop": "safe_stop", "clear": "safe_clear", "estop": "estop",
                "release": "estop_release"}


@dataclass(frozen=True, slots=True)
class StoredSession:
    """What the store keeps of one session (times in rig-clock ns)."""

    session: str
    participant: str
    rig: str
    seed: int | None
    started_ns: int
    finished_ns: int | None
    status: str
    config: Mapping[str, Any]  # the session's configuration as stored (JSON)
    options: tuple[str, ...]  # its option set, box j is options[j]
    order: tuple[str, ...] | None  # the O order it was started with, if stored
    trials: tuple[TrialRecord, ...]
    samples: tuple[tuple[int, Sample], ...]  # (trial, sample), in time order
    cues: tuple[CueRecord, ...]
    safety: tuple[SafetyEvent, ...]
    interruptions: tuple[Interruption, ...]
    rig_events: tuple[RigEventRecord, ...]
    policy: SessionPolicy | None = None  # the robot policy it ran (None: the paper's robot)
    estimates: tuple[TrialEstimate, ...] = ()  # the person estimated after each trial

    @property
    def simulated(self) -> bool:
        """Whether the person was simulated: the offline loop, or a sim participant's seed."""
        return self.rig == "offline" or self.seed is not None

    @property
    def protocol(self) -> ProtocolParams:
        """The countdown timing the session ran (SPEC defaults for what it did not store)."""
        stored = self.config.get("protocol") if isinstance(self.config, Mapping) else None
        stored = stored if isinstance(stored, Mapping) else {}
        base = ProtocolParams()
        words = stored.get("countdown", base.countdown)
        return ProtocolParams(
            countdown=tuple(str(w) for w in words) or base.countdown,
            countdown_interval_s=float(
                stored.get("countdown_interval_s", base.countdown_interval_s)),
            gaze_lead_s=float(stored.get("gaze_lead_s", base.gaze_lead_s)),
        )

    def boxes(self) -> dict[str, Box]:
        """Each option's box on the table the session was configured with ({} if unknown)."""
        layout = self.config.get("layout") if isinstance(self.config, Mapping) else None
        if isinstance(layout, Mapping) and all(
            isinstance(layout.get(n), Mapping) for n in self.options
        ):
            return {n: Box(*(float(layout[n][k]) for k in ("x1", "y1", "x2", "y2")))
                    for n in self.options}
        if len(self.options) > 2:  # the N-option table: a row on the far edge
            return dict(zip(self.options, OptionsLayout.row(len(self.options)).boxes,
                            strict=True))
        return {}


@dataclass(frozen=True, slots=True)
class Event:
    """One row of events.tsv: rig-clock ns, the session's start subtracted when written."""

    t_ns: int
    duration_ns: int
    trial_type: str  # a key of EVENT_TYPES
    trial: int | None
    attempt: int | None
    value: str
    source: str  # a key of SOURCES
    planned_ns: int | None = None  # when the protocol asked for it (cues)


def session_events(s: StoredSession) -> list[Event]:
    """Every event of a session, in time order (ties in the order they happen)."""
    events = [*_cue_events(s), *_trial_events(s), *_press_events(s)]
    events += [
        Event(i.t_start_ns, i.t_ns - i.t_start_ns, "interruption", i.trial, i.attempt,
              _one_line(i.reason), "stored")
        for i in s.interruptions
    ]
    events += [
        Event(e.t_ns, 0, SAFETY_TYPES[e.event], e.trial or None, e.attempt, _one_line(
            f"{e.device}: {e.reason}" if e.reason else e.device), "stored")
        for e in s.safety
    ]
    events += [
        Event(e.t_ns, 0, "rig_event", e.trial or None, e.attempt, _one_line(
            f"{e.kind} {e.service}@{e.host}" + (f" (code {e.code})" if e.code is not None else "")
            + (f": {e.text}" if e.text else "")), "stored")
        for e in s.rig_events
    ]
    order = list(EVENT_TYPES)
    return sorted(events, key=lambda e: (e.t_ns, order.index(e.trial_type)))


def _cue_events(s: StoredSession) -> list[Event]:
    """The gaze cue and countdown of every start of a trial: as played, or as scheduled."""
    proto = s.protocol
    gaze_of = {t.trial: t.gaze_level for t in s.trials}
    go_word = proto.countdown[-1]
    lead_ns = round(proto.gaze_lead_s * 1e9)
    step_ns = round(proto.countdown_interval_s * 1e9)
    out: list[Event] = []
    starts: dict[tuple[int, int], list[CueRecord]] = {}
    for c in s.cues:
        starts.setdefault((c.trial, c.attempt), []).append(c)
    for (trial, attempt), cues in starts.items():
        for c in cues:
            kind = "go" if c.cue == go_word else "countdown"
            out.append(Event(c.played_ns, 0, kind, trial, attempt, c.cue, "played", c.planned_ns))
        first = min(c.planned_ns for c in cues)
        out.append(Event(first - lead_ns, 0, "gaze", trial, attempt,
                         gaze_of.get(trial, "n/a"), "schedule"))
    played_go = {(c.trial, c.attempt) for c in s.cues if c.cue == go_word}
    for t in s.trials:  # a go the speaker did not report: the stored one, its words scheduled
        if t.t_go_ns is None or (t.trial, t.attempts) in played_go:
            continue
        n = len(proto.countdown)
        if (t.trial, t.attempts) not in starts:
            first = t.t_go_ns - (n - 1) * step_ns
            out.append(Event(first - lead_ns, 0, "gaze", t.trial, t.attempts, t.gaze_level,
                             "schedule"))
            out += [Event(first + i * step_ns, 0, "countdown", t.trial, t.attempts, w,
                          "schedule", first + i * step_ns)
                    for i, w in enumerate(proto.countdown[:-1])]
        out.append(Event(t.t_go_ns, 0, "go", t.trial, t.attempts, go_word, "stored", t.t_go_ns))
    return out


def _trial_events(s: StoredSession) -> list[Event]:
    return [
        Event(t.t_end_ns, 0, "trial_end", t.trial, t.attempts, _one_line(t.end_reason), "stored")
        for t in s.trials if t.t_end_ns is not None
    ]


def _press_events(s: StoredSession) -> list[Event]:
    """Each trial's presses, at the first sample that shows them (none if no sample does)."""
    boxes = s.boxes()
    by_trial: dict[int, list[Sample]] = {}
    for trial, sample in s.samples:
        by_trial.setdefault(trial, []).append(sample)
    out: list[Event] = []
    for t in s.trials:
        samples = by_trial.get(t.trial, [])
        for kind, option, shows in (
            ("human_press", t.human, _hand_in),
            ("robot_press", t.robot, _arm_in),
        ):
            box = boxes.get(option) if option is not None else None
            if box is None:
                continue
            when = first_showing(samples, box, shows)
            if when is not None:
                out.append(Event(when, 0, kind, t.trial, t.attempts, str(option), "samples"))
    return out


def first_showing(
    samples: Sequence[Sample], box: Box, shows: Callable[[Sample, Box], bool]
) -> int | None:
    """The time of the first sample that `shows` in `box`, or None."""
    return next((m.t_ns for m in samples if shows(m, box)), None)


def _hand_in(m: Sample, box: Box) -> bool:
    """A landmark of the hand inside the box: the judge's press."""
    return any(box.contains(p) for p in unpack_landmarks(m.landmarks))


def _arm_in(m: Sample, box: Box) -> bool:
    """The arm's end effector inside the box."""
    return m.ee_x is not None and m.ee_y is not None and box.contains((m.ee_x, m.ee_y))


def _one_line(text: str) -> str:
    """Free text as one TSV field: whitespace runs (tabs, newlines) become one space."""
    return " ".join(str(text).split()) or "n/a"
