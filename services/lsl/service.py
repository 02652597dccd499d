"""`nod lsl`: the rig on Lab Streaming Layer — the model's signals and the protocol's markers.

An EEG or eye-tracker recording made with LabRecorder then lines up with the rig's: two outlets
(`services.lsl.outlets`), signals (ẑ_h, z_r, b_r, hand centre, per pose) and markers (each trial's
setup, countdown words, go, end and result; interruptions, aborts, the session's end; e-stops
and their release; each device's safe stop and its end), every sample stamped with its event's
rig time mapped onto LSL's clock (`services.lsl.clockmap`), not with its arrival.

A service of its own rather than a flag of the monitor or the recorder: it needs the optional
pylsl (and liblsl), it must run on a host LabRecorder can reach, and it is the one process that
owns LSL's clock mapping; like the display, it only listens, and the conductor never waits for
it.

One key space, schema 3, for any option set: the signals outlet opens with the rig's option set
(`--options N` or the params file's list; the paper's red and blue: one signed channel per
quantity; else one channel per option and quantity, `samples.signal_names`) and, when a trial
event or an opinion over another set arrives, opens again with that set's channels; markers
name options by name, and any set but the paper's in `options`.
"""

from __future__ import annotations

import argparse
import logging
import math
import socket
import sys
from collections.abc import Callable

from services.core import messages as m
from services.core.cli import fail, service_parser
from services.core.config import load_with_options, option_names
from services.core.node import Node, setup_logging
from services.core.session import Fabric
from services.lsl.clockmap import REFRESH_S, STEP_S, Anchor, read_anchor
from services.lsl.outlets import Outlets, load_pylsl
from services.lsl.samples import (
    SafeStops,
    SignalRows,
    estop_marker,
    marker,
    result_marker,
    signal_names,
    trial_marker,
)
from services.model.geometry import COLOURS

log = logging.getLogger("nod.lsl")


class LslService:
    """Forwards the rig's signals and events to the outlets, on LSL's clock."""

    def __init__(
        self, node: Node, outlets: Outlets, anchor: Anchor, options: tuple[str, ...] = COLOURS
    ) -> None:
        """Outlets opened for `options` (the params file's or `--options N`; red, blue)."""
        self.node = node
        self.outlets = outlets
        self.anchor = anchor
        self.rows = SignalRows(options)
        self.safe_stops = SafeStops()
        node.subscribe("vision/hand", self.on_pose)
        node.subscribe("decision/z_h", self._value_handler("z_h"))
        node.subscribe("decision/z_r", self._value_handler("z_r"))
        node.subscribe("decision/b_r", self._value_handler("b_r"))
        node.subscribe("experiment/trial", self.on_trial)
        node.subscribe("experiment/result", self.on_result)
        node.subscribe("safety/estop", self.on_estop)
        node.subscribe("safety/release", self.on_estop)
        node.subscribe("actuation/state", self.on_arm)
        node.subscribe("eyes/state", self.on_eyes)
        node.every(REFRESH_S, self.refresh)

    def _use_options(self, options: tuple[str, ...]) -> None:
        """Signals over another option set: open the outlet again with its channels."""
        options = tuple(options)
        if options == self.rows.options:
            return
        log.info("lsl: options %s: signals outlet re-opened with channels %s",
                 ",".join(options), ",".join(signal_names(options)))
        self.outlets.open_signals(options, self.anchor.offset_s())
        self.rows = SignalRows(options)

    def _value_handler(self, name: str) -> Callable[[m.Opinions], None]:
        def on_value(msg: m.Opinions) -> None:
            self._use_options(msg.options)
            row = self.rows.on_value(name, msg)
            if row is not None:
                self.outlets.push_row(row.values, self.anchor.to_lsl(row.t_ns))

        return on_value

    def on_pose(self, pose: m.HandPose) -> None:
        """A hand pose, for its row (to the rows of today's option set: `_use_options`)."""
        self.rows.on_pose(pose)

    def _mark(self, text: str, t_ns: int) -> None:
        self.outlets.push_marker(text, self.anchor.to_lsl(t_ns))
        log.debug("lsl: marker %s", text)

    def on_trial(self, ev: m.TrialEvent) -> None:
        """A protocol event (its option set is the session's: the signals follow it)."""
        self._use_options(ev.options)
        self._mark(trial_marker(ev), ev.t_ns)

    def on_result(self, res: m.TrialResult) -> None:
        """A trial's result."""
        self._mark(result_marker(res), res.t_ns)

    def on_estop(self, cmd: m.Estop) -> None:
        """An e-stop engaged or released."""
        self._mark(estop_marker(cmd), cmd.t_ns)

    def on_arm(self, state: m.ArmStateMsg) -> None:
        """The arm's state: a marker where its safe stop begins or ends."""
        text = self.safe_stops.on_state("actuation", state.safe_stop, state.safety_reason)
        if text is not None:
            self._mark(text, state.t_ns)

    def on_eyes(self, state: m.EyesStateMsg) -> None:
        """The eyes' state: a marker where their safe stop begins or ends."""
        text = self.safe_stops.on_state("eyes", state.safe_stop, state.safety_reason)
        if text is not None:
            self._mark(text, state.t_ns)

    def refresh(self, now_ns: int) -> None:
        """Re-read both clocks; a step of their offset goes on record as a marker."""
        new = read_anchor(self.node.clock.now_ns, self.outlets.local_clock, self.node.clock.speed)
        step = new.offset_s() - self.anchor.offset_s()
        self.anchor = new
        if abs(step) > STEP_S:
            log.warning("lsl: the rig clock stepped %+.3f ms against LSL's (NTP?): re-anchored",
                        step * 1e3)
            self._mark(marker({"event": "clock_step", "step_s": round(step, 9)}), now_ns)


def build_parser() -> argparse.ArgumentParser:
    """The command line of `nod lsl`."""
    p = service_parser(
        "nod lsl",
        "Publish the rig's signals (z_h, z_r, b_r, hand centre) and protocol markers "
        "as Lab Streaming Layer outlets, on LSL's clock (for LabRecorder). Needs the lsl extra; "
        "LSL's own settings come from lsl_api.cfg ($LSLAPICFG).",
        options=True,
    )
    return p


def main(argv: list[str] | None = None) -> int:
    """Run the outlets until SIGINT/SIGTERM."""
    args = build_parser().parse_args(sys.argv[1:] if argv is None else argv)
    setup_logging(args.verbose)
    try:
        pylsl = load_pylsl()  # before the session: a missing library fails at once
        fabric = Fabric.from_args(args)
        # The option set the signals outlet opens with (one channel per option and quantity);
        # a message over another set still re-opens it (`_use_options`).
        options = option_names(load_with_options(args.params, args.options)[1])
    except (ImportError, ValueError, OSError) as exc:
        return fail("nod lsl", exc)
    # The outlets open first: LabRecorder lists the streams while the rig is still coming up.
    clock = fabric.clock()
    anchor = read_anchor(clock.now_ns, pylsl.local_clock, clock.speed)
    try:
        outlets = Outlets(fabric.rig, socket.gethostname(), anchor.offset_s(), options)
    except RuntimeError as exc:  # liblsl could not open its sockets
        return fail("nod lsl", f"cannot open the LSL outlets: {exc}")
    try:
        node = Node("lsl", fabric, retry_s=math.inf)
    except (ValueError, OSError, ConnectionError) as exc:
        outlets.close()
        return fail("nod lsl", exc)
    log.info("lsl: outlets nod-%s-signals and nod-%s-markers (liblsl %s); LSL − rig clock "
             "%+.6f s (±%.1f µs)", fabric.rig, fabric.rig, pylsl.library_version(),
             anchor.offset_s(), anchor.uncertainty_s * 1e6)
    LslService(node, outlets, anchor, options)
    try:
        node.run()
    finally:
        outlets.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
