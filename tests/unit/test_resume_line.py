"""The resume line: the command that goes on with a stopped session, with the flags it needs."""

from __future__ import annotations

import shlex
from pathlib import Path

from services.experiment.resume import resume_argv, resume_line, resume_problem
from services.experiment.service import build_parser
from services.model.geometry import COLOURS
from services.run import RESUME_FLAGS
from services.run import build_parser as run_parser
from services.store import Store


def test_nod_experiment_resumes_with_the_flags_that_reach_the_rig_and_store() -> None:
    p = build_parser()
    args = p.parse_args([
        "--connect", "tcp/10.0.0.1:7447", "--connect", "tcp/10.0.0.2:7447", "--rig", "rigB",
        "--db", "my sessions.sqlite", "--participant", "P07", "--seed", "3", "--order", "BRRBR",
        "--params", "study.toml", "--clicks", "none", "--record", "rec",
    ])
    line = resume_line(resume_argv(p, args, "abc123"))
    assert line.startswith("resume with: nod experiment --resume abc123 --db 'my sessions.sqlite'")
    argv = shlex.split(line.removeprefix("resume with: "))
    assert argv[argv.index("--rig") + 1] == "rigB" and argv.count("--connect") == 2
    assert argv[argv.index("--params"):][:2] == ["--params", "study.toml"]
    assert argv[argv.index("--clicks"):][:2] == ["--clicks", "none"] and "--record" in argv
    # A session keeps its own participant, seed and order; defaults are left out.
    assert not {"--participant", "--seed", "--order", "--mode", "--speed"} & set(argv)
    assert p.parse_args(argv[2:]).resume == "abc123"  # it parses back


def test_nod_run_resumes_with_its_own_form() -> None:
    p = run_parser()
    args = p.parse_args(["--sim", "--speed", "4", "--render", "--db", "s.sqlite",
                         "--monitor=--spawn", "--arm-driver", "feetech", "--arm-port", "/dev/x"])
    argv = resume_argv(p, args, "s1", ("nod", "run", "--sim"), RESUME_FLAGS)
    assert argv[:7] == ["nod", "run", "--sim", "--resume", "s1", "--db", "s.sqlite"]
    assert "--render" in argv and argv[argv.index("--speed"):][:2] == ["--speed", "4.0"]
    assert argv[-4:] == ["--arm-driver", "feetech", "--arm-port", "/dev/x"]
    args = p.parse_args(argv[2:])
    assert (args.resume, args.speed, args.render) == ("s1", 4.0, True)


def test_a_table_of_n_options_is_resumed_with_its_option_count() -> None:
    for prog, parser, flags in (
        (("nod", "experiment"), build_parser(), None),
        (("nod", "run", "--sim"), run_parser(), RESUME_FLAGS),
    ):
        args = parser.parse_args([*prog[2:], "--options", "3", "--db", "s.sqlite"])
        argv = resume_argv(parser, args, "s1", prog, *([flags] if flags else []))
        assert argv[argv.index("--options") + 1] == "3", argv


def test_a_session_is_resumed_only_with_its_own_option_set(tmp_path: Path) -> None:
    store = Store(tmp_path / "s.sqlite")
    try:
        store.begin_session("s3", "P01", "rig1", 1, 0, {}, ("red", "blue", "green"))
        store.begin_session("s2", "P02", "rig1", 2, 1, {})
        assert resume_problem(store, "s3", "rig1", ("red", "blue", "green")) is None
        assert resume_problem(store, "s2", "rig1", COLOURS) is None
        problem = resume_problem(store, "s3", "rig1", COLOURS)
        assert problem is not None and "--options 3" in problem and "\n" not in problem
        problem = resume_problem(store, "s2", "rig1", ("red", "blue", "green"))
        assert problem is not None and "['red', 'blue']" in problem
    finally:
        store.close()
