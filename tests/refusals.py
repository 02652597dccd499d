"""One check for a refusal that must be one line: a study file's, a policy file's."""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path

import pytest


def refused_in_one_line(load: Callable[[Path], object], path: Path, error: type[Exception],
                        message: str) -> None:
    """`load(path)` raises `error` in one line that names the file and matches `message`."""
    with pytest.raises(error) as exc:
        load(path)
    text = str(exc.value)
    assert "\n" not in text and text.startswith(str(path)), text
    assert re.search(message, text), text
