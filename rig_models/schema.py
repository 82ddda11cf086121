"""A small schema checker for the YAML rig and run files.

Errors name the file, the key path and what was expected (with the unit), e.g.
``rig file sgsrt.yaml: hub.inertia_kg_m2: expected a number > 0 (kg m^2), got 'abc'``.
Unknown keys are errors too (a typo must not silently fall back to a default).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any


class ConfigError(ValueError):
    """A rig or run file does not match its schema."""


QUOTE_CHARS = 80
"""The most characters of a value an error quotes (a file's value may be megabytes)."""


def short_repr(value: Any, limit: int = QUOTE_CHARS) -> str:
    """``repr(value)`` cut to about ``limit`` characters (with the total length said)."""
    if isinstance(value, str) and len(value) > limit:
        return f"{value[:limit]!r}... ({len(value)} characters)"
    text = repr(value)
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text)} characters)"


@dataclass(frozen=True)
class Field:
    """One leaf of a schema."""

    kind: str  # "number", "int", "str", "bool", "list[number]", "any"
    unit: str = ""
    default: Any = None
    required: bool = False
    minimum: float | None = None
    exclusive_minimum: float | None = None
    maximum: float | None = None
    choices: tuple[Any, ...] | None = None
    check: Callable[[Any], str | None] | None = field(default=None, compare=False)

    def describe(self) -> str:
        parts = {"number": "a finite number", "int": "an integer", "str": "a string",
                 "bool": "true or false", "list[number]": "a list of numbers",
                 "any": "a value"}[self.kind]
        if self.exclusive_minimum is not None:
            parts += f" > {self.exclusive_minimum:g}"
        if self.minimum is not None:
            parts += f" >= {self.minimum:g}"
        if self.maximum is not None:
            parts += f" <= {self.maximum:g}"
        if self.choices is not None:
            parts += " in {" + ", ".join(str(c) for c in self.choices) + "}"
        if self.unit:
            parts += f" ({self.unit})"
        return parts


Schema = Mapping[str, "Field | Schema"]


def _is_number(v: Any) -> bool:
    """A real, finite number. NaN must never pass: every comparison with NaN is False, so a
    limit of NaN would switch off the check it configures (a safety abort that never fires);
    an infinity is no limit either."""
    if isinstance(v, bool) or not isinstance(v, int | float):
        return False
    try:
        return math.isfinite(v)
    except OverflowError:  # an int too large for a float
        return False


def _leaf_ok(spec: Field, value: Any) -> bool:
    if spec.kind == "any":
        return True
    if spec.kind == "bool":
        return isinstance(value, bool)
    if spec.kind == "str":
        return isinstance(value, str)
    if spec.kind == "int":
        return isinstance(value, int) and not isinstance(value, bool) and _is_number(value)
    if spec.kind == "number":
        return _is_number(value)
    if spec.kind == "list[number]":
        return isinstance(value, list) and all(_is_number(v) for v in value)
    raise AssertionError(spec.kind)


def _range_ok(spec: Field, value: Any) -> bool:
    values = value if isinstance(value, list) else [value]
    for v in values:
        if not isinstance(v, int | float):
            continue
        if spec.minimum is not None and v < spec.minimum:
            return False
        if spec.exclusive_minimum is not None and v <= spec.exclusive_minimum:
            return False
        if spec.maximum is not None and v > spec.maximum:
            return False
    return spec.choices is None or value in spec.choices


def validate(data: Any, schema: Schema, source: str, path: str = "") -> dict[str, Any]:
    """Check ``data`` against ``schema``; return a copy with defaults filled in."""
    where = path or "(top level)"
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: {where}: expected a mapping of keys, got "
                          f"{short_repr(data)}")
    unknown = sorted(set(data) - set(schema), key=str)
    if unknown:
        known = ", ".join(sorted(schema))
        raise ConfigError(
            f"{source}: {path + '.' if path else ''}{unknown[0]}: unknown key "
            f"(expected one of: {known})"
        )
    out: dict[str, Any] = {}
    for key, spec in schema.items():
        key_path = f"{path}.{key}" if path else key
        if isinstance(spec, Field):
            if key not in data or data[key] is None:
                if spec.required:
                    raise ConfigError(f"{source}: {key_path}: missing; expected {spec.describe()}")
                out[key] = spec.default
                continue
            value = data[key]
            if not _leaf_ok(spec, value) or not _range_ok(spec, value):
                raise ConfigError(
                    f"{source}: {key_path}: expected {spec.describe()}, got {short_repr(value)}"
                )
            if spec.kind == "number":
                value = float(value)
            if spec.check is not None:
                problem = spec.check(value)
                if problem:
                    raise ConfigError(f"{source}: {key_path}: {problem}, got {short_repr(value)}")
            out[key] = value
        else:
            out[key] = validate(data.get(key), spec, source, key_path)
    return out
