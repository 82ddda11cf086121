"""Reading a run's summary.json back, whatever a hand edit left in it.

``harness judge`` and ``harness logs`` read summary.json files that people may have edited:
a list instead of an object, ``faults: "x"``, nesting thousands deep. ``read_summary``
returns the object with every field of the wrong shape left out, and one line per field
left out (naming it), so a caller judges or lists what is there and says what is not; it
raises ``ValueError`` only when the file is not a JSON object at all.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

MAX_SUMMARY_BYTES = 16 * 1024 * 1024
"""A summary.json the harness writes is a few KB; past this it is not read."""

_TEXT = (str, type(None))
_NUMBER = (int, float, type(None))
_MAPPING = (dict, type(None))
FIELD_TYPES: dict[str, tuple[type, ...]] = {
    "run": _TEXT, "clock": _TEXT, "bus": _TEXT, "stopped_by": _TEXT, "error": _TEXT,
    "ticks": _NUMBER, "rate_hz": _NUMBER, "simulated_time_s": _NUMBER,
    "wall_time_s": _NUMBER, "real_time_factor": _NUMBER, "final_angle_deg": _NUMBER,
    "final_angle_error_deg": _NUMBER, "settle_time_s": _NUMBER,
    "slew_profile_end_s": _NUMBER, "residual_tip_accel_m_s2": _NUMBER,
    "peak_tip_accel_m_s2": _NUMBER, "frames": _MAPPING, "lateness_ms": _MAPPING,
    "work_ms": _MAPPING, "realtime_measures": _MAPPING, "monitor_warnings": _MAPPING,
    "virtual_rig": _MAPPING, "faults": (list, type(None)),
    "injected_faults": (list, type(None)), "dry_run": (bool, type(None)),
}
"""Fields the harness's readers rely on, with the types they may have."""

ENTRY_TYPES: dict[str, dict[str, tuple[type, ...]]] = {
    "faults": {"device": _TEXT, "kind": _TEXT, "message": _TEXT, "time_s": _NUMBER},
    "injected_faults": {"kind": _TEXT, "device": _TEXT, "at_s": _NUMBER,
                        "duration_s": _NUMBER, "value": _NUMBER},
}
"""The fields of each entry of a list of faults, with the types they may have (a kind that
is a list cannot be compared with the kinds a criterion expects)."""


def _entry_problem(key: str, entries: list[Any]) -> str | None:
    for i, entry in enumerate(entries):
        if not isinstance(entry, dict):
            return f"expected a list of objects, got {_describe(entries)}"
        for field, kinds in ENTRY_TYPES[key].items():
            v = entry.get(field)
            if not isinstance(v, kinds) or isinstance(v, bool):
                return f"[{i}].{field}: unexpected {_describe(v)}"
    return None


def _describe(v: Any) -> str:
    text = repr(v)
    return text if len(text) <= 60 else text[:57] + "..."


def read_summary(path: Path) -> tuple[dict[str, Any], list[str]]:
    """(the summary's fields of the right shape, one line per field left out). Raises
    ``OSError`` when it cannot be read and ``ValueError`` when it is not a JSON object."""
    path = Path(path)
    if path.stat().st_size > MAX_SUMMARY_BYTES:
        raise ValueError(f"{path.stat().st_size} bytes, not a summary the harness wrote")
    try:
        loaded = json.loads(path.read_text(encoding="utf-8", errors="replace"))
    except RecursionError:
        raise ValueError("nested too deeply") from None
    if not isinstance(loaded, dict):
        raise ValueError(f"expected a JSON object, got {type(loaded).__name__}")
    out: dict[str, Any] = {}
    problems: list[str] = []
    for key, value in loaded.items():
        kinds = FIELD_TYPES.get(key)
        if kinds is not None and (not isinstance(value, kinds)
                                  or (isinstance(value, bool) and bool not in kinds)):
            problems.append(f"summary.json: {key}: unexpected {_describe(value)}")
            continue
        problem = _entry_problem(key, value) if key in ENTRY_TYPES and value else None
        if problem is not None:
            problems.append(f"summary.json: {key}{'' if problem[0] == '[' else ': '}"
                            f"{problem}")
            continue
        out[key] = value
    return out, problems
