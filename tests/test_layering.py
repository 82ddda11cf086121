"""The packages' import rules (each package's ``__init__`` docstring states its own), checked
on every module's source: imports at the top and inside functions alike.

- nothing outside ``harness/commands/`` and ``harness/cli.py`` imports ``harness.commands``
  (a command parses arguments and calls a package; the tests may call a command);
- ``rig_models`` never imports ``harness``;
- the pure packages (``controllers``, ``shaping``, ``identification``, ``sequences``)
  import no other
  package of the harness but the ones their ``__init__`` names;
- ``harness.bus`` and ``harness.record`` never import ``harness.core``.
"""

from __future__ import annotations

import ast
from collections.abc import Callable
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SOURCES = ("harness", "rig_models", "drivers", "tools", "benchmarks")

PURE = {
    "controllers": ("harness.shaping", "harness.state", "rig_models"),
    "shaping": ("rig_models",),
    "identification": (),
    "sequences": ("harness.state", "rig_models"),
}
"""A pure package: the packages of this repository it may import (its ``__init__`` says)."""


def imported(path: Path) -> set[str]:
    """Every module a file imports (``from harness import x`` as ``harness.x``), at the top
    or inside a function."""
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.add(node.module)
            out |= {f"{node.module}.{a.name}" for a in node.names}
    return out


def modules(*folders: str) -> list[Path]:
    files = [f for d in folders for f in sorted((ROOT / d).rglob("*.py"))]
    assert files, folders
    return files


def under(name: str, package: str) -> bool:
    return name == package or name.startswith(package + ".")


def breaches(files: list[Path], forbidden: Callable[[str], bool]) -> list[str]:
    return [f"{f.relative_to(ROOT) if f.is_relative_to(ROOT) else f} imports {m}"
            for f in files for m in sorted(imported(f)) if forbidden(m)]


def test_only_the_command_line_imports_the_commands():
    files = [f for f in modules(*SOURCES)
             if f.relative_to(ROOT).parts[:2] != ("harness", "commands")
             and f.relative_to(ROOT) != Path("harness/cli.py")]
    bad = breaches(files, lambda m: under(m, "harness.commands"))
    assert not bad, "a command module is a command line, not a library (move the logic " \
        "into a package):\n" + "\n".join(bad)


def test_rig_models_never_imports_the_harness():
    bad = breaches(modules("rig_models"), lambda m: under(m, "harness"))
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize("package", sorted(PURE))
def test_a_pure_package_imports_only_what_its_init_allows(package):
    allowed = PURE[package]
    init = ast.get_docstring(ast.parse((ROOT / "harness" / package / "__init__.py").read_text()))
    assert init and "Pure" in init, f"harness/{package}/__init__.py: says it is pure"
    for name in allowed:
        assert f"``{name}``" in init, f"harness/{package}/__init__.py: does not name {name}"
    own = f"harness.{package}"

    def forbidden(m: str) -> bool:
        ours = under(m, "harness") or under(m, "rig_models") or under(m, "drivers")
        return ours and m != "harness" and not under(m, own) \
            and not any(under(m, a) for a in allowed)

    bad = breaches(modules(f"harness/{package}"), forbidden)
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize("package", ["bus", "record"])
def test_the_bus_and_the_recording_never_import_the_loop(package):
    bad = breaches(modules(f"harness/{package}"), lambda m: under(m, "harness.core"))
    assert not bad, "\n".join(bad)


def test_the_checks_see_a_forbidden_import(tmp_path):
    """Each rule's check finds a breach: a module importing what the rule forbids, lazily."""
    f = tmp_path / "m.py"
    f.write_text("def f():\n    from harness import commands\n    import harness.core.loop\n")
    assert imported(f) >= {"harness", "harness.commands", "harness.core.loop"}
    assert breaches([f], lambda m: under(m, "harness.commands"))
    assert breaches([f], lambda m: under(m, "harness.core"))
