"""Rerun blueprints over the monitor's entity tree (`services.views.entities`).

The views both layouts share are made here once: the opinions (a time series of the signed
ẑ_h, z_r, b_r, or a bar chart each over three or more options) and the table seen from the
camera (buzzers, commit line, the hand's and the end effector's last `TRAIL_S` as a trail, the
arm's segment and the gaze as they are now). `services.monitor.bridge.blueprint` adds the eyes,
states, camera and text log around them; `trial_blueprint` is the recording's: the hand, the
opinions and the arm of a trial, stepped through on the `trial` timeline.

`blueprint_bytes` writes a blueprint as an `.rbl` file with the SDK's own `Blueprint.save`
(no viewer needed) and returns its bytes, for a recording's attachment.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import rerun.blueprint as rrb

from services.views.entities import APPLICATION_ID, ENTITIES, TIMELINE

TRAIL_S = 3.0  # seconds of hand / end-effector path shown on the table
LIVE_S = 0.1  # the arm segment and the gaze arrows: only the last 0.1 s (≥ 2 samples of each)
RBL_MEDIA_TYPE = "application/vnd.rerun.blueprint"  # an .rbl file (Rerun names no media type)


def opinions_view(bars: bool = False) -> rrb.Container | rrb.View:
    """ẑ_h, z_r and b_r: one time series view, or (`bars`: N > 2 options) a bar chart each."""
    if not bars:
        return rrb.TimeSeriesView(origin="opinion", name="opinions: ẑ_h, z_r, b_r")
    return rrb.Horizontal(*(
        rrb.BarChartView(origin=ENTITIES[f"bars/{o}"], name=f"{label}, one bar per option")
        for o, label in (("z_h", "ẑ_h"), ("z_r", "z_r"), ("b_r", "b_r"))
    ))


def _since(seconds: float) -> rrb.TimeRangeBoundary:
    return rrb.TimeRangeBoundary.cursor_relative(seconds=-seconds)


def table_view() -> rrb.Spatial2DView:
    """The table: buzzers, commit line, hand and arm over the last TRAIL_S; arm and gaze now."""
    now = rrb.TimeRangeBoundary.cursor_relative()
    live = rrb.VisibleTimeRanges(timeline=TIMELINE, start=_since(LIVE_S), end=now)
    return rrb.Spatial2DView(
        origin="table",
        name="table: buzzers, commit line, hand, arm and gaze",
        visual_bounds=rrb.VisualBounds2D(x_range=[0.0, 1.0], y_range=[0.0, 1.0]),
        time_ranges=rrb.VisibleTimeRange(TIMELINE, start=_since(TRAIL_S), end=now),
        # the arm and the gaze as they are now, not a 3 s fan of old segments and arrows
        overrides={ENTITIES["arm_link"]: live, ENTITIES["gaze"]: live},
    )


def trial_blueprint() -> rrb.Blueprint:
    """A trial at a glance: the opinions over the arm's state, the table, the trial's events."""
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                opinions_view(),
                rrb.StateTimelineView(origin="state", name="trial · arm · gaze"),
                row_shares=[3, 1],
            ),
            rrb.Vertical(
                table_view(),
                rrb.TextLogView(origin="log", name="events, presses, outcomes"),
                row_shares=[3, 1],
            ),
            column_shares=[1, 1],
        ),
        rrb.TimePanel(timeline=TIMELINE),
        collapse_panels=True,
    )


def blueprint_bytes(blueprint: rrb.Blueprint, application_id: str = APPLICATION_ID) -> bytes:
    """The blueprint as an `.rbl` file's bytes (`Blueprint.save`, the SDK's file format)."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "trial.rbl"
        blueprint.save(application_id, path)
        return path.read_bytes()
