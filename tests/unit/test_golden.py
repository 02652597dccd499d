"""The paper's study as it is computed today stays as it is (issue 34's golden).

`tests/golden/golden.py` says what is kept; a change to any number here is a change of the
paper's pipeline, to be made on purpose (`python -m tests.golden.golden --write`, said in the
commit), never as a side effect of a refactor.
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

import pytest

from tests.golden import golden


@pytest.fixture(scope="module")
def now() -> dict:
    return json.loads(json.dumps(golden.capture()))


@pytest.mark.parametrize("part", golden.FILES)
def test_the_paper_pipeline_equals_its_golden(now, part):
    kept = json.loads((golden.HERE / f"{part}.json").read_text())
    diffs = golden.held_in(kept, now[part], part)
    assert not diffs, "\n".join(diffs[:20])


def test_the_golden_notices_a_changed_number():
    kept = {"a": [1, {"b": 0.5}], "c": "x"}
    assert golden.held_in(kept, {"a": [1, {"b": 0.5}], "c": "x", "new": 1}) == []
    assert golden.held_in(kept, {"a": [1, {"b": 0.50000001}], "c": "x"}) == [
        "/a[1]/b: 0.50000001 was 0.5"]
    assert golden.held_in(kept, {"a": [1], "c": "x"})[0].startswith("/a:")
    assert golden.held_in(kept, {"a": [1, {"b": 0.5}]}) == ["/c: missing"]


def test_the_golden_cohort_is_the_stored_cohort():
    # The digests cover what `nod cohort` stores: the same sessions in a store give the same.
    with tempfile.TemporaryDirectory() as tmp:
        db = Path(tmp) / "c.sqlite"
        sessions = golden.cohort_sessions(db)
        from services.store import Store

        store = Store(db)
        try:
            stored = {s["seed"]: [t.outcome for _, t in store.trials(s["session"])]
                      for s in store.sessions()}
        finally:
            store.close()
    assert stored == {int(seed): [t["outcome"] for t in trials]
                      for seed, trials in sessions.items()}


def test_a_store_written_by_todays_code_opens_and_reads(tmp_path):
    import shutil

    from services.store import Store

    copy = tmp_path / "old.sqlite"
    shutil.copy(golden.HERE / "store-2026-12.sqlite", copy)
    store = Store(copy)
    try:
        (session,) = store.sessions()
        trials = [t for _, t in store.trials(session["session"])]
    finally:
        store.close()
    assert session["status"] == "complete" and [t.trial for t in trials] == [1, 2, 3]
    assert [t.outcome for t in trials] == ["D", "C", "C"]

