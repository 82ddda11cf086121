"""The built-in run files (``harness/runs/*.yaml``): where they are and their names with
their descriptions (``harness cases``). Light on purpose (PyYAML only): listing them does not
load the loop, the controllers or the rig model (``harness.core.runs`` parses a run)."""

from __future__ import annotations

from pathlib import Path

import yaml

RUNS_DIR = Path(__file__).parent.parent / "runs"

# libyaml's loader where PyYAML has it (about ten times faster on the seventeen files): the
# same documents as PyYAML's own safe loader
_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def list_runs() -> list[tuple[str, str]]:
    """(name, description) of every built-in run, by name."""
    out = []
    for path in sorted(RUNS_DIR.glob("*.yaml")):
        raw = yaml.load(path.read_text(), Loader=_LOADER) or {}  # noqa: S506 - a safe loader
        out.append((path.stem, str(raw.get("description", ""))))
    return out


def run_path(name_or_path: str) -> Path:
    """A run file's path: a YAML path (or any existing file) as it is, else the built-in run
    of that name."""
    p = Path(name_or_path)
    if p.suffix in (".yaml", ".yml") or p.exists():
        return p
    return RUNS_DIR / f"{name_or_path}.yaml"
