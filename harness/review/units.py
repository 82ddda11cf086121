"""Units and limits as people write them (``N m``, ``m/s²``, ``|x| ≤ 0.1 deg``), from the
suffixes our names carry (``_n_m``, ``_m_s2``, ``max_abs_deg``): the verdict in run.rrd,
report.html and the printed tables. Pure text; no imports of the harness."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

# suffix -> as written; longest suffixes are matched first
UNITS: dict[str, str] = {
    "n_m_s": "N m s", "n_m": "N m", "m_s2": "m/s²", "deg_s": "deg/s", "rad_s": "rad/s",
    "m_s": "m/s", "deg": "deg", "rad": "rad", "ms": "ms", "s": "s", "hz": "Hz", "v": "V",
    "m": "m", "percent": "%", "bool": "", "count": "", "ratio": "",
}
_SUFFIXES = sorted(UNITS, key=len, reverse=True)


def unit_text(suffix: str | None) -> str:
    """``n_m`` -> ``N m``, ``m_s2`` -> ``m/s²`` (unknown suffixes as they are)."""
    if not suffix:
        return ""
    return UNITS.get(suffix, suffix.replace("_", " "))


def split_unit(name: str) -> tuple[str, str]:
    """``max_abs_deg`` -> (``max_abs``, ``deg``); (``name``, "") without a known suffix."""
    for suffix in _SUFFIXES:
        if name.endswith("_" + suffix) and len(name) > len(suffix) + 1:
            return name[: -len(suffix) - 1], suffix
    return name, ""


def number(v: Any) -> str:
    if v is None:
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return "-" if not math.isfinite(v) else f"{v:.4g}"
    return str(v)


def quantity(v: Any, suffix: str | None) -> str:
    """A value with its unit: ``0.053 N m``."""
    u = unit_text(suffix)
    text = number(v)
    return f"{text} {u}" if u and text != "-" and not isinstance(v, bool) else text


_LIMIT_WORDS = {"max_abs": "|x| ≤", "max": "≤", "min": "≥", "max_count": "≤", "is": "=",
                "equals": "=", "within": "within", "stays": "stays", "band": "band ±",
                "center": "centre", "tol": "tolerance", "tol_rel": "tolerance",
                "max_shift": "shift ≤", "marginal": "marginal within"}


def limit_text(limit: Mapping[str, Any]) -> str:
    """A criterion's limits (verdict.json's ``limit``) as one readable phrase:
    ``{"max_abs_deg": 0.1}`` -> ``|x| ≤ 0.1 deg``."""
    parts = []
    for key, v in limit.items():
        if key == "max_count":
            parts.append(f"≤ {number(v)}")
            continue
        base, suffix = split_unit(key)
        word = _LIMIT_WORDS.get(base, base.replace("_", " "))
        parts.append(f"{word} {quantity(v, suffix)}".strip())
    return ", ".join(parts) or "-"
