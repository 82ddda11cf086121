"""The sub-commands of ``harness``: one module a command, each with ``register(sub)``.

A command module parses arguments and calls a package; its top-level imports stay light
(argparse and the standard library: ``harness --help`` reads only its source, the command
chosen is imported) and it imports the package it calls inside its function. Nothing outside
this package and ``harness/cli.py`` imports it.
"""

from __future__ import annotations


def examples(*lines: str) -> str:
    """A parser's epilog: ``examples:`` and one command line a line, indented."""
    return "examples:\n" + "\n".join(f"  {line}" for line in lines)
