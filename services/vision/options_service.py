"""`nod vision --options N`: the camera path over a table of N boxes.

`VisionService` as ever for the hand (`vision/hand`, the monitor's frame), and for the table
the boxes of every option found by their colours in the camera's frames
(`services.vision.option_boxes`), published on `options/layout` at 1 Hz once found. Until
every box is found nothing is published for the table (each tracked frame tries again, with a
warning every 100 frames); the paper's `vision/layout` is not published.
"""

from __future__ import annotations

import logging
from typing import Any

from services.core.options_messages import LayoutFields, layout_message_fields
from services.model.geometry import CommitLine
from services.vision.calibration import CalibrationError
from services.vision.option_boxes import find_option_boxes
from services.vision.service import VisionService

log = logging.getLogger("nod.vision")


class OptionsVisionService(VisionService):
    """A VisionService that finds N boxes by colour and publishes them on options/layout."""

    def __init__(self, *args: Any, names: tuple[str, ...], commit: CommitLine,
                 **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.names = names
        self.commit = commit
        self.pub_options = self.node.publisher("options/layout")
        self.options_fields: LayoutFields | None = None
        self._tries = 0

    def process(self, frame: Any) -> Any:
        """Find the boxes (until found), then track the hand as VisionService does."""
        if self.options_fields is None:
            try:
                found = find_option_boxes(frame.image, self.names, self.commit)
            except CalibrationError as exc:
                self._tries += 1
                if self._tries % 100 == 1:
                    log.warning("table of %d boxes not found yet: %s", len(self.names), exc)
            else:
                self.options_fields = layout_message_fields(self.names, found)
                log.info("found the %d boxes: %s", len(self.names), self.options_fields)
        return super().process(frame)

    def publish_layout(self, now_ns: int) -> None:
        """The N boxes and the commit line, latched by republishing every second (once found)."""
        if self.options_fields is not None:
            self.pub_options.put(t_ns=now_ns, **self.options_fields)
