"""Fixtures of the unit tests."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest


@pytest.fixture
def close() -> Iterator[list[Any]]:
    """Figures to close after the test (the figure tests append what they draw).

    matplotlib is imported here, when a figure test asks, not when any unit test starts.
    """
    from services.analysis.figures import pyplot

    figs: list[Any] = []
    yield figs
    for fig in figs:
        pyplot().close(fig)
