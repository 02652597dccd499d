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
