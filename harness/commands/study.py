"""`harness study NAME`: reproduce a paper's study on its own reference model.

Every module in `harness/studies/` that defines ``register_study(subparsers)`` adds one
study; its parser sets ``func`` (args -> int exit code). Only the study chosen is imported;
the others are listed by the name and help their ``register_study`` passes to
``add_parser``, read from their source (each study imports numpy, scipy and its model).
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
from collections.abc import Sequence
from pathlib import Path

from harness import studies
from harness.commands import examples, parsers_in


def register(sub: argparse._SubParsersAction, argv: Sequence[str] | None = None) -> None:
    """``argv``: the command line being parsed; only the study it names is imported (all
    of them without it: the CLI reference, tests walking every option)."""
    parser = sub.add_parser(
        "study",
        help="reproduce a paper's study on its reference model, beside the paper's table",
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=examples("harness study xu2018 --only model", "harness study wang2022 --json"),
    )
    study_sub = parser.add_subparsers(dest="study", metavar="STUDY")
    words = [a for a in argv or () if not a.startswith("-")]
    for info in sorted(pkgutil.iter_modules(studies.__path__), key=lambda m: m.name):
        folder = getattr(info.module_finder, "path", None)
        lines = None if argv is None or folder is None or info.ispkg \
            else parsers_in(Path(folder) / f"{info.name}.py", "register_study")
        if lines is not None and not any(name in words for name, _ in lines):
            for name, keywords in lines:  # not chosen: listed by its help line only
                study_sub.add_parser(name, **keywords)
            continue
        module = importlib.import_module(f"harness.studies.{info.name}")
        hook = getattr(module, "register_study", None)
        if hook is not None:
            hook(study_sub)
    parser.set_defaults(func=lambda args: (parser.print_help(), 2)[1])
