"""The conductor's participant checks and O order: `nod experiment --order … --again …`.

A session runs the schedule of its parameters with the O of its consensus trials given by
`--order` (a study's counterbalanced order, `nod study start`), or the schedule's own. The order
is stored with the session (`services.store.participants`), and a resumed session runs the
order it was started with. A participant who already has a complete session is refused, unless
`--again REASON` says why they do the study once more (the reason is stored too).
"""

from __future__ import annotations

import dataclasses

from services.model.params import NodConfig
from services.model.protocol import Order, order_of, parse_order, with_order
from services.store import Store
from services.store.participants import check_id, order_of_session, reuse_problem
from services.store.withdrawals import withdrawal_problem


def session_config(
    cfg: NodConfig, store: Store, order: str | None, resume: str | None
) -> NodConfig:
    """The configuration a session runs: `cfg` with its O order (ValueError: why not).

    `order` is the `--order` flag (None: not given); `resume` the session resumed (or None),
    whose stored order wins, and a different `--order` is refused.
    """
    trials = cfg.protocol.trials
    wanted: Order | None = None if order is None else parse_order(order, len(order_of(trials)))
    if resume is not None:
        stored = order_of_session(store, resume)
        if stored is not None:
            n = len(order_of(trials))
            if len(stored) != n:
                raise ValueError(
                    f"session {resume} ran {len(stored)} consensus trials, these parameters "
                    f"have {n}: resume it with the --params it started with"
                )
            ran = parse_order(",".join(stored), n)
            if wanted is not None and wanted != ran:
                raise ValueError(
                    f"session {resume} runs the order {','.join(ran)}; --order "
                    f"{','.join(wanted)} differs (leave --order out to resume it)"
                )
            wanted = ran
    if wanted is None or wanted == order_of(trials):
        return cfg
    protocol = dataclasses.replace(cfg.protocol, trials=with_order(trials, wanted))
    return dataclasses.replace(cfg, protocol=protocol)


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
