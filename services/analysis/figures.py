"""What every figure of the analysis shares: a headless matplotlib and the output formats.

matplotlib is imported on first use only (the statistics and the services never pay for it),
with the Agg backend so figures draw on a machine without a display.
"""

from __future__ import annotations

from typing import Any

# matplotlib picks the backend from the file's suffix: PNG for reports, PDF or SVG for a paper
# (vector; SVG keeps the text as text).
FORMATS = ("png", "pdf", "svg")


def pyplot() -> Any:
    """matplotlib.pyplot on the headless Agg backend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def parse_formats(text: str) -> tuple[str, ...]:
    """"png,pdf" → ("png", "pdf"); ValueError naming the allowed formats otherwise."""
    formats = tuple(dict.fromkeys(f.strip().lower() for f in text.split(",") if f.strip()))
    if not formats or any(f not in FORMATS for f in formats):
        raise ValueError(f"formats must be among {', '.join(FORMATS)}, got {text!r}")
    return formats
