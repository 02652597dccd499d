"""Per-participant model fits in the store (`nod fit`): table `fits`, exported as fits.csv.

One row per participant and identifiable parameter: the estimate and its interval, the session
it was fitted from, the method and when. A 0/1 parameter (a kind) has its most likely value as
the estimate, its 90 % set's least and largest value as low and high, and its probability of 1
in `probability` (NULL for every other parameter; a store written before the column was added
gets it, NULL, when opened: `Store._migrate`). `prior_p` is the participant's out-of-prior check
(`services.fit.prior_check`; below 0.05 the fit's prior does not reproduce them), the same on
each of their rows; NULL for a fit made before the check (the column is added the same way).
A parameter that the recovery check did not pass is
not stored: an estimate that the data cannot pin down is no finding to export. Fitting a
participant again replaces their rows. The table is created with the others
(`services.store.schema.FITS_SCHEMA`: an older file gets it when opened).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from services.store.store import Store



@dataclass(frozen=True, slots=True)
class FitRecord:
    """One participant's estimate of one parameter."""

    participant: str
    session: str
    parameter: str
    estimate: float
    low: float
    high: float
    level: float  # the interval's nominal coverage (0.9)
    method: str  # how it was fitted, e.g. "sbi-quantile-boosting K=2000 params=<hash>"
    fitted_ns: int  # wall clock
    probability: float | None = None  # a 0/1 parameter's probability of 1; None for the others
    prior_p: float | None = None  # the participant's out-of-prior p-value; None: unchecked


def write_fits(store: Store, records: Sequence[FitRecord]) -> None:
    """Store fits, replacing every earlier row of the participants they are for, atomically."""
    with store.transaction():
        for who in sorted({r.participant for r in records}):
            store.db.execute("DELETE FROM fits WHERE participant = ?", (who,))
        store.db.executemany(
            "INSERT INTO fits (participant, session, parameter, estimate, low, high, level, "
            "method, fitted_ns, probability, prior_p) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
            [(r.participant, r.session, r.parameter, r.estimate, r.low, r.high, r.level,
              r.method, r.fitted_ns, r.probability, r.prior_p) for r in records],
        )


def read_fits(store: Store) -> list[FitRecord]:
    """Every stored fit, by participant and parameter."""
    cur = store.db.execute(
        "SELECT participant, session, parameter, estimate, low, high, level, method, fitted_ns, "
        "probability, prior_p FROM fits ORDER BY participant, parameter"
    )
    return [FitRecord(*row) for row in cur]
