"""Reading a run folder back, whatever a hand edit or a damaged disk left in it.

Every reader of a run folder other than the judge (the twin, the history's scatter, replay,
the report) takes its configuration and its side files through here: a file of the wrong
shape is refused with one line naming the file and the field (``RunFolderError``; the
commands exit 2), never a traceback; and the work a folder asks for is bounded before it
starts (``RunFolder.max_ticks``: a time stamp far beyond the run's end is refused, not
allocated).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

MAX_RATE_HZ = 2000.0
"""The fastest loop a run file may ask for (harness.core.runs' RUN_SCHEMA)."""
MAX_DURATION_S = 30 * 24 * 3600.0
"""The longest run a run file may ask for (RUN_SCHEMA)."""
MAX_SIDE_FILE_BYTES = 16 * 1024 * 1024
"""identify.json and the like are a few KB; past this a file is not read."""
TICK_SLACK = 1000
"""Ticks past the configured end a recording may hold (the safe commands at the end)."""


class RunFolderError(ValueError):
    """A run folder's file is missing or of the wrong shape: the message names the file and
    the field."""


def _number(where: str, v: Any, lo: float, hi: float, unit: str) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise RunFolderError(f"{where}: expected a number ({unit}), got {v!r}")
    x = float(v)
    if not math.isfinite(x) or not lo < x <= hi:
        raise RunFolderError(f"{where}: expected a number in ({lo:g}, {hi:g}] {unit}, "
                             f"got {v!r}")
    return x


@dataclass
class RunFolder:
    """A run folder's configuration, checked: its ``run`` section's rate and duration are
    finite numbers in the run file's bounds."""

    path: Path
    config: dict[str, Any]
    run: dict[str, Any]
    rate_hz: float
    duration_s: float
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def dt_s(self) -> float:
        return 1.0 / self.rate_hz

    @property
    def max_ticks(self) -> int:
        """The most ticks the run can have recorded: anything later is not its data."""
        return int(math.ceil(self.duration_s * self.rate_hz)) + TICK_SLACK

    def check_ticks(self, what: str, last_tick: int) -> None:
        """Refuses a recording whose samples reach past the run's end (``what`` names the
        file and channel), before any work is sized on it."""
        if last_tick > self.max_ticks:
            raise RunFolderError(
                f"{what}: a time stamp at {last_tick * self.dt_s:.6g} s, past the run's "
                f"end ({self.duration_s:g} s in config.yaml run.duration_s): not this run's "
                "data (a damaged or edited recording)")


def load_run_folder(run_dir: Path | str) -> RunFolder:
    """The run folder's config.yaml, checked (see ``RunFolder``); RunFolderError names the
    file and the field of what is wrong."""
    import yaml

    run_dir = Path(run_dir)
    path = run_dir / "config.yaml"
    if not run_dir.is_dir():
        raise RunFolderError(f"{run_dir}: not a directory")
    try:
        if path.stat().st_size > MAX_SIDE_FILE_BYTES:
            raise RunFolderError(f"{path}: {path.stat().st_size} bytes, not a config the "
                                 "harness wrote")
        cfg = yaml.safe_load(path.read_text(encoding="utf-8", errors="replace"))
    except FileNotFoundError:
        raise RunFolderError(f"{path}: no such file (not a run directory)") from None
    except (OSError, yaml.YAMLError, RecursionError) as exc:
        raise RunFolderError(f"{path}: unreadable ({str(exc).splitlines()[0]})") from None
    if not isinstance(cfg, dict):
        raise RunFolderError(f"{path}: expected a mapping, got {type(cfg).__name__}")
    run = cfg.get("run")
    if not isinstance(run, dict):
        raise RunFolderError(f"{path}: run: expected the run's section (a mapping), got "
                             f"{type(run).__name__}")
    rate = _number(f"{path}: run.rate_hz", run.get("rate_hz"), 0.0, MAX_RATE_HZ, "Hz")
    duration = _number(f"{path}: run.duration_s", run.get("duration_s"), 0.0,
                       MAX_DURATION_S, "s")
    rig = cfg.get("rig")
    if rig is not None and not isinstance(rig, dict):
        raise RunFolderError(f"{path}: rig: expected the rig file's data (a mapping), got "
                             f"{type(rig).__name__}")
    return RunFolder(run_dir, cfg, run, rate, duration)


def read_json_object(path: Path) -> dict[str, Any] | None:
    """A side file of the run (identify.json, ...) that must be a JSON object: None when it
    does not exist, RunFolderError when it is not an object (or too large to be one the
    harness wrote)."""
    if not path.is_file():
        return None
    if path.stat().st_size > MAX_SIDE_FILE_BYTES:
        raise RunFolderError(f"{path}: {path.stat().st_size} bytes, not a file the harness "
                             "wrote")
    try:
        loaded = json.loads(path.read_text(encoding="utf-8", errors="replace"))
    except (ValueError, RecursionError) as exc:
        raise RunFolderError(f"{path}: not JSON ({exc})") from None
    if not isinstance(loaded, dict):
        raise RunFolderError(f"{path}: expected a JSON object, got {type(loaded).__name__}")
    return loaded


def identified_modes(run_dir: Path) -> list[dict[str, Any]] | None:
    """identify.json's modes, each checked (``omega_rad_s`` a finite number > 0, sigma and
    damping finite numbers when given); None without the file."""
    path = Path(run_dir) / "identify.json"
    doc = read_json_object(path)
    if doc is None:
        return None
    modes = doc.get("modes")
    if not isinstance(modes, list):
        raise RunFolderError(f"{path}: modes: expected a list, got {type(modes).__name__}")
    for i, m in enumerate(modes):
        where = f"{path}: modes[{i}]"
        if not isinstance(m, dict):
            raise RunFolderError(f"{where}: expected an object, got {type(m).__name__}")
        _number(f"{where}.omega_rad_s", m.get("omega_rad_s"), 0.0, math.inf, "rad/s")
        for key in ("sigma_omega_rad_s", "damping_ratio"):
            if m.get(key) is not None:
                _number(f"{where}.{key}", m[key], -math.inf, math.inf, "")
    return modes
