"""The monitor over a table of N boxes: one bar per option, the boxes, the arm, the trials.

`RerunBridge` dispatches the `options/*` messages here (its `_on_<KIND>` handlers are these
functions), so the paper's bridge stays as it is. Entities:

    options/{z_h,z_r,b_r}        a bar chart each: one bar per option, the latest vector
    table/buzzers                the N boxes in their options' colours, labelled by name
    table/{arm,arm_link}         the end effector and the arm's segment, as the paper's arm
    log/{trial,result}           the protocol's steps and the outcomes, options by name

The first `options/*` message sends a blueprint with the three bar charts beside the table.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from services.core import options_messages as om
from services.scene.option_colours import COLOURS

BARS: dict[str, str] = {
    "options/z_h": "options/z_h",
    "options/z_r": "options/z_r",
    "options/b_r": "options/b_r",
}
_GREY = (160, 160, 160)


def options_blueprint() -> rrb.Blueprint:
    """The layout of an N-option session: the three bar charts, the table, the text log."""
    bars = rrb.Vertical(
        rrb.BarChartView(origin=BARS["options/z_h"], name="ẑ_h, one bar per option"),
        rrb.BarChartView(origin=BARS["options/z_r"], name="z_r, one bar per option"),
        rrb.BarChartView(origin=BARS["options/b_r"], name="b_r, one bar per option"),
    )
    right = rrb.Vertical(
        rrb.Spatial2DView(origin="table", name="table: boxes, hand, arm",
                          visual_bounds=rrb.VisualBounds2D(x_range=[0.0, 1.0], y_range=[0.0, 1.0])),
        rrb.TextLogView(origin="log", name="events, outcomes"),
    )
    return rrb.Blueprint(rrb.Horizontal(bars, right), rrb.TimePanel(timeline="time"),
                         collapse_panels=True)


def _name(bridge: Any, option: int | None) -> str:
    names: tuple[str, ...] = bridge.option_names
    if option is None:
        return "-"
    return names[option] if option < len(names) else f"box {option}"


def _first(bridge: Any) -> None:
    if not bridge.options_seen:
        bridge.options_seen = True
        bridge.rec.send_blueprint(options_blueprint())


def on_option_vector(bridge: Any, topic: str, msg: om.OptionVector) -> None:
    """ẑ_h, z_r or b_r over the options: a bar chart of the latest vector."""
    _first(bridge)
    path = BARS.get(topic)
    if path is not None:
        bridge.rec.log(path, rr.BarChart(np.asarray(msg.values, dtype=np.float64)))


def on_options_layout(bridge: Any, topic: str, msg: om.OptionsLayoutMsg) -> None:
    """The N boxes, each in its option's colour (grey when the name is not a colour)."""
    _first(bridge)
    key = (msg.names, msg.boxes, msg.commit_y)
    if key == bridge.options_layout:
        return
    bridge.options_layout, bridge.option_names = key, msg.names
    colours = [tuple(reversed(COLOURS[n][0])) if n in COLOURS else _GREY for n in msg.names]
    bridge.rec.log("table/buzzers", rr.Boxes2D(
        array=np.array(msg.boxes, dtype=np.float32), array_format=rr.Box2DFormat.XYXY,
        colors=colours, labels=list(msg.names)), static=True)


def on_options_arm_state(bridge: Any, topic: str, msg: om.OptionsArmState) -> None:
    """The end effector and the arm's segment from its base."""
    bridge.rec.log("table/arm", rr.Points2D([msg.ee]))
    bridge.rec.log("table/arm_link", rr.LineStrips2D([[(0.5, 0.0), msg.ee]]))


def on_options_trial(bridge: Any, topic: str, msg: om.OptionsTrialEvent) -> None:
    """A protocol step, O by name."""
    _first(bridge)
    o = f" O={_name(bridge, msg.option)}" if msg.option is not None else ""
    text = f"trial {msg.trial} {msg.phase} [{msg.mode}{o}]" + (f": {msg.text}" if msg.text else "")
    bridge.rec.log("log/trial", rr.TextLog(text, level="WARN" if msg.phase == "abort" else "INFO"))


def on_options_result(bridge: Any, topic: str, msg: om.OptionsResult) -> None:
    """A finished trial, its options by name."""
    o = f" O={_name(bridge, msg.option)}" if msg.option is not None else ""
    text = (f"trial {msg.trial} [{msg.mode}{o}]: robot {_name(bridge, msg.robot)}, human "
            f"{_name(bridge, msg.human)} → {msg.outcome or '-'} (switches {msg.switches}, "
            f"violations {msg.violations}, score {msg.score})")
    if msg.interrupted:
        text += ": interrupted, not scored"
    bridge.rec.log("log/result", rr.TextLog(text, level="WARN" if msg.interrupted else "INFO"))
