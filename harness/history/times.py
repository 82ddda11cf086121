"""Times given to ``harness history`` (``--since`` / ``--until``), read as instants.

The database keeps each result's UTC time as ``YYYY-MM-DDTHH:MM:SSZ``, text that sorts as
time. A time given on the command line is parsed as ISO 8601 (``20260101``, ``2026-01-01``,
``2026-01-01T10:00``, ``2026-01-01T10:00:00Z``, ``2026-01-01T10:00+02:00``), taken as UTC
when it names no offset, converted to UTC when it does, and written in the database's form:
the comparison is then between instants, never between two spellings of one.
"""

from __future__ import annotations

import datetime as dt


class TimeError(ValueError):
    """Not a date or time."""


def parse_utc(text: str) -> dt.datetime:
    """``text`` (ISO 8601, basic or extended form, with or without an offset) as an aware
    UTC datetime; a date alone is its day's start."""
    raw = str(text).strip()
    try:
        t = dt.datetime.fromisoformat(raw)
        if t.tzinfo is None:
            t = t.replace(tzinfo=dt.UTC)
        return t.astimezone(dt.UTC)
    except (ValueError, OverflowError) as exc:
        raise TimeError(f"expected a date or time in ISO 8601 (20260101, 2026-01-01, "
                        f"2026-01-01T10:00, 2026-01-01T10:00+02:00; UTC unless it names an "
                        f"offset), got {raw[:60]!r}") from exc


def utc_text(text: str) -> str:
    """``text`` as the database writes times: ``2026-01-01T08:00:00Z`` for
    ``2026-01-01T10:00+02:00``."""
    t = parse_utc(text)
    return (f"{t.year:04d}-{t.month:02d}-{t.day:02d}T{t.hour:02d}:{t.minute:02d}:"
            f"{t.second:02d}Z")
