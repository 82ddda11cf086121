"""Drift alarms with uncertainty (pure: numbers in, alarms out).

A series is a list of ``Point`` (time, value, 1 sigma or None), oldest first. Three rules:

- **change** (an identified mode, or anything with its own 1 sigma): each run against the
  reference run (the first of the series, or the one chosen): flagged when
  ``|x_i - x_ref| > k * sqrt(sigma_i^2 + sigma_ref^2)``, the change beyond ``k`` times its
  combined standard uncertainty (``k`` = 3 by default, a Shewhart chart's limits: a
  stationary series raises a false alarm about once in 370 runs).
- **control** (a criterion's value or margin, which carries no sigma of its own): the
  reference is the mean of the first ``n_ref`` runs and the spread the virtual rig's
  predicted scatter of that criterion if known (``harness.history.scatter``), else the
  standard deviation of those runs; flagged beyond ``k`` spreads (the mean's own
  uncertainty included).
- **trend**: the weighted least-squares slope over the last ``n_trend`` runs, flagged when
  it differs from zero by more than ``k`` of its own standard error (a slow drift no single
  run shows; the slope's error comes from the points' sigmas, else from their scatter
  about the line).

A mode outside the band a calibrated shaper was designed for is a **band** alarm: run
``harness calibrate`` again.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from harness.history import DEFAULT_K, DEFAULT_N_REF, DEFAULT_N_TREND


@dataclass
class Point:
    time_utc: str
    value: float
    sigma: float | None = None
    source: str = ""


@dataclass
class Alarm:
    kind: str  # "change" | "control" | "trend" | "band"
    series: str
    index: int  # the run's index in the series (0 = oldest)
    time_utc: str
    value: float
    reference: float
    change: float
    sigma: float  # the combined 1 sigma the change is judged against (trend: the slope's)
    k: float
    unit: str
    message: str
    source: str = ""

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def _fmt(v: float) -> str:
    return f"{v:.5g}"


def change_alarms(points: Sequence[Point], series: str, unit: str, k: float = DEFAULT_K,
                  reference: int = 0) -> list[Alarm]:
    """Every run after ``reference`` whose change from it exceeds ``k`` combined sigma."""
    if not points:
        return []
    if not 0 <= reference < len(points):
        raise ValueError(f"reference: expected a run index in [0, {len(points) - 1}], "
                         f"got {reference}")
    ref = points[reference]
    if ref.sigma is None:
        raise ValueError(f"{series}: the reference run has no 1 sigma")
    out = []
    for i, p in enumerate(points):
        if i <= reference or p.sigma is None:
            continue
        s = math.hypot(p.sigma, ref.sigma)
        d = p.value - ref.value
        if abs(d) > k * s:
            rel = f" ({100 * d / ref.value:+.2f} %)" if ref.value else ""
            out.append(Alarm(
                "change", series, i, p.time_utc, p.value, ref.value, d, s, k, unit,
                f"{series}: {_fmt(p.value)} {unit} on {p.time_utc} changed by {d:+.4g} {unit}"
                f"{rel} from {_fmt(ref.value)} {unit} ({ref.time_utc}), beyond {k:g} x the "
                f"combined 1 sigma {s:.3g} {unit}", p.source))
    return out


def control_alarms(points: Sequence[Point], series: str, unit: str, k: float = DEFAULT_K,
                   n_ref: int = DEFAULT_N_REF, spread: float | None = None) -> list[Alarm]:
    """Runs after the first ``n_ref`` beyond ``k`` spreads of their mean (``spread``: the
    predicted scatter's standard deviation; None: the reference runs' own)."""
    if len(points) <= n_ref or n_ref < 1:
        return []
    ref = np.array([p.value for p in points[:n_ref]], dtype=float)
    center = float(ref.mean())
    if spread is None:
        if n_ref < 3:
            return []
        spread = float(ref.std(ddof=1))
    s = spread * math.sqrt(1.0 + 1.0 / n_ref)  # the mean of n_ref runs is uncertain too
    if not s > 0:
        return []
    out = []
    for i, p in enumerate(points[n_ref:], start=n_ref):
        d = p.value - center
        if abs(d) > k * s:
            out.append(Alarm(
                "control", series, i, p.time_utc, p.value, center, d, s, k, unit,
                f"{series}: {_fmt(p.value)} {unit} on {p.time_utc} is {d:+.4g} {unit} from "
                f"the mean of its first {n_ref} runs ({_fmt(center)} {unit}), beyond {k:g} x "
                f"{s:.3g} {unit}", p.source))
    return out


def trend_alarm(points: Sequence[Point], series: str, unit: str, k: float = DEFAULT_K,
                n_trend: int = DEFAULT_N_TREND) -> Alarm | None:
    """The slope over the last ``n_trend`` runs, if it is beyond ``k`` standard errors."""
    if n_trend < 3 or len(points) < n_trend:
        return None
    pts = points[-n_trend:]
    x = np.arange(n_trend, dtype=float)
    y = np.array([p.value for p in pts], dtype=float)
    sig = [p.sigma for p in pts]
    if all(s is not None and s > 0 for s in sig):
        w = 1.0 / np.square(np.array(sig, dtype=float))
        known = True
    else:
        w = np.ones(n_trend)
        known = False
    xm = float(np.sum(w * x) / np.sum(w))
    ym = float(np.sum(w * y) / np.sum(w))
    sxx = float(np.sum(w * (x - xm) ** 2))
    slope = float(np.sum(w * (x - xm) * (y - ym)) / sxx)
    if known:
        se = math.sqrt(1.0 / sxx)
    else:
        resid = y - (ym + slope * (x - xm))
        var = float(np.sum(resid ** 2)) / (n_trend - 2)
        se = math.sqrt(var / sxx)
    if not se > 0 or abs(slope) <= k * se:
        return None
    last = pts[-1]
    return Alarm("trend", series, len(points) - 1, last.time_utc, last.value, pts[0].value,
                 slope * (n_trend - 1), se, k, unit,
                 f"{series}: trend {slope:+.4g} {unit} per run over the last {n_trend} runs "
                 f"(to {last.time_utc}), beyond {k:g} x its standard error {se:.3g} "
                 f"{unit}/run", last.source)


def band_alarm(point: Point, index: int, series: str, band: dict[str, float],
               designed_by: str) -> Alarm | None:
    """``point`` (a mode, rad/s) outside the band ``band`` a shaper was designed for."""
    lo, hi = band["omega_lo_rad_s"], band["omega_hi_rad_s"]
    if lo <= point.value <= hi:
        return None
    centre = band["omega_rad_s"]
    return Alarm("band", series, index, point.time_utc, point.value, centre,
                 point.value - centre, 0.0, 0.0, "rad/s",
                 f"{series}: {_fmt(point.value)} rad/s on {point.time_utc} left the band "
                 f"[{_fmt(lo)}, {_fmt(hi)}] rad/s the shaper of {designed_by} was designed "
                 "for: run `harness calibrate` again", point.source)


def first(alarms: Sequence[Alarm], kind: str | None = None) -> Alarm | None:
    chosen = [a for a in alarms if kind is None or a.kind == kind]
    return min(chosen, key=lambda a: a.index) if chosen else None
