"""`harness cases`: list the built-in runs.

One line a run file of ``harness/runs/``: its name (what ``harness run NAME`` and a suite's
``run:`` take) and its description. A run file of your own is run by its path instead.
"""

from __future__ import annotations

import argparse

from harness.commands import examples


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("cases", help="list the built-in runs", description=__doc__,
                       formatter_class=argparse.RawDescriptionHelpFormatter,
                       epilog=examples("harness cases", "harness run slew-rw-zv"))
    p.set_defaults(func=cmd_cases)


def cmd_cases(args: argparse.Namespace) -> int:
    from harness.core.builtin_runs import list_runs  # PyYAML only when listing

    runs = list_runs()
    width = max(len(n) for n, _ in runs)
    for name, desc in runs:
        print(f"{name:<{width}}  {desc}")
    return 0
