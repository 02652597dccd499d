"""The protocol's two phases and a participant's category in each (Sec 7, Fig 8b).

The control phase is trials 1–3 (neutral eyes, a robot in dissensus), the experiment phase
trials 4–8. A participant's category in a phase is the most frequent outcome of its trials; the
study analysis, the power analysis and the cohort calibration's Fig 8b flows all use this one
rule.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence

CONTROL_TRIALS: tuple[int, ...] = (1, 2, 3)
EXPERIMENT_TRIALS: tuple[int, ...] = (4, 5, 6, 7, 8)


def phase_category(outcomes: Sequence[str | None]) -> str | None:
    """The most frequent outcome of a phase's trials (in trial order); ties go to the later trial.

    None entries (timeouts, missing trials) are ignored; None if nothing is left.
    """
    counts = Counter(o for o in outcomes if o is not None)
    if not counts:
        return None
    top = max(counts.values())
    last_seen = {o: i for i, o in enumerate(outcomes) if o is not None}
    return max((o for o, n in counts.items() if n == top), key=lambda o: last_seen[o])
