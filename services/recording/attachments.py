"""The viewers' layouts every recording carries as MCAP attachments.

- `foxglove-layout.json` (application/json): a Foxglove layout of a trial over the
  recording's own channels (`services.views.foxglove`): import it in Foxglove's layout menu.
- `rerun-blueprint.rbl` (application/vnd.rerun.blueprint): a Rerun blueprint of a trial over
  the monitor's entity tree (`services.views.blueprint`), written by the SDK's
  `Blueprint.save`: open it beside the `.rrd` that `nod monitor --save` writes while the
  recording is replayed (docs/data.md).
"""

from __future__ import annotations

from functools import cache

from services.recording.mcap_io import McapOut
from services.views.blueprint import RBL_MEDIA_TYPE, blueprint_bytes, trial_blueprint
from services.views.foxglove import LAYOUT_MEDIA_TYPE, layout_bytes

FOXGLOVE_LAYOUT = "foxglove-layout.json"
RERUN_BLUEPRINT = "rerun-blueprint.rbl"
NAMES = (FOXGLOVE_LAYOUT, RERUN_BLUEPRINT)


@cache
def _blueprint() -> bytes:
    return blueprint_bytes(trial_blueprint())


def attach_views(out: McapOut, rig: str, log_time: int) -> None:
    """Attach the Foxglove layout (for `rig`'s keys) and the Rerun blueprint to `out`."""
    out.attach(FOXGLOVE_LAYOUT, LAYOUT_MEDIA_TYPE, layout_bytes(rig), log_time)
    out.attach(RERUN_BLUEPRINT, RBL_MEDIA_TYPE, _blueprint(), log_time)
