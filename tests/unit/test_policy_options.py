"""A robot policy runs on the paper's two options only: refused in one line at three, before
anything is written or any table is built (`nod experiment --policy`, `nod run --policy`)."""

from __future__ import annotations

from pathlib import Path

import pytest

from services.experiment import service as experiment
from services.store import Store


def test_nod_experiment_refuses_a_policy_at_three_options(tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]
                                                          ) -> None:
    db = tmp_path / "s.sqlite"
    code = experiment.main(["--options", "3", "--policy", "paper", "--db", str(db),
                            "--connect", "tcp/127.0.0.1:9", "--clicks", "none"])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1 and "two-option table only" in err, err
    with Store(db) as store:  # nothing written
        assert store.sessions() == []
