"""Read a tip-acceleration record from CSV: time (s) and acceleration (m/s^2).

- Delimiter: ``,``, ``;``, tab, or whitespace (detected from the first data line unless
  given). Blank lines and lines starting with ``#`` are skipped.
- Header optional: if the first line has a non-numeric field in the selected columns it is
  taken as a header, and columns may then be selected by name.
- Errors are ``ValueError`` naming the line (1-based, as an editor shows it) and column:
  unparsable or non-finite values, missing columns, time not strictly increasing, and a
  sampling interval that differs from the median interval by more than ``rel_tol``.
- Bounded: the file is read a line at a time, a line longer than ``MAX_LINE_CHARS`` is
  refused at once (a 100 MB field took 800 MB and became a 100 MB error line), values are
  kept as packed floats, and an error quotes at most ``QUOTE_CHARS`` of a value.
"""

from __future__ import annotations

import math
from array import array
from collections.abc import Iterator
from pathlib import Path
from typing import NamedTuple, TextIO

import numpy as np

MAX_LINE_CHARS = 65536
"""The longest line read: a time/acceleration row is a few dozen characters."""

QUOTE_CHARS = 80
"""The most characters of a value an error quotes."""


def quote(value: object, limit: int = QUOTE_CHARS) -> str:
    """``repr(value)`` cut to about ``limit`` characters (the total length said)."""
    if isinstance(value, str) and len(value) > limit:
        return f"{value[:limit]!r}... ({len(value)} characters)"
    text = repr(value)
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text)} characters)"


class AccelRecord(NamedTuple):
    t: np.ndarray  # s
    accel: np.ndarray  # m/s^2
    column_names: tuple[str, str] | None  # header names of the two columns, if any


def _split(line: str, delimiter: str | None) -> list[str]:
    fields = line.split() if delimiter is None else line.split(delimiter)
    return [f.strip().strip('"').strip("'") for f in fields]


def _detect_delimiter(line: str) -> str | None:
    for d in (",", ";", "\t"):
        if d in line:
            return d
    return None  # whitespace


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _resolve_column(col: int | str, header: list[str] | None, role: str) -> int:
    if isinstance(col, int):
        if col < 0:
            raise ValueError(f"{role}_column must be a non-negative index, got {col}")
        return col
    if header is None:
        raise ValueError(f"{role}_column {col!r} is a name but the CSV has no header line")
    if col not in header:
        raise ValueError(f"{role}_column {quote(col)} not in the header {quote(header)}")
    return header.index(col)


def read_accel_csv(
    source: str | Path | TextIO,
    *,
    time_column: int | str = 0,
    accel_column: int | str = 1,
    delimiter: str | None = None,
    rel_tol: float = 0.05,
) -> AccelRecord:
    """Read time and acceleration columns from a CSV file path or open text stream."""
    if not rel_tol > 0:
        raise ValueError(f"rel_tol must be positive, got {rel_tol!r}")
    if isinstance(source, str | Path):
        with open(source, encoding="utf-8") as fh:
            return _read(fh, str(source), time_column, accel_column, delimiter, rel_tol)
    return _read(source, getattr(source, "name", "<stream>"), time_column, accel_column,
                 delimiter, rel_tol)


def _data_lines(fh: TextIO, name: str) -> Iterator[tuple[int, str]]:
    """(line number, line) of every data line: not blank, not a ``#`` comment; a line
    longer than ``MAX_LINE_CHARS`` is a ``ValueError`` before more of it is read."""
    lineno = 0
    while True:
        line = fh.readline(MAX_LINE_CHARS + 1)
        if not line:
            return
        lineno += 1
        if len(line) > MAX_LINE_CHARS and not line.endswith("\n"):
            raise ValueError(f"{name}: line {lineno}: longer than {MAX_LINE_CHARS} characters "
                             f"(starts {quote(line)}); a time/acceleration row is short")
        if line.strip() and not line.lstrip().startswith("#"):
            yield lineno, line.rstrip("\r\n")


def _read(fh: TextIO, name: str, time_column: int | str, accel_column: int | str,
          delimiter: str | None, rel_tol: float) -> AccelRecord:
    lines = _data_lines(fh, name)
    head = next(lines, None)
    if head is None:
        raise ValueError(f"{name}: no data lines")
    delim = _detect_delimiter(head[1]) if delimiter is None else delimiter
    first = _split(head[1], delim)
    header: list[str] | None = None
    if not all(_is_number(f) for f in first if f):
        header = first
        rows: Iterator[tuple[int, str]] = lines
    else:
        rows = _chain(head, lines)
    ti = _resolve_column(time_column, header, "time")
    ai = _resolve_column(accel_column, header, "accel")
    t_vals, a_vals, linenos = array("d"), array("d"), array("q")
    for lineno, line in rows:
        fields = _split(line, delim)
        need = max(ti, ai)
        if len(fields) <= need:
            raise ValueError(
                f"{name}: line {lineno} has {len(fields)} column(s); column {need + 1} is needed"
            )
        row = []
        for idx, role in ((ti, "time"), (ai, "acceleration")):
            raw = fields[idx]
            label = f"column {idx + 1} ({role}" + (f", {quote(header[idx])})" if header
                                                   else ")")
            try:
                value = float(raw)
            except ValueError:
                raise ValueError(
                    f"{name}: line {lineno}, {label}: cannot read {quote(raw)} as a number"
                ) from None
            if not math.isfinite(value):
                raise ValueError(f"{name}: line {lineno}, {label}: value {quote(raw)} is not "
                                 "finite")
            row.append(value)
        t_vals.append(row[0])
        a_vals.append(row[1])
        linenos.append(lineno)
    if len(t_vals) < 2:
        raise ValueError(f"{name}: need at least 2 data lines, got {len(t_vals)}")
    t = np.frombuffer(t_vals, dtype=np.float64).copy()
    a = np.frombuffer(a_vals, dtype=np.float64).copy()
    dt = np.diff(t)
    bad = np.flatnonzero(dt <= 0.0)
    if bad.size:
        i = int(bad[0]) + 1
        raise ValueError(
            f"{name}: line {linenos[i]}, column {ti + 1} (time): {t[i]!r} s is not after "
            f"{t[i - 1]!r} s on line {linenos[i - 1]}; time must be strictly increasing"
        )
    med = float(np.median(dt))
    off = np.flatnonzero(np.abs(dt - med) > rel_tol * med)
    if off.size:
        i = int(off[0]) + 1
        raise ValueError(
            f"{name}: line {linenos[i]}, column {ti + 1} (time): sampling interval "
            f"{dt[i - 1]:.6g} s differs from the median {med:.6g} s by more than "
            f"{rel_tol:.0%}; the record must be uniformly sampled"
        )
    names = None if header is None else (header[ti], header[ai])
    return AccelRecord(t=t, accel=a, column_names=names)


def _chain(first: tuple[int, str], rest: Iterator[tuple[int, str]]
           ) -> Iterator[tuple[int, str]]:
    yield first
    yield from rest
