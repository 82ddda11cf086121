"""Command line of the harness: `harness <command> ...`.

Each sub-command lives in its own module under `harness/commands/` and exposes
``register(subparsers) -> None``; the parser it adds sets ``func`` (args -> int exit code).
Modules are discovered, so adding a command never touches this file.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys

from harness import commands
from harness.record.output import OutputError, is_output_failure


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="harness",
        description="HIL test harness for the SGSRT flexible-spacecraft air-bearing rig.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        module = importlib.import_module(f"harness.commands.{info.name}")
        register = getattr(module, "register", None)
        if register is not None:
            register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if getattr(args, "func", None) is None:
        parser.print_help(sys.stderr)
        return 2
    try:
        return int(args.func(args) or 0)
    except OSError as exc:
        if not is_output_failure(exc):
            raise
        # a full, read-only or failing disk: one line naming the file, not a traceback
        print(f"harness: cannot write {exc.filename or ''}: {exc.strerror}", file=sys.stderr)
        return 4
    except OutputError as exc:
        print(f"harness: {exc}", file=sys.stderr)
        return 4


if __name__ == "__main__":
    sys.exit(main())
