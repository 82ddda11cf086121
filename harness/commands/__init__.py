"""The sub-commands of ``harness``: one module a command, each with ``register(sub)``.

A command module parses arguments and calls a package; its top-level imports stay light
(argparse and the standard library: ``harness --help`` reads only its source, the command
chosen is imported) and it imports the package it calls inside its function. Nothing outside
this package and ``harness/cli.py`` imports it.
"""

from __future__ import annotations

import ast
from pathlib import Path

ParserLines = list[tuple[str, dict[str, str]]]
"""A module's parsers: (name, ``add_parser`` keywords other than the name: only ``help``)."""


def parsers_in(path: Path, function: str = "register") -> ParserLines | None:
    """The parsers a module's ``function(sub)`` adds with ``sub.add_parser("NAME",
    help="...")``, read from its source without importing it (so ``--help`` lists a command
    or a study without importing its numpy and scipy); [] for a module with no such
    function; None when they cannot be read so (a computed name or help, aliases, no
    ``add_parser`` call): the module is then imported."""
    try:
        tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    except (OSError, SyntaxError, ValueError):
        return None
    register = next((n for n in tree.body if isinstance(n, ast.FunctionDef)
                     and n.name == function), None)
    if register is None:
        return []
    if not register.args.args:
        return None
    sub = register.args.args[0].arg
    found: ParserLines = []
    for node in ast.walk(register):
        if not (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
                and node.func.attr == "add_parser" and isinstance(node.func.value, ast.Name)
                and node.func.value.id == sub):
            continue
        if not node.args or not isinstance(node.args[0], ast.Constant) \
                or not isinstance(node.args[0].value, str):
            return None
        keywords: dict[str, str] = {}
        for kw in node.keywords:
            if kw.arg is None or kw.arg == "aliases":
                return None
            if kw.arg == "help":
                if not (isinstance(kw.value, ast.Constant) and isinstance(kw.value.value, str)):
                    return None
                keywords["help"] = kw.value.value
        found.append((node.args[0].value, keywords))
    return found or None


def examples(*lines: str) -> str:
    """A parser's epilog: ``examples:`` and one command line a line, indented."""
    return "examples:\n" + "\n".join(f"  {line}" for line in lines)
