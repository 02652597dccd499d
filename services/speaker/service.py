"""`nod speaker`: the participant's audio countdown — a tone per word and a distinct go tone.

It listens to the conductor's `experiment/trial` events (one key space, schema 3: a session over
any number of options counts down alike) and plays a short 660 Hz beep for each
countdown word and a longer 990 Hz tone for go (`services.speaker.tones`), through a driver
(`services.speaker.drivers`: sim, wav, sounddevice), and publishes each cue's onset as played
on `speaker/played`; the conductor stores them with the trial (table `cues`, `cues.csv`).
Playing runs on a thread of its own, so a sound card never holds up zenoh's delivery; a cue that
arrives while the previous one still plays waits its turn. The conductor does not wait for the
speaker: a rig without one runs its trials uncued.
"""

from __future__ import annotations

import argparse
import logging
import math
import queue
import sys
import threading
from pathlib import Path

from services.core import messages as m
from services.core.cli import fail, service_parser
from services.core.node import Node, setup_logging
from services.core.session import Fabric
from services.speaker.drivers import DRIVERS, SpeakerDriver, make_speaker
from services.speaker.tones import render, tone_for

log = logging.getLogger("nod.speaker")
PHASES = ("countdown", "go")
QUEUE = 16  # cues waiting to be played; more means the output is stuck: the newest are dropped


class SpeakerService:
    """Turns countdown and go events into tones, and reports each onset."""

    def __init__(self, node: Node, driver: SpeakerDriver) -> None:
        self.node = node
        self.driver = driver
        self.sounds = {phase: render(tone_for(phase)) for phase in PHASES}
        self.pending: queue.Queue[m.TrialEvent] = queue.Queue(QUEUE)
        self.pub = node.publisher("speaker/played")
        node.subscribe("experiment/trial", self.on_trial)
        self._thread = threading.Thread(target=self._play_loop, name="speaker", daemon=True)
        self._thread.start()

    def on_trial(self, msg: m.TrialEvent) -> None:
        """A countdown word or go: queue its tone (the other phases are silent)."""
        if msg.phase not in PHASES:
            return
        try:
            self.pending.put_nowait(msg)
        except queue.Full:
            log.warning("trial %d: cue %r dropped: %d cues wait to be played (output stuck?)",
                        msg.trial, msg.text, QUEUE)

    def _play_loop(self) -> None:
        """Play each queued cue and publish its onset, until the node stops."""
        while not self.node.stop.is_set():
            try:
                ev = self.pending.get(timeout=0.1)
            except queue.Empty:
                continue
            cue = (ev.text or ev.phase)[:32]
            try:
                played = self.driver.play(self.sounds[ev.phase])
            except OSError as exc:
                log.error("trial %d: cue %r not played: %s", ev.trial, cue, exc)
                continue
            late_ms = (played - ev.t_ns) / 1e6
            log.info("trial %d: %s played (%+.1f ms after its event)", ev.trial, cue, late_ms)
            with self.node.lock:
                if self.node.session is None:  # closing
                    return
                self.pub.put(trial=ev.trial, cue=cue, planned_ns=ev.t_ns, played_ns=played)


def build_parser() -> argparse.ArgumentParser:
    """The command line of `nod speaker`."""
    p = service_parser(
        "nod speaker",
        "Play the participant's countdown (a beep per word, a go tone) and publish "
        "each cue's onset as played on speaker/played.",
    )
    p.add_argument("--driver", choices=DRIVERS, default="sim",
                   help="sim (silent), wav (into --out) or sounddevice (the sound card: the "
                   "audio extra and PortAudio)")
    p.add_argument("--out", type=Path, default=None, metavar="FILE.wav",
                   help="the wav driver's file: every cue at its offset from the start")
    p.add_argument("--device", default=None,
                   help="the sounddevice driver's output (index or name; default: the system's)")
    return p


def main(argv: list[str] | None = None) -> int:
    """Run the speaker until SIGINT/SIGTERM."""
    args = build_parser().parse_args(sys.argv[1:] if argv is None else argv)
    setup_logging(args.verbose)
    try:
        driver = make_speaker(args.driver, args.out, args.device)
        fabric = Fabric.from_args(args)
        driver.connect(fabric.clock())  # before the session: a missing library fails at once
    except (ValueError, OSError) as exc:
        return fail("nod speaker", exc)
    try:
        node = Node("speaker", fabric, retry_s=math.inf)
    except (ValueError, OSError, ConnectionError) as exc:
        driver.close()
        return fail("nod speaker", exc)
    log.info("speaker: driver %s%s", args.driver, f" into {args.out}" if args.out else "")
    with driver:
        SpeakerService(node, driver)
        node.run()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
