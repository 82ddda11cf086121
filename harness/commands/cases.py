"""`harness cases`: list the built-in runs."""

from __future__ import annotations

import argparse

from harness.core.runs import list_runs


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("cases", help="list the built-in runs")
    p.set_defaults(func=cmd_cases)


def cmd_cases(args: argparse.Namespace) -> int:
    runs = list_runs()
    width = max(len(n) for n, _ in runs)
    for name, desc in runs:
        print(f"{name:<{width}}  {desc}")
    return 0
