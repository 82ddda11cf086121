"""The command line starts cheaply: only the command chosen is imported; the others are
listed by the help line read from their source. A command module dropped into
``harness/commands/`` is found without touching ``harness/cli.py``. Every command and option
has help text and every command's ``--help`` an example."""

from __future__ import annotations

import argparse
import json
import re
import shlex
import subprocess
import sys
import textwrap

import pytest

from harness import commands
from harness.cli import build_parser, command_index, main

HEAVY = ("numpy", "scipy", "can", "cantools", "canopen", "rerun", "matplotlib", "yaml")


def loaded_after(args: list[str]) -> list[str]:
    """The heavy packages a fresh ``harness ARGS`` process has imported when it ends."""
    code = ("import sys, json, contextlib, io\n"
            "from harness.cli import main\n"
            "with contextlib.redirect_stdout(io.StringIO()):\n"
            f"    main({args!r})\n"
            f"print(json.dumps(sorted(m for m in {HEAVY!r} if m in sys.modules)))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def test_help_and_cases_import_nothing_heavy():
    assert loaded_after(["--help"]) == []
    assert loaded_after(["cases"]) == ["yaml"]  # the run files' descriptions, nothing else


@pytest.mark.parametrize("command", ["history", "rt-check", "study"])
def test_help_of_commands_with_heavy_work_imports_no_numpy(command):
    """Their work needs numpy, scipy or the loop; their ``--help`` needs none of it."""
    assert not {"numpy", "scipy", "can"} & set(loaded_after([command, "--help"]))


def test_study_help_lists_every_study_as_importing_them_does():
    """``harness study --help`` read from the studies' source equals the one built by
    importing every study, and a chosen study's own options are there."""
    def study_help(argv: list[str] | None) -> str:
        action = next(a for a in build_parser(argv)._actions
                      if isinstance(a, argparse._SubParsersAction))
        return action.choices["study"].format_help()

    assert study_help(["study", "--help"]) == study_help(None)
    chosen = build_parser(["study", "wang2022", "--help"])
    study = next(a for a in chosen._actions if isinstance(a, argparse._SubParsersAction))
    inner = next(a for a in study.choices["study"]._actions
                 if isinstance(a, argparse._SubParsersAction))
    assert "--json" in inner.choices["wang2022"].format_help()


def test_the_listing_read_from_source_is_the_one_the_modules_register():
    """``harness --help`` built from the modules' source equals the one built by importing
    every command (and every module's commands were read from source, none imported)."""
    assert all(lines for _, lines in command_index())
    assert build_parser([]).format_help() == build_parser().format_help()


def test_a_command_module_dropped_in_is_found_and_imported_only_when_chosen(tmp_path,
                                                                            monkeypatch,
                                                                            capsys):
    (tmp_path / "hello_probe.py").write_text(textwrap.dedent('''
        import argparse

        IMPORTED = []
        IMPORTED.append(1)


        def register(sub: argparse._SubParsersAction) -> None:
            p = sub.add_parser("hello-probe", help="say hello", description="Says hello.")
            p.add_argument("--times", type=int, default=1, help="how often")
            p.set_defaults(func=lambda args: print("hello " * args.times) or 0)
    '''))
    monkeypatch.setattr(commands, "__path__", [*commands.__path__, str(tmp_path)])
    monkeypatch.delitem(sys.modules, "harness.commands.hello_probe", raising=False)
    assert main(["--help"]) == 0
    assert re.search(r"hello-probe\s+say hello", capsys.readouterr().out)
    assert "harness.commands.hello_probe" not in sys.modules
    assert main(["hello-probe", "--times", "2"]) == 0
    assert capsys.readouterr().out.strip() == "hello hello"
    assert "harness.commands.hello_probe" in sys.modules
    # its numeric options are checked like every command's
    assert main(["hello-probe", "--times", "-3"]) == 2
    assert "--times: expected >= 0" in capsys.readouterr().err
    sys.modules.pop("harness.commands.hello_probe", None)


def test_a_module_whose_help_is_computed_is_imported_to_register(tmp_path, monkeypatch,
                                                                 capsys):
    (tmp_path / "computed_help.py").write_text(textwrap.dedent('''
        import argparse

        WORD = "computed"


        def register(sub: argparse._SubParsersAction) -> None:
            sub.add_parser("computed", help=f"a {WORD} help line")
    '''))
    monkeypatch.setattr(commands, "__path__", [*commands.__path__, str(tmp_path)])
    assert main(["--help"]) == 0
    assert "a computed help line" in capsys.readouterr().out
    sys.modules.pop("harness.commands.computed_help", None)


def test_numbers_are_checked_on_the_chosen_command(capsys):
    assert main(["probe", "--rate-hz", "nan"]) == 2
    assert "--rate-hz: expected a finite number" in capsys.readouterr().err
    assert main(["sweep", "--n-lambda", "1e3"]) == 2
    assert "--n-lambda: expected an integer, got '1e3'" in capsys.readouterr().err


def _parsers(parser: argparse.ArgumentParser):
    yield parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                yield from _parsers(sub)


PARSERS = list(_parsers(build_parser()))


@pytest.mark.parametrize("parser", PARSERS, ids=[p.prog for p in PARSERS])
def test_every_command_and_option_says_what_it_is(parser):
    assert parser.description, f"{parser.prog}: no description"
    for action in parser._actions:
        if not isinstance(action, argparse._SubParsersAction):
            assert action.help, f"{parser.prog} {'/'.join(action.option_strings) or action.dest}"


@pytest.mark.parametrize("name", sorted(
    next(a for a in PARSERS[0]._actions if isinstance(a, argparse._SubParsersAction)).choices))
def test_every_command_help_shows_an_example(name, capsys):
    assert main([name, "--help"]) == 0
    text = capsys.readouterr().out
    after_usage = text.split("\n\n", 1)[1]
    # an example: a command line of its own, indented (an epilog's, or the description's)
    assert re.search(rf"^\s+(\$ )?harness {re.escape(name)}\b", after_usage, re.M), \
        f"harness {name} --help: no example"


def test_every_example_parses():
    """Each example of every ``--help`` is a command line the parser accepts (it does not
    run it: the examples name run directories of their own)."""
    parser = build_parser()
    seen = 0
    for p in PARSERS:
        text = p.format_help()
        if "examples:\n" not in text:
            continue
        for line in text.split("examples:\n", 1)[1].splitlines():
            argv = shlex.split(line)
            if not argv or argv[0] != "harness" or "COMMAND" in argv or "--help" in argv:
                continue
            parser.parse_args(argv[1:])  # a bad example exits 2: the test fails
            seen += 1
    assert seen >= 30
