"""Text for one line of stderr: every error the rig prints goes through `one_line`.

Apart from `services.core.cli` so that the session code (which the CLI helpers build on) can
use it without importing the CLI back.
"""

from __future__ import annotations

import re


def one_line(text: str, limit: int | None = 300) -> str:
    """An error for one line of stderr: whitespace folded, zenoh's Rust locations gone, cut short.

    `limit` characters at most (None: the whole text).
    """
    text = re.sub(r"\s*\bat \S+\.rs:\d+\.?", "", " ".join(text.split()))
    return text if limit is None or len(text) <= limit else text[:limit] + "…"
