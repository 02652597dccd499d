"""`nod replay FILE.mcap`: play a recording back onto a rig, or re-run the decision model on it.

Three ways to play:

- Plain (default): each message's original payload bytes, on its key (rewritten to `--rig` if
  given; default the recording's rig), at the original inter-message timing (`log_time`, the
  recorder's wall clock) divided by `--speed`. For viewers (`nod monitor`, `nod topic`) and
  for services started on a clock that matches the recording's stamps.
- `--restamp`: each message re-encoded with `t_ns` moved onto the live rig clock (`--clock-speed`,
  `--epoch-ns`: the values the rig's services were given; a real rig's wall clock by default)
  and `seq` renumbered per key, sent when the rig clock reads that stamp. Live services judge
  freshness and clock skew by `t_ns`, so a replay into running services needs this.
- `--follow` (implies `--restamp`): the live conductor (`nod experiment`) drives the protocol,
  and the replay follows it. At each recorded trial "setup" and "go" the replay waits for the
  live conductor's same event (repeating the last hand pose meanwhile, restamped, so the rig
  stays fresh) or skips ahead to it, and moves its clock offset there: each trial's recorded
  hand path starts at the live "go" exactly as it started at the recorded one. With
  `--inputs`, a fresh decision/actuation/eyes/experiment then replays the recorded session.

What `--inputs` replays (derived from the contract, `input_topics()`): the keys that some
service under test (decision, actuation, eyes, experiment) subscribes to and none of them
publishes — `vision/hand` and `vision/layout` — less `rig/event` (the recorded launcher's
account of its processes: replayed, it would interrupt trials for crashes that are not
happening) and `safety/*` (operator acts: an e-stop replayed would hold the rig, and a release
is never replayed from a file — it could release an e-stop engaged live; `safety/release` is
left out of every replay unless named with `--only`), `experiment/operator` (the live operator
starts and holds the trials) and `speaker/played` (the recorded countdown's onsets: they would
be stored under the replayed trials). A replay of vision keys holds the
`vision` liveliness token, as the sim participant does, so the services that require vision
accept it.

`--through decision [--params P] --out FILE2` runs offline, no Zenoh: the recorded
vision/hand, vision/layout and experiment/trial messages go in order through `DecisionModel`
(reset on setup/go with `DecisionModel.on_trial`, like the decision service), and FILE2 is the
recording without its decision/* channels plus the recomputed decision/z_r, z_h and b_r (same
keys, encoded with the project's encoder, stamped with the pose's `t_ns`, logged at the pose's
log time). One line per trial compares the final z_r and b_r, recorded vs recomputed.
`--policy paper|adaptive|FILE.toml` makes it a robot policy's counterfactual
(`services.recording.counterfactual`): each trial's b* and u_r as the policy would have chosen
them from the trials played so far, and per trial what the robot would have decided beside what
happened (`--json`: machine readable); the policy's gaze level is reported, never applied.
"""

from __future__ import annotations

import argparse
import json
import logging
import threading
from pathlib import Path

from services.core.cli import (
    add_params_arg,
    fabric_parser,
    fail,
    int_in,
    one_line,
    positive_float,
)
from services.core.clock import Clock
from services.core.keys import Keys
from services.core.node import install_signal_handlers, setup_logging
from services.core.session import Fabric, open_session
from services.recording.counterfactual import GAZE_NOT_APPLIED, replay_policy
from services.recording.mcap_io import (
    McapIn,
)
from services.recording.player import LiveEvents, Player
from services.recording.selection import (
    PROG,
    input_topics,
    scan,
    select_topics,
)
from services.recording.through import through_decision

log = logging.getLogger("nod.replay")


def build_parser() -> argparse.ArgumentParser:
    """The command line of `nod replay`."""
    p = fabric_parser(
        PROG,
        "Play a recording (nod record) back onto a rig, or re-run the decision "
        "model on it offline (--through decision).",
    )
    p.add_argument("file", type=Path, metavar="FILE.mcap", help="the recording")
    p.set_defaults(rig=None)
    p.add_argument("--speed", type=positive_float, default=1.0, metavar="X",
                   help="play X times as fast as recorded (plain replays; default 1)")
    p.add_argument("--only", action="append", default=None, metavar="KEY",
                   help="replay only this key (e.g. vision/hand, 'vision/*'); repeatable")
    p.add_argument("--inputs", action="store_true",
                   help="replay only what a fresh decision/actuation/eyes/experiment need from "
                   "outside: " + ", ".join(input_topics()))
    p.add_argument("--loop", action="store_true", help="start over at the end, until Ctrl-C")
    p.add_argument("--restamp", action="store_true",
                   help="move every t_ns onto the live rig clock and renumber seq (for live "
                   "services)")
    p.add_argument("--follow", action="store_true",
                   help="follow the live conductor: meet it at each trial's setup and go "
                   "(implies --restamp)")
    p.add_argument("--follow-timeout", type=positive_float, default=60.0, metavar="S",
                   help="how long to wait for the live conductor at a trial event (60 s)")
    clock = p.add_argument_group("the live rig's clock (--restamp, --follow)")
    clock.add_argument("--clock-speed", type=positive_float, default=1.0, metavar="S",
                       help="the rig's simulated seconds per wall second (its services' --speed)")
    clock.add_argument("--epoch-ns", type=int_in(0, 2**63 - 1), default=None,
                       help="the rig's clock epoch (its services' --epoch-ns)")
    off = p.add_argument_group("offline (no Zenoh)")
    off.add_argument("--through", choices=("decision",), default=None,
                     help="re-run this model over the recording and write --out")
    off.add_argument("--out", type=Path, default=None, metavar="FILE2.mcap",
                     help="the recording written by --through")
    off.add_argument("--policy", default=None, metavar="paper|adaptive|FILE.toml",
                     help="with --through decision: each trial's b* and u_r as this robot "
                     "policy would have chosen them, and what the robot would have decided "
                     "(a counterfactual; the policy's gaze is reported, not applied)")
    off.add_argument("--policy-params", type=Path, default=None, metavar="FILE.toml",
                     help="the simulated people an adaptive policy's table is built from "
                     "(default: the fitted person, as nod cohort's)")
    off.add_argument("--json", action="store_true",
                     help="with --policy: the per-trial summary as JSON on stdout")
    add_params_arg(p)
    p.add_argument("-v", "--verbose", action="store_true", help="log at debug level")
    return p


def main(argv: list[str] | None = None) -> int:
    """Replay, or re-run the decision model; 2 on bad flags, an unreadable file or no router."""
    parser = build_parser()
    args = parser.parse_args(argv)
    setup_logging(args.verbose)
    problem = _check(args)
    if problem:
        return fail(PROG, problem)
    try:
        if args.through is not None:
            return _through(args)
        return _replay(args)
    except (ValueError, OSError) as exc:
        return fail(PROG, one_line(str(exc)))


def _check(args: argparse.Namespace) -> str | None:
    if args.through is not None:
        if args.out is None:
            return "--through needs --out FILE2.mcap"
        if args.out.resolve() == args.file.resolve():
            return "--out must be another file than the recording"
        if args.policy is None and (args.policy_params is not None or args.json):
            return "--policy-params and --json go with --policy"
        return None
    if (args.out is not None or args.params is not None or args.policy is not None
            or args.policy_params is not None or args.json):
        return "--out, --params, --policy, --policy-params and --json go with --through"
    if args.follow and args.loop:
        return "--follow plays one session: it does not --loop"
    if (args.restamp or args.follow) and args.speed != 1.0:
        return ("a restamped replay runs on the live rig's clock (--clock-speed); --speed is "
                "for plain replays")
    return None


def _through(args: argparse.Namespace) -> int:
    if args.policy is not None:
        return _policy(args)
    res = through_decision(args.file, args.out, args.params)
    for t in res.trials:
        print(t.line())
    print(
        f"{PROG}: wrote {args.out}: {res.messages} messages; decision/z_r, z_h, b_r recomputed "
        f"from {res.poses} hand poses ({res.recomputed} messages), {res.left_out} recorded "
        "decision messages left out",
        flush=True,
    )
    return 0


def _policy(args: argparse.Namespace) -> int:
    rep = replay_policy(args.file, args.out, args.params, args.policy, args.policy_params)
    if args.json:
        print(json.dumps(rep.as_json(), indent=2), flush=True)
        return 0
    res = rep.through
    for t in res.trials:
        print(t.line())
    print(f"policy {rep.policy.name} (sha256 {rep.policy.sha256[:12]}…), a counterfactual: "
          f"{GAZE_NOT_APPLIED}")
    for p in rep.trials:
        print(p.line())
    print(
        f"{PROG}: wrote {args.out}: {res.messages} messages; decision/z_r, z_h, b_r recomputed "
        f"under policy {rep.policy.name} from {res.poses} hand poses ({res.recomputed} "
        f"messages), {res.left_out} recorded decision messages left out",
        flush=True,
    )
    return 0


def _replay(args: argparse.Namespace) -> int:
    src = McapIn(args.file)
    found = scan(src)
    if found.truncated:
        log.warning("%s: %s; replaying what precedes it", args.file, found.truncated)
    topics = select_topics(found.topics, args.only, args.inputs)
    if not topics:
        raise ValueError(f"nothing to replay: the file holds {sorted(found.topics) or 'no keys'}")
    rig = args.rig or found.rig or "rig1"
    args.rig = rig
    restamp = args.restamp or args.follow
    if args.follow and not found.anchors:
        raise ValueError("--follow needs the recording's experiment/trial events; it has none")
    stop = threading.Event()
    install_signal_handlers(stop)
    session = open_session(Fabric.from_args(args).zenoh_config())
    keys = Keys(rig)
    tokens = []
    live = None
    try:
        if any(t.startswith("vision/") for t in topics):  # stand in for vision, like the sim
            tokens.append(session.liveliness().declare_token(keys.alive("vision")))
        if args.follow:
            live = LiveEvents(session, keys)
        player = Player(
            session, rig, topics, stop,
            speed=args.speed,
            clock=Clock(args.clock_speed, args.epoch_ns) if restamp else None,
            follow=live,
            follow_timeout_s=args.follow_timeout,
            hand_period_ns=found.hand_period_ns,
        )
        print(
            f"{PROG}: {args.file} ({found.messages} messages) onto rig {rig!r}: "
            f"{', '.join(sorted(topics))}"
            + (" (restamped)" if restamp and not args.follow else "")
            + (" (following the live conductor)" if args.follow else ""),
            flush=True,
        )
        while True:
            player.play(src, found.anchors)
            if not args.loop or stop.is_set():
                break
        player.close()
    finally:
        if live is not None:
            live.close()
        for token in tokens:
            token.undeclare()
        session.close()
    print(player.stats.line(), flush=True)
    return 130 if stop.is_set() else 0


if __name__ == "__main__":
    raise SystemExit(main())
