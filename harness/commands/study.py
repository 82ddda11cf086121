"""`harness study NAME`: reproduce a paper's study on its own reference model.

Every module in `harness/studies/` that defines ``register_study(subparsers)`` adds one
study; its parser sets ``func`` (args -> int exit code).
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil

from harness import studies
from harness.commands import examples


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser(
        "study",
        help="reproduce a paper's study on its reference model, beside the paper's table",
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=examples("harness study xu2018 --only model", "harness study wang2022 --json"),
    )
    study_sub = parser.add_subparsers(dest="study", metavar="STUDY")
    for info in sorted(pkgutil.iter_modules(studies.__path__), key=lambda m: m.name):
        module = importlib.import_module(f"harness.studies.{info.name}")
        hook = getattr(module, "register_study", None)
        if hook is not None:
            hook(study_sub)
    parser.set_defaults(func=lambda args: (parser.print_help(), 2)[1])
