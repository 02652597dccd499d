"""The checks parameter dataclasses run in `__post_init__`, worded once.

A bad value in a config file must fail where it is loaded, in one line that names the class, the
field, the rule and the value ("SimArmParams.max_speed must be finite and > 0, got 0.0"), not
as a NaN or a division by zero deep in a session. Each check takes the object and the names of
the fields it applies to, and checks them in that order.
"""

from __future__ import annotations

import math
from collections.abc import Callable


def _require(obj: object, names: tuple[str, ...], ok: Callable[[float], bool], rule: str) -> None:
    for name in names:
        value = getattr(obj, name)
        if not ok(value):
            raise ValueError(f"{type(obj).__name__}.{name} must be {rule}, got {value!r}")


def require_finite(obj: object, *names: str) -> None:
    """Each named field is a finite number (not NaN, not ±inf)."""
    _require(obj, names, math.isfinite, "finite")


def require_positive(obj: object, *names: str) -> None:
    """Each named field is finite and > 0 (a duration, a rate, a gain that divides)."""
    _require(obj, names, lambda v: math.isfinite(v) and v > 0, "finite and > 0")


def require_non_negative(obj: object, *names: str) -> None:
    """Each named field is finite and >= 0 (a hold, a margin, a magnitude)."""
    _require(obj, names, lambda v: math.isfinite(v) and v >= 0, "finite and >= 0")
