"""What a launcher's console shows of a session: a progress line and one row per trial.

`nod run` and `nod up` subscribe to the conductor's trial events and results and feed them here:
the operator sees every trial's outcome in the launcher's terminal, whoever runs the conductor.
One view for any option set (one key space, schema 3): the conductor's messages name O, the
robot's and the human's box, and they are shown by name, in columns as wide as the longest name
of the session's options, so the paper's table is what it always was.
"""

from __future__ import annotations

import logging
import sys
import threading
from collections import Counter
from typing import Any

import zenoh

from services.core import messages as m
from services.core.contract import EXPERIMENT_POLICY, EXPERIMENT_RESULT, EXPERIMENT_TRIAL
from services.core.keys import Keys
from services.core.node import clip
from services.model.geometry import COLOURS
from services.model.params import NodConfig
from services.model.schedule import OptionsSchedule

log = logging.getLogger("nod.launch")


class SessionView:
    """Prints progress and the per-trial table from the conductor's events, options by name."""

    def __init__(
        self,
        n_trials: int,
        stream=sys.stdout,
        compact: bool = False,
        names: tuple[str, ...] = COLOURS,
    ) -> None:
        self.n = n_trials
        self.compact = compact
        self.names = names
        longest = max(len(name) for name in names)
        self.widths = (max(5, longest + 1), max(6, longest + 2))  # O; robot and human
        self.participant = ""
        self.total_trials = 0
        self.out = stream
        self.tty = stream.isatty()
        self.lock = threading.Lock()
        self.results: list[m.TrialResult] = []
        self.policy: dict[int, m.PolicyMsg] = {}  # a robot policy's settings, by trial
        self.finished = threading.Event()
        self._header_done = False

    @staticmethod
    def name(option: str | None) -> str:
        """An option's name, '-' for none."""
        return option or "-"

    def on_trial(self, ev: m.TrialEvent) -> None:
        """A protocol step: update the progress line."""
        with self.lock:
            if ev.phase in ("session_end", "abort"):
                self.finished.set()
                return
            label = {"setup": f"gaze {ev.text}", "countdown": ev.text, "go": "go!"}.get(
                ev.phase, ev.phase
            )
            option = f" O={self.name(ev.option)}" if ev.option is not None else ""
            who = f"{self.participant} " if self.compact else ""
            line = f"{who}trial {ev.trial}/{self.n} [{ev.mode}{option}]: {label}"
            if self.tty:
                self.out.write("\r\033[K" + line)
                self.out.flush()

    def begin(self, participant: str) -> None:
        """A new participant's session starts."""
        with self.lock:
            self.participant = participant
            self.results = []
            self.policy = {}

    def on_policy(self, msg: m.PolicyMsg) -> None:
        """A robot policy's settings for a trial: shown on its row."""
        with self.lock:
            self.policy[msg.trial] = msg

    def note(self, text: str) -> None:
        """A line for the operator between the rows (e.g. a trial waiting for their start)."""
        with self.lock:
            if self.tty:
                self.out.write("\r\033[K")
            self.out.write(f"{text}\n")
            self.out.flush()

    def on_result(self, r: m.TrialResult) -> None:
        """A finished trial: a table row (one participant) or a participant's line (a study)."""
        with self.lock:
            self.results.append(r)
            self.total_trials += 1
            if self.tty:
                self.out.write("\r\033[K")
            if self.compact:
                if len(self.results) == self.n:
                    outcomes = " ".join(f"{x.outcome or '-':<2}" for x in self.results)
                    score = sum(x.score for x in self.results)
                    self.out.write(f"{self.participant}: {outcomes}  score {score:>3}\n")
                self.out.flush()
                return
            o, who = self.widths
            if not self._header_done:
                self.out.write(
                    f"{'trial':>5} {'mode':<10} {'O':<{o}} {'robot':<{who}} {'human':<{who}} "
                    f"{'outcome':<8} {'switch':>6} {'viol':>4} {'score':>5}\n"
                )
                self._header_done = True
            self.out.write(
                f"{r.trial:>5} {r.mode:<10} {self.name(r.option):<{o}} "
                f"{self.name(r.robot):<{who}} {self.name(r.human):<{who}} {r.outcome or '-':<8} "
                f"{r.switches:>6} {r.violations:>4} "
                f"{r.score:>5}{'  interrupted' if r.interrupted else ''}{self._settings(r)}\n"
            )
            self.out.flush()

    def _settings(self, r: m.TrialResult) -> str:
        """A trial's robot-policy settings at the end of its row ('' without a policy)."""
        p = self.policy.get(r.trial)
        if p is None:
            return ""
        frozen = ", frozen" if p.frozen else ""
        return f"  [{p.policy}: b*={p.b_star:g} u_r={p.u_r:g} gaze {p.gaze_level}{frozen}]"

    def subscribe(self, session: zenoh.Session, keys: Keys) -> list[Any]:
        """Follow the rig's conductor: its trial events and results (undeclare them when done)."""
        bad: Counter[str] = Counter()

        def decoded(cls: type[m.Message], handler: Any) -> Any:
            def on_sample(sample: zenoh.Sample) -> None:
                try:
                    handler(m.decode(cls, sample.payload.to_bytes()))
                except m.MessageError as exc:
                    key = str(sample.key_expr)
                    bad[key] += 1
                    if bad[key] <= 10 or bad[key] % 1000 == 0:  # never a flood from a bad peer
                        log.warning("bad message #%d on %s: %s", bad[key], key, clip(str(exc)))

            return on_sample

        return [
            session.declare_subscriber(keys.topic(EXPERIMENT_TRIAL.name),
                                       decoded(EXPERIMENT_TRIAL.message, self.on_trial)),
            session.declare_subscriber(keys.topic(EXPERIMENT_RESULT.name),
                                       decoded(EXPERIMENT_RESULT.message, self.on_result)),
            session.declare_subscriber(keys.topic(EXPERIMENT_POLICY.name),
                                       decoded(EXPERIMENT_POLICY.message, self.on_policy)),
        ]


def session_view(
    cfg: NodConfig, schedule: OptionsSchedule | None, compact: bool = False
) -> SessionView:
    """The launcher's view of a session: of the schedule's options, or of the paper's."""
    if schedule is not None:
        return SessionView(len(schedule.trials), compact=compact, names=schedule.names)
    return SessionView(len(cfg.protocol.trials), compact=compact)
