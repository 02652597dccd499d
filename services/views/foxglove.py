"""A Foxglove layout of a trial over a recording's channels: the hand, the opinions, the arm.

Foxglove reads a recording's JSON channels through their JSON Schemas, so its panels address
fields by message path: topic (the full key, quoted: it has no leading slash) and field. The
layout (Foxglove's layout JSON: `configById`, a mosaic `layout` tree of panel ids) holds:

- opinions: ẑ_h, z_r and b_r over time (option 0's value: the paper's signed z);
- hand and arm: the hand centre's and the end effector's x and y over time (the table image,
  normalised; y toward the person);
- trial and arm: the protocol's phase and the arm's phase as state transitions;
- the trial's events and results as raw messages.

Times are each message's log time (the recorder's clock), Foxglove's "receive time".
"""

from __future__ import annotations

import json
from typing import Any

LAYOUT_MEDIA_TYPE = "application/json"


def _path(rig: str, topic: str, field: str) -> str:
    return f'"nod/{rig}/{topic}".{field}'


def _plot(title: str, paths: list[str]) -> dict[str, Any]:
    return {
        "title": title,
        "paths": [{"value": p, "enabled": True, "timestampMethod": "receiveTime"}
                  for p in paths],
        "showLegend": True,
        "legendDisplay": "floating",
        "isSynced": True,
        "xAxisVal": "timestamp",
    }


def _split(direction: str, first: Any, second: Any, percent: float = 50) -> dict[str, Any]:
    return {"direction": direction, "first": first, "second": second,
            "splitPercentage": percent}


def trial_layout(rig: str) -> dict[str, Any]:
    """The layout of a trial for the keys of `rig` (`nod/<rig>/...`)."""
    opinions = [_path(rig, f"decision/{q}", "values[0]") for q in ("z_h", "z_r", "b_r")]
    hand_arm = [_path(rig, "vision/hand", "center[0]"), _path(rig, "vision/hand", "center[1]"),
                _path(rig, "actuation/state", "ee[0]"), _path(rig, "actuation/state", "ee[1]")]
    config = {
        "Plot!opinions": _plot("opinions: ẑ_h, z_r, b_r (option 0)", opinions),
        "Plot!hand_arm": _plot("hand centre and end effector (x, y)", hand_arm),
        "StateTransitions!phases": {
            "title": "trial and arm",
            "paths": [{"value": _path(rig, "experiment/trial", "phase"),
                       "timestampMethod": "receiveTime"},
                      {"value": _path(rig, "actuation/state", "phase"),
                       "timestampMethod": "receiveTime"}],
        },
        "RawMessages!trial": {"topicPath": f'"nod/{rig}/experiment/trial"'},
        "RawMessages!result": {"topicPath": f'"nod/{rig}/experiment/result"'},
    }
    return {
        "configById": config,
        "globalVariables": {},
        "userNodes": {},
        "playbackConfig": {"speed": 1},
        "layout": _split(
            "row",
            _split("column", "Plot!opinions", "Plot!hand_arm"),
            _split("column", "StateTransitions!phases",
                   _split("row", "RawMessages!trial", "RawMessages!result"), 40),
            60,
        ),
    }


def layout_bytes(rig: str) -> bytes:
    """`trial_layout(rig)` as a JSON file's bytes."""
    return json.dumps(trial_layout(rig), indent=1, ensure_ascii=False).encode()
