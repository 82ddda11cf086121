"""Command line of the harness: `harness <command> ...`.

Each sub-command lives in its own module under `harness/commands/` and exposes
``register(subparsers) -> None``; the parser it adds sets ``func`` (args -> int exit code).
Modules are discovered, so adding a command never touches this file.
"""

from __future__ import annotations

import argparse
import importlib
import math
import os
import pkgutil
import sys
from collections.abc import Callable

from harness import commands
from harness.record.output import OutputError, is_output_failure
from harness.record.recording import ABANDONED

MAX_RATE_HZ = 10_000.0
"""The fastest loop or SYNC rate any command accepts: a 1 Mbit/s CAN bus carries about
8000 frames a second, so a faster SYNC rate cannot be served (``harness probe`` hung at
absurd rates)."""

MAX_SECONDS = 30 * 24 * 3600.0
"""The longest duration (or time) any option takes: 30 days."""

MAX_COUNT = 100_000
"""The largest count (workers, grid points, starts, modes) an option takes."""


def _range_for(dest: str, kind: type) -> tuple[float, bool, float] | None:
    """(lowest, lowest allowed?, highest) of a numeric option, from its name's unit; None:
    any finite number (angles, amplitudes, seeds, ``--cpu -1``)."""
    if dest.endswith("_hz"):
        return 0.0, False, MAX_RATE_HZ
    if dest.endswith(("_s", "_ms", "_us")):
        scale = {"_s": 1.0, "_ms": 1e3, "_us": 1e6}["_" + dest.rsplit("_", 1)[1]]
        return 0.0, True, MAX_SECONDS * scale
    if dest.endswith(("_kg", "_m", "_kg_m2", "_n_m", "_m_s2")) or dest in ("target_ratio",):
        return 0.0, False, 1e9
    if dest == "serve_socketcand":  # 0: any free port (the rig process's own choice)
        return 0, True, 65535
    if kind is int and dest not in ("seed", "cpu"):
        return 0, True, MAX_COUNT
    return None


def _checked_number(option: str, dest: str, kind: type) -> Callable[[str], float | int]:
    """An argparse ``type``: a finite number of the option's kind within its range; the
    error (exit 2) names the option (argparse prefixes it) and what it expects."""
    bounds = _range_for(dest, kind)

    def parse(text: str) -> float | int:
        try:
            value = kind(text)
        except (TypeError, ValueError):
            raise argparse.ArgumentTypeError(
                f"expected {'an integer' if kind is int else 'a number'}, got {text!r}"
            ) from None
        if kind is float and not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
        if bounds is not None:
            low, low_ok, high = bounds
            if value < low or (value == low and not low_ok) or value > high:
                raise argparse.ArgumentTypeError(
                    f"expected {'>=' if low_ok else '>'} {low:g} and <= {high:g}, got {text!r}")
        elif kind is int and abs(value) > 2**31:
            raise argparse.ArgumentTypeError(f"expected an integer of at most 2^31, got {text!r}")
        return value

    parse.__name__ = kind.__name__  # argparse names the type in its own messages
    return parse


def check_numbers(parser: argparse.ArgumentParser) -> None:
    """Every ``type=float`` / ``type=int`` option of every command, checked finite and in
    range before the command runs (``--duration-s nan`` ran into a traceback, ``--rate-hz
    1e12`` hung ``harness probe``)."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                check_numbers(sub)
        elif action.type in (float, int):
            option = action.option_strings[-1] if action.option_strings else action.dest
            action.type = _checked_number(option, action.dest, action.type)


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
    check_numbers(parser)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # a refused option (exit 2, named) or --help: returned, so
        return int(exc.code or 0)  # in-process callers get the code as from any command
    if getattr(args, "func", None) is None:
        parser.print_help(sys.stderr)
        return 2
    ABANDONED.clear()
    try:
        code = _run(args)
        sys.stdout.flush()  # a closed pipe shows here, not in the interpreter's exit
    except BrokenPipeError:
        # the reader went away (`harness logs | head -1`): what it read is all it wanted
        _silence_stdout()
        return EXIT_BROKEN_PIPE
    if ABANDONED.is_set():
        # a Rerun sink stopped answering (a viewer gone, a dead disk): Rerun's own shutdown
        # at exit would wait for it forever; everything of ours is written and closed
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    return code


EXIT_BROKEN_PIPE = 141
"""The exit code when stdout's reader closed it: 128 + SIGPIPE, what a shell reports for a
program its pipe's reader left, never a traceback."""


def _silence_stdout() -> None:
    """Point stdout at /dev/null, so the interpreter's own flush at exit of what was still
    buffered finds no closed pipe (which it would report as an ignored BrokenPipeError)."""
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):  # not a file (an in-process caller's)
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, fd)
    finally:
        os.close(devnull)


def _run(args: argparse.Namespace) -> int:
    try:
        return int(args.func(args) or 0)
    except OSError as exc:
        if not is_output_failure(exc):
            raise
        # a full, read-only or failing disk: one line naming the file (or the command's
        # output folder when the error does not say), not a traceback
        where = exc.filename or getattr(args, "out", None) or "the output folder"
        print(f"harness: cannot write to {where}: {exc.strerror or exc}", file=sys.stderr)
        return 4
    except OutputError as exc:
        print(f"harness: {exc}", file=sys.stderr)
        return 4


if __name__ == "__main__":
    sys.exit(main())
