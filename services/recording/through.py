"""`nod replay --through decision`: the decision model re-run over a recording, offline.

The recorded vision/hand, vision/layout and experiment/trial messages go in order through
`DecisionModel` (reset on setup/go with `DecisionModel.on_trial`, like the decision service);
the output file is the recording without its decision/* channels plus the recomputed ones.
A recording of a table of N options (messages over three or more options, or the retired
`options/*` keys) is refused in one line: the comparison here is of the paper's signed z_r and
b_r, not yet of vectors. A recording of schema 1 (before one schema for any N) is read through
`services.core.schema1`, and its copy is written in today's schema and form (JSON channels).

`tune` gives a trial its own decision parameters (a robot policy's b* and u_r,
`services.recording.counterfactual`): the engine is retuned before that trial's "setup"; a
trial it does not name, or names with the recording's own parameters, runs on those, exactly
as without `tune`.
"""

from __future__ import annotations

import logging
import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

from services.core import messages as m
from services.core.config import from_mapping, load_toml, split_options
from services.core.keys import topic_of
from services.model.decision import DecisionModel, DecisionParams
from services.model.geometry import COLOURS, Colour
from services.model.params import NodConfig
from services.recording.mcap_io import (
    END_METADATA,
    FILE_METADATA,
    SESSION_METADATA,
    McapIn,
    McapOut,
)
from services.recording.selection import decode_entry

log = logging.getLogger("nod.replay")
DECISION_TOPICS = ("decision/z_r", "decision/z_h", "decision/b_r")


@dataclass
class TrialComparison:
    """One trial's decision outputs, recorded vs recomputed, at the last pose both answered."""

    trial: int
    mode: str = ""
    option: str | None = None
    recorded: dict[int, tuple[float, float]] = field(default_factory=dict)  # src_seq → (z_r, b_r)
    recomputed: dict[int, tuple[float, float]] = field(default_factory=dict)
    robot: str | None = None
    human: str | None = None
    outcome: str | None = None
    closed: bool = False
    going: bool = False  # after its "go": a pose in a box is the human's press
    press_seq: int | None = None  # the hand pose of the human's press (the first in a box)
    gaze: str | None = None  # the gaze level the recorded eyes showed (eyes/gaze), if recorded

    def at_press(self) -> tuple[tuple[float, float] | None, tuple[float, float] | None]:
        """(recorded, recomputed) (z_r, b_r) at the pose of the human's press (None: none)."""
        if self.press_seq is None:
            return None, None
        return self.recorded.get(self.press_seq), self.recomputed.get(self.press_seq)

    def final(self) -> tuple[tuple[float, float] | None, tuple[float, float] | None]:
        """(recorded, recomputed) (z_r, b_r) at the last pose of the trial both have."""
        common = set(self.recorded) & set(self.recomputed)
        if common:
            seq = max(common)
            return self.recorded[seq], self.recomputed[seq]
        rec = self.recorded[max(self.recorded)] if self.recorded else None
        new = self.recomputed[max(self.recomputed)] if self.recomputed else None
        return rec, new

    def line(self) -> str:
        """`trial 5 consensus O=red: z_r +0.41 → -0.22 (red → blue), b_r ...; recorded: ...`."""
        rec, new = self.final()

        def fmt(v: tuple[float, float] | None, i: int) -> str:
            return "—" if v is None else f"{v[i]:+.3f}"

        def side(v: tuple[float, float] | None) -> str:
            return "?" if v is None else ("red" if v[0] > 0 else "blue" if v[0] < 0 else "0")

        option = f" O={self.option}" if self.option else ""
        return (
            f"trial {self.trial} {self.mode}{option}: z_r {fmt(rec, 0)} → {fmt(new, 0)} "
            f"({side(rec)} → {side(new)}), b_r {fmt(rec, 1)} → {fmt(new, 1)}; recorded: robot "
            f"{self.robot or '—'}, human {self.human or '—'}, outcome {self.outcome or '—'}"
        )


def _merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for k, v in over.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def decision_config(meta: dict[str, str], params: Path | None) -> NodConfig:
    """The recording's parameters (its `params_toml`, if it has one), overridden by `params`."""
    base: dict[str, Any] = {}
    if meta.get("params_toml"):
        base = tomllib.loads(meta["params_toml"])
    over = load_toml(params) if params is not None else {}
    rest, schedule = split_options(_merge(base, over))
    if schedule is not None:
        raise ValueError(two_options_only(f"its parameters list {schedule.n_options} options"))
    return from_mapping(NodConfig, rest)


def two_options_only(why: str) -> str:
    """Why a recording of N options does not go through, in one line."""
    return (f"the recording is of a table of N options ({why}): --through decision re-runs "
            "the paper's two-option engine only (docs/multi-option.md)")


def paper_options(msg: m.TrialEvent | m.TrialResult | m.Layout, src: Path) -> None:
    """Refuse (ValueError, one line) a recorded message of another option set than the paper's."""
    if tuple(msg.options) != COLOURS:
        raise ValueError(two_options_only(f"{src} has {msg.KIND} over {','.join(msg.options)}"))


def paper_value(msg: m.Opinions, src: Path) -> float:
    """The paper's signed number of a recorded opinion (refused for N options)."""
    if tuple(msg.options) != COLOURS:
        raise ValueError(two_options_only(f"{src} has opinions over {','.join(msg.options)}"))
    return msg.signed


@dataclass
class ThroughResult:
    """What `--through decision` did."""

    trials: list[TrialComparison]
    poses: int
    recomputed: int
    left_out: int
    messages: int


def through_decision(
    src_path: Path,
    out_path: Path,
    params: Path | None,
    tune: Mapping[int, DecisionParams] | None = None,
    extra_metadata: Mapping[str, str] | None = None,
) -> ThroughResult:
    """Re-run the decision model on a recording; write it with the recomputed outputs.

    `tune`: per trial index, the decision parameters of that trial (module doc);
    `extra_metadata`: more entries of the derived file's metadata.
    """
    src = McapIn(src_path)
    meta = src.file_metadata()
    cfg = decision_config(meta, params)
    model = DecisionModel(cfg.decision, cfg.layout)
    layout = cfg.layout
    out = McapOut(out_path)
    derived = {**meta, "derived_from": str(src_path), "through": "decision"}
    if params is not None:
        derived["through_params_file"] = str(params)
        derived["through_params_toml"] = Path(params).read_text(encoding="utf-8")
    derived.update(extra_metadata or {})
    out.metadata(FILE_METADATA, derived)
    seq = dict.fromkeys(DECISION_TOPICS, 0)
    trials: dict[int, TrialComparison] = {}
    current: TrialComparison | None = None
    poses = recomputed = left_out = 0
    failed = True
    try:
        for e in src:
            topic = topic_of(e.key)
            if e.key.split("/", 2)[-1].startswith("options/"):  # the retired N-option keys
                raise ValueError(two_options_only(f"{src_path} has {e.key}"))
            if topic in DECISION_TOPICS:
                left_out += 1
                if (
                    e.valid and current is not None and not current.closed
                    and topic != "decision/z_h"
                ):
                    msg = decode_entry(topic, e)
                    if msg is not None:
                        z_r, b_r = current.recorded.get(msg.src_seq, (math.nan, math.nan))
                        value = paper_value(msg, src_path)
                        current.recorded[msg.src_seq] = (
                            (value, b_r) if topic == "decision/z_r" else (z_r, value)
                        )
                continue
            msg = out.rewrite(e)
            if msg is None:
                continue
            if isinstance(msg, m.TrialEvent | m.TrialResult | m.Layout):
                paper_options(msg, src_path)
            if isinstance(msg, m.TrialEvent):
                if tune is not None and msg.phase == "setup":
                    wanted = tune.get(msg.trial, cfg.decision)
                    if wanted != model.params:
                        model.retune(wanted)
                try:
                    # a colour: `paper_options` held the event's options to red and blue
                    model.on_trial(msg.phase, msg.mode, cast(Colour | None, msg.option))
                except ValueError as exc:  # the decision service refuses such an event too
                    log.warning("trial event refused: %s", exc)
                if msg.phase == "setup":
                    current = trials[msg.trial] = TrialComparison(msg.trial, msg.mode, msg.option)
                elif msg.phase == "go" and current is not None and current.trial == msg.trial:
                    current.going = True
                elif msg.phase in ("end", "interrupted") and current is not None:
                    current.closed = True
            elif isinstance(msg, m.TrialResult) and msg.trial in trials:
                t = trials[msg.trial]
                t.robot, t.human, t.outcome = msg.robot, msg.human, msg.outcome
            elif isinstance(msg, m.GazeMsg):
                if not msg.gesture and msg.trial in trials:
                    trials[msg.trial].gaze = msg.level
            elif isinstance(msg, m.Layout):
                try:
                    layout = msg.paper_table()
                    model.set_layout(layout)
                except ValueError as exc:
                    log.warning("layout refused: %s", exc)
            elif isinstance(msg, m.HandPose):
                poses += 1
                if not model.accepts(msg.t_ns):
                    continue
                res = model.on_hand(msg.t_ns, msg.landmarks if msg.detected else None)
                prefix = e.key[: -len("vision/hand")]
                obs = res.observation
                outputs: tuple[tuple[str, m.Opinions], ...] = (
                    ("decision/z_r", m.Opinions(seq=seq["decision/z_r"], t_ns=msg.t_ns,
                                                src_seq=msg.seq, **m.signed_fields(res.z_r))),
                    ("decision/z_h", m.Observed(seq=seq["decision/z_h"], t_ns=msg.t_ns,
                                                src_seq=msg.seq, theta=obs.theta,
                                                distance=obs.distance,
                                                **m.signed_fields(res.z_hat))),
                    ("decision/b_r", m.Opinions(seq=seq["decision/b_r"], t_ns=msg.t_ns,
                                                src_seq=msg.seq, **m.signed_fields(res.b_r))),
                )
                for name, output in outputs:
                    seq[name] += 1
                    out.write_message(prefix + name, output, e.message.log_time)
                    recomputed += 1
                if current is not None and not current.closed:
                    current.recomputed[msg.seq] = (res.z_r, res.b_r)
                    if (current.going and current.press_seq is None and msg.detected
                            and layout.pressed(msg.landmarks) is not None):
                        current.press_seq = msg.seq
        for name, data in src.metadata:
            if name == SESSION_METADATA:
                out.metadata(name, dict(data))
        out.metadata(END_METADATA, {"messages": str(out.messages), "source_truncated":
                                    src.truncated or ""})
        failed = False
    finally:
        out.finish()
        if failed:  # no half-derived file left behind
            Path(out_path).unlink(missing_ok=True)
    return ThroughResult(sorted(trials.values(), key=lambda t: t.trial), poses, recomputed,
                         left_out, out.messages)
