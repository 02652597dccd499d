"""One study from several stores: each rig's conductor writes its own, the tools read them all.

A lab that runs the study on several rigs keeps one store per rig (no two conductors ever share
a SQLite file across hosts); `nod analyze study` and `nod export` take every store as one
study. Sessions keep the rig their conductor stored with them. A participant belongs to one
rig and one store: an id found in two stores, or on two rigs, is refused in one line naming
both — two people given one id, or one person run twice, is for the experimenter to resolve,
never a merge that would count someone twice or drop a session silently. A store holding part
of a simulated cohort (`nod cohort` stopped half-way, `services.store.cohorts`) is refused too:
its sessions are not the cohort.
"""

from __future__ import annotations

import sqlite3
from collections.abc import Iterator, Sequence
from contextlib import closing, contextmanager
from pathlib import Path

from services.store.cohorts import refuse_unfinished
from services.store.store import Store


@contextmanager
def open_stores(paths: Sequence[str | Path]) -> Iterator[list[tuple[str, Store]]]:
    """Every store by its path, checked to hold disjoint participants; closed on exit.

    ValueError (one line) for a missing file, a store given twice, a participant of two, or a
    store with an incomplete cohort.
    """
    names = [str(p) for p in paths]
    if not names:
        raise ValueError("no store given: --db FILE (repeat it for each rig's store)")
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise ValueError(f"--db {twice[0]} is given twice: each store once")
    for name in names:
        if not Path(name).is_file():
            raise ValueError(f"--db: no such database {name!r}; run `nod run` first")
    opened: list[tuple[str, Store]] = []
    try:
        for name in names:
            opened.append((name, Store(name)))
            refuse_unfinished(opened[-1][1], name)
        check_participants(opened)
        yield opened
    finally:
        for _, store in opened:
            store.close()


def check_participants(stores: Sequence[tuple[str, Store]]) -> None:
    """Refuse a participant id found in two stores or on two rigs (ValueError, one line)."""
    home: dict[str, tuple[str, str | None]] = {}  # participant -> (store, rig of its sessions)
    for name, store in stores:
        found: list[tuple[str, str | None]] = [
            (str(s["participant"]), str(s["rig"])) for s in store.sessions()
        ]
        # Answers are the participant's too: in another store than the sessions, they'd be
        # someone else's or a copy.
        found += [(q.participant, None) for q in store.questionnaires()]
        for pid, rig in found:
            seen = home.get(pid)
            if seen is None or seen[1] is None and seen[0] == name:
                home[pid] = (name, rig)
                continue
            if seen[0] != name:
                raise ValueError(
                    f"participant {pid} is in two stores, {seen[0]} and {name}: one person has "
                    "one id in one store; give one of them a new id (or leave a store out)"
                )
            if rig is not None and seen[1] != rig:
                raise ValueError(
                    f"participant {pid} has sessions on rigs {seen[1]} and {rig} in {name}: "
                    "one person runs on one rig; give one of them a new id"
                )


@contextmanager
def union_of(stores: Sequence[tuple[str, Store]]) -> Iterator[sqlite3.Connection]:
    """One read-only connection on which each table of the stores is the union of their rows.

    Every store is attached read-only, and each of the first store's tables is a view of the
    same name over all of them (by column name: a migrated store may order its columns
    otherwise), so a query written for one store — `nod export`'s, with its ORDER BY — reads
    every store's rows as one.
    """
    with closing(sqlite3.connect("file::memory:", uri=True)) as db:  # URIs: the read-only ATTACH
        for i, (name, _) in enumerate(stores):
            uri = Path(name).absolute().as_uri() + "?mode=ro"
            db.execute(f"ATTACH DATABASE ? AS s{i}", (uri,))
        tables = [r[0] for r in db.execute(
            "SELECT name FROM s0.sqlite_master WHERE type = 'table' AND name NOT LIKE 'sqlite_%'"
        )]
        for table in tables:
            cols = ", ".join(f'"{r[1]}"' for r in db.execute(f'PRAGMA s0.table_info("{table}")'))
            parts = [f'SELECT {cols} FROM s{i}."{table}"' for i in range(len(stores))]
            db.execute(f'CREATE TEMP VIEW "{table}" AS ' + " UNION ALL ".join(parts))
        yield db
