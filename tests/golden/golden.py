"""The golden of the paper's study: what the two-option pipeline computes today, kept as data.

Captured before the N-option rig is folded into one pipeline (issue 34): every step of that
change merges only while this is equal. Four parts, each from the code as it runs:

- `cohort`: the deterministic offline sessions of a seeded cohort (`nod cohort`'s person and
  loop: `services.sim.cohort.simulate`), per trial every stored field, and a SHA-256 of the
  trial's samples written as text with every float at full precision (byte for byte).
- `study`: `nod analyze study --json` on those sessions stored as `nod cohort` stores them.
- `thresholds`: `nod analyze thresholds --json`.
- `replay`: `nod replay session.mcap --through decision` — the decision engine re-run over a
  recorded pose stream (a 3-trial simulated session recorded by `nod run --sim --record`):
  per trial the recomputed z_r, ẑ_h and b_r at its last pose, and a SHA-256 of every
  recomputed value in order.

Beside them, `store-2026-12.sqlite`: the store that same recorded session wrote (schema of
today's code), for the migration a one-pipeline store will need (stores made before it must
still open); `session.mcap` is its recording (schema 1 messages), which must still replay.

`python -m tests.golden.golden --write` captures them into tests/golden/*.json (only when the
change of a number is intended, said in the commit); `tests/unit/test_golden.py` compares.
The analysis JSON may gain keys (a new note, a caveat): what the golden holds must be equal.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import io
import json
import sys
import tempfile
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
SEEDS = range(1, 13)  # 12 participants of `nod cohort`'s person
FILES = ("cohort", "study", "thresholds", "replay")


def _floats(values: Any) -> str:
    """Values as text, floats at full precision (repr), for a digest."""
    return json.dumps(values, default=repr, allow_nan=True)


def cohort_sessions(db: Path | None = None) -> dict[str, Any]:
    """The golden cohort: per seed, per trial, every field; stored into `db` if given."""
    from services.cohort.person import load_cohort_params
    from services.sim.cohort import Job, simulate, store_session
    from services.store import Store

    cfg = load_cohort_params(None)
    out: dict[str, Any] = {}
    store = Store(db) if db is not None else None
    try:
        for i, seed in enumerate(SEEDS):
            job = Job(i, seed, cfg, True)
            trials = simulate(job)
            if store is not None:
                store_session(store, job, trials, "cohort")
            out[str(seed)] = [
                {
                    "trial": t.trial, "mode": t.mode, "option": t.option, "human": t.human,
                    "robot": t.robot, "outcome": t.outcome, "switches": t.switches,
                    "violations": t.violations, "score": t.score,
                    "duration_s": repr(t.duration_s),
                    "samples": len(t.samples),
                    "samples_sha256": hashlib.sha256(
                        _floats([list(s) for s in t.samples]).encode()).hexdigest(),
                }
                for t in trials
            ]
    finally:
        if store is not None:
            store.close()
    return out


def _nod_json(module: Any, argv: list[str]) -> Any:
    """A `nod` command's --json output, run in-process."""
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        code = module.main(argv)
    if code != 0:
        raise RuntimeError(f"{argv} exited {code}")
    return json.loads(buf.getvalue())


def study_analysis(db: Path) -> Any:
    """`nod analyze study --json` on the golden cohort's store (its path, a temp file, left out)."""
    from services.analysis import cli

    out = _nod_json(cli, ["study", "--db", str(db), "--json"])
    out.pop("stores", None)
    return out


def thresholds() -> Any:
    """`nod analyze thresholds --json`."""
    from services.analysis import cli

    return _nod_json(cli, ["thresholds", "--json"])


def replay_decision(out: Path) -> dict[str, Any]:
    """The decision engine over the recorded pose stream (`nod replay --through decision`)."""
    from services.core import messages as m
    from services.core.keys import topic_of
    from services.recording.mcap_io import McapIn
    from services.recording.through import DECISION_TOPICS, through_decision

    res = through_decision(HERE / "session.mcap", out, None)
    values: list[tuple[str, int, Any]] = []
    for entry in McapIn(out):
        topic = topic_of(entry.key)
        if topic in DECISION_TOPICS:
            msg = m.decode(_message_type(topic), entry.payload)
            values.append((topic, msg.src_seq, repr(msg.signed)))  # schema 3: (z, -z)
    return {
        "poses": res.poses, "recomputed": res.recomputed, "left_out": res.left_out,
        "trials": [
            {"trial": t.trial, "mode": t.mode, "final": [None if v is None else list(map(repr, v))
                                                         for v in t.final()]}
            for t in res.trials
        ],
        "values": len(values),
        "values_sha256": hashlib.sha256(json.dumps(values).encode()).hexdigest(),
    }


def _message_type(topic: str) -> Any:
    from services.core.contract import TOPICS

    return TOPICS[topic].message


def capture() -> dict[str, Any]:
    """Every part of the golden, computed now."""
    with tempfile.TemporaryDirectory() as tmp:
        db = Path(tmp) / "cohort.sqlite"
        return {
            "cohort": cohort_sessions(db),
            "study": study_analysis(db),
            "thresholds": thresholds(),
            "replay": replay_decision(Path(tmp) / "through.mcap"),
        }


def held_in(golden: Any, now: Any, where: str = "") -> list[str]:
    """Where `now` differs from `golden` (keys `now` has beyond the golden's are allowed)."""
    if isinstance(golden, dict):
        if not isinstance(now, dict):
            return [f"{where or '/'}: a {type(now).__name__}, was a dict"]
        out = []
        for k, v in golden.items():
            if k not in now:
                out.append(f"{where}/{k}: missing")
            else:
                out += held_in(v, now[k], f"{where}/{k}")
        return out
    if isinstance(golden, list):
        if not isinstance(now, list) or len(now) != len(golden):
            return [f"{where}: {now!r:.200} was {golden!r:.200}"]
        return [d for i, (g, n) in enumerate(zip(golden, now, strict=True))
                for d in held_in(g, n, f"{where}[{i}]")]
    return [] if golden == now else [f"{where}: {now!r:.200} was {golden!r:.200}"]


def main(argv: list[str] | None = None) -> int:
    """Write the golden (`--write`), or compare with it."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--write", action="store_true", help="capture into tests/golden/*.json")
    args = p.parse_args(argv)
    now = json.loads(json.dumps(capture()))  # as it would be read back
    if args.write:
        for name in FILES:
            (HERE / f"{name}.json").write_text(json.dumps(now[name], indent=1, sort_keys=True)
                                               + "\n")
        print(f"golden written: {', '.join(f'{n}.json' for n in FILES)}")
        return 0
    diffs = [d for name in FILES
             for d in held_in(json.loads((HERE / f"{name}.json").read_text()), now[name], name)]
    print("\n".join(diffs[:40]) or "golden equal")
    return 1 if diffs else 0


if __name__ == "__main__":
    sys.exit(main())
