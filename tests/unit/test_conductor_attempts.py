"""A resumed session's attempts: the starts a trial had before the crash count against
`max_attempts` (services/experiment/conductor.py `_attempts_so_far`, docs/safety.md §2).

The conductor is built without a fabric: only what the resume rule touches (the store, the
protocol, a clock) is real or stubbed. One conductor for any option set: every test runs with
the paper's two options and with a table of three (`services.experiment.keyspace`).
"""

from __future__ import annotations

import threading
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import pytest

from services.experiment.conductor import Conductor
from services.experiment.keyspace import KeySpace, key_space
from services.model.params import NodConfig
from services.model.schedule import OptionsSchedule
from services.store import Interruption, Store

MAX = 3


@pytest.fixture(params=[2, 3], ids=["two options", "three options"])
def keys(request) -> KeySpace:
    n = request.param
    return key_space(NodConfig(), None if n == 2 else OptionsSchedule.default(n))


def conductor(
    store: Store, keys: KeySpace, max_attempts: int = MAX, repeat: bool = True
) -> Conductor:
    cfg = keys.cfg
    proto = replace(cfg.protocol, trials=keys.trials, max_attempts=max_attempts,
                    repeat_interrupted=repeat)
    c = Conductor.__new__(Conductor)  # no node: the resume rule needs none of the fabric
    c.cfg, c.proto, c.store, c.session, c.records = cfg, proto, store, "s1", []
    c.keys, c.policy = keys, None
    c.node = SimpleNamespace(lock=threading.Lock(), clock=SimpleNamespace(now_ns=lambda: 9))
    c.rig = SimpleNamespace(take_events=lambda: [])
    c.cues = SimpleNamespace(take=lambda: [])
    c.console = SimpleNamespace(result=lambda *a: None)
    c.pub_result = SimpleNamespace(put=lambda **k: None)
    return c


@pytest.fixture
def store(tmp_path: Path, keys: KeySpace):
    s = Store(tmp_path / "s.db")
    s.begin_session("s1", "P01", "sim", 1, 0, keys.summary(), keys.names)
    yield s
    s.close()


def broken(store: Store, trial: int, attempts: int) -> None:
    """`attempts` starts of `trial` interrupted and stored before the crash."""
    for a in range(1, attempts + 1):
        store.write_interruption("s1", Interruption(trial, a, a, a + 1, "eyes: gaze stale"))


@pytest.mark.parametrize("before", range(MAX))
def test_a_trial_with_starts_left_goes_on_from_the_starts_it_had(store, keys, before):
    broken(store, 3, before)
    assert conductor(store, keys)._attempts_so_far(3, None) == (3, before)
    assert store.trials("s1") == []


def test_a_trial_out_of_attempts_before_the_crash_is_stored_interrupted_not_retried(store, keys):
    broken(store, 3, MAX)
    c = conductor(store, keys)
    assert c._attempts_so_far(3, None) == (4, 0)  # trial 4 starts fresh
    [(_, rec)] = store.trials("s1")
    assert (rec.trial, rec.interrupted, rec.attempts, rec.outcome, rec.score) == (
        3, True, MAX, None, 0)


@pytest.mark.parametrize("stored, lost, expected", [
    (0, 1, (3, 1)),  # the dead conductor's first start: two left
    (MAX - 2, MAX - 1, (3, MAX - 1)),  # one left
    (MAX - 1, MAX, (4, 0)),  # the lost start was the last one
])
def test_the_start_a_dead_conductor_left_open_counts_too(store, keys, stored, lost, expected):
    broken(store, 3, stored)
    c = conductor(store, keys)
    assert c._attempts_so_far(3, (3, lost, 100)) == expected
    assert store.attempts_made("s1", 3) == lost  # filed as the interruption it was
    interrupted = [t for _, t in store.trials("s1") if t.interrupted]
    assert [(t.trial, t.attempts) for t in interrupted] == ([(3, MAX)] if lost == MAX else [])


def test_over_a_crash_a_trial_is_started_at_most_max_attempts_times(store, keys):
    # Whatever the split of starts before the crash, the resumed protocol's starts of the trial
    # and those before add up to max_attempts, never one more.
    from services.model.protocol import SessionProtocol

    for before in range(MAX + 1):
        c = conductor(store, keys)
        c.session = f"s{before + 10}"
        store.begin_session(c.session, "P01", "sim", 1, 0, keys.summary(), keys.names)
        for a in range(1, before + 1):
            store.write_interruption(c.session, Interruption(2, a, a, a + 1, "e-stop"))
        first, made = c._attempts_so_far(2, None)
        starts = before
        if first == 2:
            protocol = SessionProtocol(c.proto, first, made)
            protocol.start(0.0)
            while protocol.trial is not None and protocol.trial.index == 2:
                starts += 1
                protocol.interrupt(1.0, "e-stop")
                protocol.resume(2.0)
        assert starts == MAX, before


def test_without_repeats_a_trial_interrupted_once_is_not_started_again(store, keys):
    broken(store, 3, 1)
    assert conductor(store, keys, repeat=False)._attempts_so_far(3, None) == (4, 0)
