"""``harness commission --write-rig FILE``: the rig file under test with what commissioning
measured of its model, for the lab to review.

The file written ``extends:`` the rig file under test (a built-in name, or its absolute
path) and gives only the measured model keys, each with its 1-sigma, the file's value, the
verdict and the date in a comment: a short file a lab reads line by line, its devices,
limits and tolerances still the reviewed file's. A measured value is written when the rig
differs from its file (DIFFERS) or when it is known at least twice as well as the file's
tolerance claims (``model.WRITE_SIGMA_FRACTION``); the header lists the others and why.

Where it may go (``check_target``, before anything moves): a ``.yaml`` / ``.yml`` name
that is one safe path component (``harness.core.paths.safe_name``) in a folder that
exists, never the rig file under test nor the built-in rigs' folder, never over a file
this command did not write; written atomically (``write_text_atomic``), never through a
link left in its place (``fresh_output_path``).
"""

from __future__ import annotations

import datetime as dt
import math
from pathlib import Path
from typing import Any

from harness.commissioning.model import _file_value, written
from harness.core.paths import safe_child, safe_name
from harness.record.output import fresh_output_path, write_text_atomic
from rig_models.rig_file import RIGS_DIR, load_rig, rig_path
from rig_models.schema import ConfigError

HEADER = "# Written by harness commission"

SECTIONS = ("hub", "beam", "reaction_wheel", "hub_sensor", "accelerometer", "thruster_valves")


def check_target(path: Path, rig: Any, rig_ref: str | None = None) -> Path:
    """``path`` checked as the place for the measured rig file (module docstring); the
    path to write. Raises ConfigError (exit 2, nothing sent)."""
    path = Path(path)
    if path.suffix not in (".yaml", ".yml"):
        raise ConfigError(f"--write-rig {path}: a rig file's name ends in .yaml or .yml")
    if safe_name(path.name) != path.name:
        raise ConfigError(f"--write-rig {path}: the name {path.name!r} is not a safe file "
                          f"name (letters, digits, - _ + .); e.g. {safe_name(path.name)!r}")
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise ConfigError(f"--write-rig {path}: the folder {folder} does not exist")
    target = safe_child(folder, path.name)
    resolved = target.resolve()
    if resolved.parent == RIGS_DIR.resolve():
        raise ConfigError(f"--write-rig {path}: not into the built-in rigs' folder "
                          f"{RIGS_DIR}: write it beside your rig file")
    under_test = rig_path(rig_ref) if rig_ref else None
    if under_test is not None and under_test.exists() and under_test.resolve() == resolved:
        raise ConfigError(f"--write-rig {path}: that is the rig file under test; write the "
                          "measured file beside it and review the difference")
    if target.is_symlink() or (target.exists() and not _ours(target)):
        raise ConfigError(f"--write-rig {path}: the file exists and was not written by "
                          "harness commission; choose another name")
    return target


def _ours(path: Path) -> bool:
    try:
        with open(path, encoding="utf-8") as f:
            return f.readline().startswith(HEADER)
    except (OSError, UnicodeDecodeError):
        return False


def _num(value: float, sigma: float | None) -> str:
    """``value`` with digits down to a tenth of its sigma (at least 4 significant)."""
    if value == 0 or not math.isfinite(value):
        return "0.0" if value == 0 else repr(value)
    digits = 4
    if sigma and sigma > 0 and math.isfinite(sigma):
        digits = max(digits, int(math.ceil(math.log10(abs(value) / (0.1 * sigma)))) + 1)
    text = f"{value:.{min(digits, 12)}g}"
    return text if any(ch in text for ch in ".e") else text + ".0"


def _extends(c: Any) -> str:
    ref = c.options.rig
    p = Path(ref)
    if p.suffix not in (".yaml", ".yml") and not p.exists() and (RIGS_DIR / f"{ref}.yaml").exists():
        return str(ref)
    return str(rig_path(ref).resolve())


def render(c: Any, when: dt.datetime, target: Path) -> str:
    rig = c.plan.rig
    day = when.strftime("%Y-%m-%d")
    rows = [r for r in c.measured() if r.value is not None]
    take = {r.key: r for r in rows if written(r, rig)}
    left = [r for r in rows if r.key not in take]
    by_section: dict[str, list[str]] = {s: [] for s in SECTIONS}

    def note(r: Any) -> str:
        return (f"measured {_num(r.value, r.sigma)} +- {r.sigma:.2g} (1 sigma) on {day}, "
                f"{r.verdict}; the file's {r.expected:.5g}")

    lists: dict[str, list[tuple[int, Any]]] = {}
    for key, r in take.items():
        base = key.split("[")[0]
        if "[" in key:
            lists.setdefault(base, []).append((int(key.split("[")[1].rstrip("]")), r))
            continue
        section, name = base.split(".", 1)
        value = r.value
        extra = ""
        if name.startswith("friction_") and value < 0:
            extra = f" (written as 0: friction is not negative, measured {value:.3g})"
            value = 0.0
        by_section[section].append(f"  {name}: {_num(value, r.sigma)}  # {note(r)}{extra}")
        if name == "friction_coulomb_n_m":
            breakaway = rig.section("reaction_wheel").get("friction_breakaway_n_m")
            if breakaway is not None and breakaway < value:
                by_section[section].append(
                    f"  friction_breakaway_n_m: {_num(value, r.sigma)}  # the file's "
                    f"{breakaway:g} was below the measured Coulomb friction")
    n_modes = len(rig.beam_modes.omega_rad_s)
    for base, entries in sorted(lists.items()):
        section, name = base.split(".", 1)
        values = [_file_value(rig, base, k) for k in range(n_modes)]
        parts = []
        for k, r in sorted(entries, key=lambda e: e[0]):
            values[k] = r.value
            parts.append(f"mode {k + 1} {_num(r.value, r.sigma)} +- {r.sigma:.2g} "
                         f"({r.verdict}, the file's {r.expected:.4g})")
        others = [str(k + 1) for k in range(n_modes) if k not in dict(entries)]
        text = ", ".join(_num(v, None) for v in values)
        by_section[section].append(
            f"  {name}: [{text}]  # measured on {day}: " + "; ".join(parts)
            + (f"; mode {', '.join(others)}: the file's" if others else ""))
    lines = [f"{HEADER} on {when.strftime('%Y-%m-%dT%H:%M:%SZ')}: the rig file under test",
             f"# ({c.options.rig}) with what commissioning measured of its model, each value",
             "# with its 1-sigma. Review it line by line; then commission it:",
             f"#   harness commission --rig {target}",
             f"# The commissioning: {c.folder} (verdict {c.verdict})."]
    if left:
        lines.append("# Measured but not written (the file's value kept):")
        for r in left:
            why = ("its sigma is not under half the file's tolerance" if r.verdict in
                   ("PASS", "INFO") else r.verdict)
            lines.append(f"#   {r.key}: {_num(r.value, r.sigma)} +- {r.sigma:.2g} "
                         f"(the file's {r.expected:.5g}): {why}")
    name = rig.name if rig.name.endswith("-measured") else f"{rig.name}-measured"
    lines += [f"extends: {_extends(c)}", f"name: {name}"]
    for section in SECTIONS:
        if by_section[section]:
            lines += [f"{section}:", *by_section[section]]
    return "\n".join(lines) + "\n"


def write_rig(target: Path, c: Any) -> Path:
    """Write the measured rig file at ``target`` (checked by ``check_target``) and load it
    back (a file that does not load is an error here, not at the lab's next run)."""
    text = render(c, dt.datetime.now(dt.UTC), target)
    path = fresh_output_path(target)
    write_text_atomic(path, text)
    load_rig(path)
    return path
