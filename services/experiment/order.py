"""The conductor's participant checks and O order: `nod experiment --order … --again …`.

A session runs the schedule of its parameters with the O of its consensus trials given by
`--order` (a study's counterbalanced order, `nod study start`; over any option set, by name),
or the schedule's own. The order is stored with the session (`services.store.participants`),
and a resumed session runs the order it was started with. A participant who already has a
complete session is refused, unless `--again REASON` says why they do the study once more (the
reason is stored too).
"""

from __future__ import annotations

from services.experiment.keyspace import KeySpace, Order
from services.store import Store
from services.store.participants import check_id, order_of_session, reuse_problem
from services.store.withdrawals import withdrawal_problem


def session_keys(
    keys: KeySpace, store: Store, order: str | None, resume: str | None
) -> KeySpace:
    """The key space a session runs: `keys` with its O order (ValueError: why not).

    `order` is the `--order` flag (None: not given), by the option set's names (the paper's
    colours or letters, `KeySpace.parse_order`); `resume` the session resumed (or None), whose
    stored order wins, and a different `--order` is refused.
    """
    wanted: Order | None = None if order is None else keys.parse_order(order)
    if resume is not None:
        stored = order_of_session(store, resume)
        if stored is not None:
            n = len(keys.order())
            if len(stored) != n:
                raise ValueError(
                    f"session {resume} ran {len(stored)} consensus trials, these parameters "
                    f"have {n}: resume it with the --params it started with"
                )
            ran = keys.parse_order(",".join(stored))
            if wanted is not None and wanted != ran:
                raise ValueError(
                    f"session {resume} runs the order {','.join(ran)}; --order "
                    f"{','.join(wanted)} differs (leave --order out to resume it)"
                )
            wanted = ran
    if wanted is None or wanted == keys.order():
        return keys
    return keys.with_order(wanted)


def participant_problem(
    store: Store, participant: str, again: str | None, resume: str | None
) -> str | None:
    """Why this session may not start, or None.

    A bad id, a reused one without a reason, a participant who withdrew (a resumed session too).
    """
    if resume is not None:  # the session's own participant, going on, unless they withdrew
        row = store.db.execute(
            "SELECT participant FROM sessions WHERE session = ?", (resume,)
        ).fetchone()
        return None if row is None else withdrawal_problem(store, str(row[0]))
    if again is not None and not again.strip():
        return "--again needs a reason, e.g. --again 'fire alarm at trial 5'"
    try:
        check_id(participant)
    except ValueError as exc:
        return f"--participant: {exc}"
    if again is not None:
        return withdrawal_problem(store, participant)
    return reuse_problem(store, participant, complete_only=True)
