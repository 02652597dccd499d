"""Every `nod` command exists, imports, and answers --help."""

import importlib

import pytest

from services.cli import COMMANDS, main


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_every_command_answers_help(name, capsys):
    module = importlib.import_module(COMMANDS[name][0])
    assert callable(module.main)
    with pytest.raises(SystemExit) as exc:
        main([name, "--help"])
    assert exc.value.code == 0
    assert "usage" in capsys.readouterr().out.lower()


def test_unknown_command_is_exit_2(capsys):
    assert main(["no-such-command"]) == 2
    assert "unknown command" in capsys.readouterr().err


def test_a_failure_is_one_line_on_stderr_and_exit_2(capsys):
    from services.core.cli import fail, one_line

    err = ValueError("no router at\n  tcp/127.0.0.1:7447 at io/zenoh-link/src/lib.rs:42.")
    assert fail("nod x", err) == 2
    assert capsys.readouterr().err == "nod x: no router at tcp/127.0.0.1:7447\n"
    assert one_line("a " * 400) == ("a " * 150)[:300] + "…"
    assert fail("nod x", "b" * 400) == 2 and capsys.readouterr().err == f"nod x: {'b' * 400}\n"


def test_every_integer_flag_is_checked_in_one_line():
    import argparse

    from services.core.cli import PORT, SEED, int_in

    assert int_in(1)("7") == 7 and PORT("65535") == 65535 and SEED("0") == 0
    for parse, text, why in (
        (int_in(1), "0", "must be >= 1, got 0"),
        (int_in(0, 255), "256", "must be in [0, 255], got 256"),
        (PORT, "-1", "in [1, 65535]"),
        (SEED, "2.5", "whole number"),
        (SEED, str(2**63), "in [0, 9223372036854775807]"),
    ):
        try:
            parse(text)
        except argparse.ArgumentTypeError as exc:
            assert why in str(exc), exc
        else:
            raise AssertionError(f"{text!r} accepted")


@pytest.mark.parametrize(("command", "finalised"), [("decision", False), ("experiment", False),
                                                    ("report", True), ("experiment next", True)])
def test_a_service_process_ends_without_finalisation_a_tool_with_it(command, finalised):
    """`entry`: a service's code stands, its process skips the interpreter's finalisation (where
    a Zenoh callback thread could abort it); a tool, or a service's verb, ends as usual."""
    import subprocess
    import sys

    script = (
        "import atexit, sys, services.cli as cli\n"
        "atexit.register(lambda: print('finalised', flush=True))\n"
        "cli.main = lambda argv: print('ran', argv, flush=True) or 3\n"
        f"sys.argv = ['nod', *{command.split()!r}]\n"
        "raise SystemExit(cli.entry())\n"
    )
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                         timeout=60)
    assert run.returncode == 3, run.stderr
    assert "ran" in run.stdout and ("finalised" in run.stdout) == finalised, run.stdout
