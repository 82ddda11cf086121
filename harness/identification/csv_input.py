"""Read a tip-acceleration record from CSV: time (s) and acceleration (m/s^2).

- Delimiter: ``,``, ``;``, tab, or whitespace (detected from the first data line unless
  given). Blank lines and lines starting with ``#`` are skipped.
- Header optional: if the first line has a non-numeric field in the selected columns it is
  taken as a header, and columns may then be selected by name.
- Errors are ``ValueError`` naming the line (1-based, as an editor shows it) and column:
  unparsable or non-finite values, missing columns, time not strictly increasing, and a
  sampling interval that differs from the median interval by more than ``rel_tol``.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import NamedTuple, TextIO

import numpy as np


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
        raise ValueError(f"{role}_column {col!r} not in the header {header}")
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
            text = fh.read()
        name = str(source)
    else:
        text = source.read()
        name = getattr(source, "name", "<stream>")
    lines = [
        (i + 1, ln)
        for i, ln in enumerate(text.splitlines())
        if ln.strip() and not ln.lstrip().startswith("#")
    ]
    if not lines:
        raise ValueError(f"{name}: no data lines")
    delim = _detect_delimiter(lines[0][1]) if delimiter is None else delimiter
    first = _split(lines[0][1], delim)
    header: list[str] | None = None
    if not all(_is_number(f) for f in first if f):
        header = first
        lines = lines[1:]
    ti = _resolve_column(time_column, header, "time")
    ai = _resolve_column(accel_column, header, "accel")
    t_vals: list[float] = []
    a_vals: list[float] = []
    for lineno, line in lines:
        fields = _split(line, delim)
        need = max(ti, ai)
        if len(fields) <= need:
            raise ValueError(
                f"{name}: line {lineno} has {len(fields)} column(s); column {need + 1} is needed"
            )
        row = []
        for idx, role in ((ti, "time"), (ai, "acceleration")):
            raw = fields[idx]
            label = f"column {idx + 1} ({role}" + (f", {header[idx]!r})" if header else ")")
            try:
                value = float(raw)
            except ValueError:
                raise ValueError(
                    f"{name}: line {lineno}, {label}: cannot read {raw!r} as a number"
                ) from None
            if not math.isfinite(value):
                raise ValueError(f"{name}: line {lineno}, {label}: value {raw!r} is not finite")
            row.append(value)
        t_vals.append(row[0])
        a_vals.append(row[1])
    if len(t_vals) < 2:
        raise ValueError(f"{name}: need at least 2 data lines, got {len(t_vals)}")
    t = np.asarray(t_vals)
    a = np.asarray(a_vals)
    linenos = [ln for ln, _ in lines]
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
