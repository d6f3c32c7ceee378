"""Every subcommand is on the command line; one whose module does not import says what is missing, in one line, and
exits 2, instead of vanishing from `babblegen --help`."""

from __future__ import annotations

import builtins
import sys

import pytest

from babblegen.cli import SUBCOMMANDS, build_parser, main

COMMANDS = [(module, name) for module, names in SUBCOMMANDS.items() for name in names]


def test_every_subcommand_is_listed_with_its_own_help():
    listed = build_parser().format_help()
    for _, name in COMMANDS:
        assert f"    {name} " in listed, listed
    assert "unavailable" not in listed, listed


@pytest.mark.parametrize(("module", "name"), COMMANDS)
def test_a_subcommand_whose_module_does_not_import_says_so_in_one_line(monkeypatch, capsys, module, name):
    monkeypatch.setitem(sys.modules, module, None)  # importing it raises ImportError
    listed = build_parser().format_help()
    assert f"    {name} " in listed and "unavailable: cannot import" in listed, listed
    for argv in ([name], [name, "--help"], [name, "--some-option", "value", "DIR"]):
        assert main(argv) == 2
        out, err = capsys.readouterr()
        assert not out
        assert err.startswith(f"babblegen: error: {name}: cannot import {module} (") and err.count("\n") == 1, err


def test_the_line_names_the_missing_dependency(monkeypatch, capsys):
    """A dependency missing below the subcommand's module (as when a package is not installed)."""
    monkeypatch.delitem(sys.modules, "babblegen.worldmodel.cli", raising=False)
    real_import = builtins.__import__

    def import_without_episodes(name, *args, **kwargs):
        if name == "babblegen.worldmodel.episodes":
            raise ModuleNotFoundError("No module named 'torch_geometric'", name="torch_geometric")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", import_without_episodes)
    assert main(["evaluate", "--train", "a=dir", "--test", "b=dir"]) == 2
    out, err = capsys.readouterr()
    assert not out
    assert err == (
        "babblegen: error: evaluate: cannot import babblegen.worldmodel.cli (No module named 'torch_geometric')\n"
    )


def test_other_commands_still_refuse_unknown_arguments(monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "babblegen.worldmodel.cli", None)
    with pytest.raises(SystemExit) as exit_:
        main(["generate", "--out", "x", "--no-such-flag"])
    assert exit_.value.code == 2
    assert "unrecognized arguments: --no-such-flag" in capsys.readouterr().err
