"""What `nod run --options N` shows of a session: a progress line and one row per trial.

`SessionView` for the `options/*` keys: O, the robot's and the human's boxes are shown by
their option names (`[protocol] options`), the outcome, switches, violations and score as
the paper's table.
"""

from __future__ import annotations

import logging
import sys
from typing import Any

import zenoh

from services.core import messages as m
from services.core import options_messages as om
from services.core.keys import Keys
from services.core.node import clip
from services.launch.view import SessionView
from services.model.params import NodConfig
from services.model.schedule import OptionsSchedule

log = logging.getLogger("nod.launch")


class OptionsSessionView(SessionView):
    """Progress and the per-trial table of an N_o-option session."""

    def __init__(
        self, names: tuple[str, ...], n_trials: int, stream=sys.stdout, compact: bool = False
    ) -> None:
        super().__init__(n_trials, stream, compact)
        self.names = names
        self.options_results: list[om.OptionsResult] = []

    def name(self, option: int | None) -> str:
        """An option's name, '-' for none."""
        return "-" if option is None else self.names[option]

    def on_options_trial(self, ev: om.OptionsTrialEvent) -> None:
        """A protocol step: update the progress line."""
        with self.lock:
            if ev.phase in ("session_end", "abort"):
                self.finished.set()
                return
            if self.tty:
                o = f" O={self.name(ev.option)}" if ev.option is not None else ""
                self.out.write(f"\r\033[Ktrial {ev.trial}/{self.n} [{ev.mode}{o}]: {ev.phase}")
                self.out.flush()

    def on_options_result(self, r: om.OptionsResult) -> None:
        """A finished trial: one row of the table."""
        with self.lock:
            self.options_results.append(r)
            self.total_trials += 1
            if self.tty:
                self.out.write("\r\033[K")
            if not self._header_done:
                self.out.write(
                    f"{'trial':>5} {'mode':<10} {'O':<7} {'robot':<7} {'human':<7} "
                    f"{'outcome':<8} {'switch':>6} {'viol':>4} {'score':>5}\n"
                )
                self._header_done = True
            self.out.write(
                f"{r.trial:>5} {r.mode:<10} {self.name(r.option):<7} {self.name(r.robot):<7} "
                f"{self.name(r.human):<7} {r.outcome or '-':<8} {r.switches:>6} "
                f"{r.violations:>4} {r.score:>5}{'  interrupted' if r.interrupted else ''}\n"
            )
            self.out.flush()

    def subscribe(self, session: zenoh.Session, keys: Keys) -> list[Any]:
        """Follow the conductor's `options/trial` and `options/result` (undeclare when done)."""

        def decoded(cls: type[m.Message], handler: Any) -> Any:
            def on_sample(sample: zenoh.Sample) -> None:
                try:
                    handler(m.decode(cls, sample.payload.to_bytes()))
                except m.MessageError as exc:
                    log.warning("bad message on %s: %s", sample.key_expr, clip(str(exc)))

            return on_sample

        return [
            session.declare_subscriber(
                keys.topic("options/trial"), decoded(om.OptionsTrialEvent, self.on_options_trial)
            ),
            session.declare_subscriber(
                keys.topic("options/result"), decoded(om.OptionsResult, self.on_options_result)
            ),
        ]


def session_view(
    cfg: NodConfig, schedule: OptionsSchedule | None, compact: bool = False
) -> SessionView:
    """The launcher's view of a session: the paper's, or of N options when there is a schedule."""
    if schedule is not None:
        return OptionsSessionView(schedule.names, len(schedule.trials))
    return SessionView(len(cfg.protocol.trials), compact=compact)
