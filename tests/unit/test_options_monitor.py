"""The monitor over a table of three boxes: one bar chart per opinion, boxes by colour."""

from __future__ import annotations

import uuid
from pathlib import Path

import rerun as rr
from rerun.chunk import RrdReader

from services.core import options_messages as om
from services.model.geometry import OptionsLayout
from services.monitor.bridge import APPLICATION_ID, RerunBridge, blueprint, rrd_rows

T0 = 1_700_000_000_000_000_000
NAMES = ("red", "blue", "green")


def _record(tmp_path: Path, messages: list[tuple[str, object]]) -> tuple[Path, RerunBridge]:
    path = tmp_path / "o.rrd"
    rec = rr.RecordingStream(APPLICATION_ID, recording_id=uuid.uuid4())
    rec.set_sinks(rr.FileSink(str(path)), default_blueprint=blueprint())
    bridge = RerunBridge(rec)
    bridge.log_styles()
    for topic, msg in messages:
        bridge.log(topic, msg)  # type: ignore[arg-type]
    rec.flush()
    rec.disconnect()
    return path, bridge


def test_three_options_show_as_bars_boxes_and_named_results(tmp_path: Path) -> None:
    layout = om.layout_message_fields(NAMES, OptionsLayout.row(3))
    msgs: list[tuple[str, object]] = [
        ("options/layout", om.OptionsLayoutMsg(seq=0, t_ns=T0, **layout)),
        ("options/trial", om.OptionsTrialEvent(seq=0, t_ns=T0, n_options=3, phase="setup",
                                                trial=4, mode="consensus", option=2)),
    ]
    for i in range(4):
        for topic in ("options/z_h", "options/z_r", "options/b_r"):
            msgs.append((topic, om.OptionVector(seq=i, t_ns=T0 + i, values=(0.2 * i, -0.1 * i,
                                                                             -0.1 * i))))
    msgs.append(("options/arm_state", om.OptionsArmState(seq=0, t_ns=T0 + 9, n_options=3,
                                                         ee=(0.3, 0.2), target=2)))
    msgs.append(("options/result", om.OptionsResult(seq=0, t_ns=T0 + 10, n_options=3, trial=4,
                                                     mode="consensus", option=2, robot=2,
                                                     human=2, outcome="C", score=2)))
    path, bridge = _record(tmp_path, msgs)
    rows, static = rrd_rows(path)
    for bars in ("/options/z_h", "/options/z_r", "/options/b_r"):
        assert rows[bars] == 4
    assert static["/table/buzzers"] == 1 and rows["/table/arm"] == 1
    assert bridge.trial == 4 and bridge.option_names == NAMES
    texts = []
    for chunk in RrdReader(path).stream():
        if chunk.entity_path in ("/log/trial", "/log/result") and not chunk.is_static:
            batch = chunk.to_record_batch()
            i = batch.schema.get_field_index("TextLog:text")
            texts += batch.column(i).to_pylist()
    assert any("O=green" in str(t) for t in texts), texts
    assert any("robot green, human green → C" in str(t) for t in texts), texts
