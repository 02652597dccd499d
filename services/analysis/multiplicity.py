"""Corrections for multiple comparisons over a family of tests (the study's Stuart–Maxwell tests).

Each method maps the family's m raw p-values to adjusted ones, so that "adjusted p < α" controls
the family-wise error rate at α:

- **Holm** (step-down, Holm 1979): sort p ascending, p_(1) ≤ … ≤ p_(m);
  p̃_(i) = max_{j ≤ i} min(1, (m − j + 1) p_(j)). Uniformly more powerful than Bonferroni and
  valid under any dependence between the tests (the adjacent-trial tests share participants).
- **Bonferroni**: p̃_i = min(1, m p_i).
- **none**: p̃_i = p_i.

No statistics package of the environment has Holm (statsmodels is not a dependency; scipy has
only Benjamini–Hochberg, `scipy.stats.false_discovery_control`), so it is written out here.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal, get_args

Correction = Literal["holm", "bonferroni", "none"]
CORRECTIONS: tuple[Correction, ...] = get_args(Correction)
NAMES: dict[Correction, str] = {"holm": "Holm", "bonferroni": "Bonferroni", "none": "uncorrected"}


def adjust(p: Sequence[float], method: Correction = "holm") -> list[float]:
    """The adjusted p-values of a family, in the order given; ValueError for a p outside [0, 1]."""
    if method not in CORRECTIONS:
        raise ValueError(f"correction must be one of {', '.join(CORRECTIONS)}, got {method!r}")
    bad = [x for x in p if not 0.0 <= x <= 1.0]  # also refuses nan
    if bad:
        raise ValueError(f"p-values must lie in [0, 1], got {bad}")
    m = len(p)
    if method == "none":
        return [float(x) for x in p]
    if method == "bonferroni":
        return [min(1.0, m * x) for x in p]
    out = [0.0] * m
    running = 0.0
    for rank, i in enumerate(sorted(range(m), key=lambda k: p[k])):
        running = max(running, min(1.0, (m - rank) * p[i]))
        out[i] = running
    return out
