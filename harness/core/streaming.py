"""Statistics of a run that do not grow with its length (pure: numbers in, numbers out).

- ``LatencyHistogram``: per-tick durations (lateness, work) counted in 1 us bins up to
  20 ms and in 1 % wide logarithmic bins above; percentiles are read from the counts
  (exact to the bin: 1 us below 20 ms), the maximum is kept exactly. Fixed memory.
- ``RunningSummary``: what ``harness.core.session.summarise`` needs from the whole run, updated
  one recorded block at a time (vectorised): running maxima, the last row, the first time the
  reference reached the target, the last time the hub was outside the settle band, and the
  sums of a least-squares line through the hub angle.
"""

from __future__ import annotations

import math

import numpy as np

LINEAR_BINS = 20_000  # 1 us bins: 0 .. 20 ms
LINEAR_STEP_S = 1e-6
LOG_RATIO = 1.01
LOG_BINS = 1_400  # 20 ms * 1.01**1400 > 1e4 s


class LatencyHistogram:
    """Counts of durations in seconds; ``percentiles_ms()`` gives p50 / p99 / max in ms."""

    __slots__ = ("counts", "n", "max_s", "_log_base")

    def __init__(self) -> None:
        self.counts = [0] * (LINEAR_BINS + LOG_BINS + 1)
        self.n = 0
        self.max_s = 0.0
        self._log_base = math.log(LOG_RATIO)

    def add(self, x_s: float) -> None:
        # the bin computed inline (not by _index): the loop adds a sample every tick
        if x_s < 0.0:
            x_s = 0.0
        i = int(x_s * 1e6)
        if i >= LINEAR_BINS:
            i = LINEAR_BINS + min(LOG_BINS, int(math.log(x_s / (LINEAR_BINS * LINEAR_STEP_S))
                                                / self._log_base))
        self.counts[i] += 1
        self.n += 1
        if x_s > self.max_s:
            self.max_s = x_s

    def add_repeated(self, x_s: float, n: int) -> None:
        """``n`` samples of ``x_s``: what ``n`` calls of ``add(x_s)`` give, in one."""
        if n <= 0:
            return
        x = max(x_s, 0.0)
        self.counts[self._index(x)] += n
        self.n += n
        if x > self.max_s:
            self.max_s = x

    def _index(self, x_s: float) -> int:
        i = int(x_s * 1e6)
        if i >= LINEAR_BINS:
            i = LINEAR_BINS + min(LOG_BINS, int(math.log(x_s / (LINEAR_BINS * LINEAR_STEP_S))
                                                / self._log_base))
        return i

    append = add  # list-like, for code that appended to a list of floats

    def __len__(self) -> int:
        return self.n

    def merge(self, other: LatencyHistogram) -> None:
        """Add another histogram's samples to this one."""
        self.counts = [a + b for a, b in zip(self.counts, other.counts, strict=True)]
        self.n += other.n
        self.max_s = max(self.max_s, other.max_s)

    def _bin_value(self, i: int) -> float:
        if i < LINEAR_BINS:
            return (i + 0.5) * LINEAR_STEP_S
        lo = LINEAR_BINS * LINEAR_STEP_S * LOG_RATIO ** (i - LINEAR_BINS)
        return lo * math.sqrt(LOG_RATIO)

    def quantile_s(self, q: float) -> float:
        """The q-quantile (0..1): the centre of the bin holding it, never above the max."""
        if self.n == 0:
            return 0.0
        rank = q * (self.n - 1)
        cum = 0
        for i, c in enumerate(self.counts):
            if c and cum + c > rank:
                return min(self._bin_value(i), self.max_s)
            cum += c
        return self.max_s

    def percentiles_ms(self) -> dict[str, float]:
        if self.n == 0:
            return {"p50": 0.0, "p99": 0.0, "max": 0.0}
        return {"p50": self.quantile_s(0.50) * 1e3, "p99": self.quantile_s(0.99) * 1e3,
                "max": self.max_s * 1e3}

    def count_above(self, x_s: float) -> int:
        """Samples in bins that lie wholly above ``x_s`` (bin resolution)."""
        total = 0
        for i, c in enumerate(self.counts):
            if c and self._bin_value(i) > x_s:
                total += c
        return total


class RunningSummary:
    """Whole-run figures of the recorded channels, fed one block of rows at a time."""

    def __init__(self, channels: list[str], target_deg: float | None, band_deg: float) -> None:
        self.index = {c: i for i, c in enumerate(channels)}
        self.target_deg = target_deg
        self.band_deg = band_deg
        self.rows = 0
        self.t_first: float | None = None
        self.t_last: float | None = None
        self.last_row: np.ndarray | None = None
        self.max_abs: dict[str, float] = {}
        self.has_ref = False
        self.reach_t: float | None = None  # first time the reference equals the target
        self.outside_seen = False  # the hub has been outside the settle band
        self.settle_t: float | None = None  # first time after the last time outside
        self._pending_settle = False  # last outside was the last row of a block
        # least-squares line through the hub angle: sums over (t - t0)
        self._s = np.zeros(5)  # n, St, Stt, Sy, Sty

    def update(self, t: np.ndarray, data: np.ndarray) -> None:
        if len(t) == 0:
            return
        ix = self.index
        if self.t_first is None:
            self.t_first = float(t[0])
        if self._pending_settle:
            self.settle_t = float(t[0])
            self._pending_settle = False
        self.rows += len(t)
        self.t_last = float(t[-1])
        self.last_row = data[-1].copy()
        for ch in ("/tip/accel_m_s2", "/wheel/torque_cmd_n_m", "/wheel/torque_n_m"):
            if ch in ix:
                col = data[:, ix[ch]]
                m = float(np.nanmax(np.abs(col))) if np.any(~np.isnan(col)) else math.nan
                old = self.max_abs.get(ch, math.nan)
                self.max_abs[ch] = m if math.isnan(old) else (old if math.isnan(m)
                                                                else max(old, m))
        angle = data[:, ix["/attitude/angle_deg"]]
        if "/attitude/reference_deg" in ix:
            ref = data[:, ix["/attitude/reference_deg"]]
            if not self.has_ref and np.any(~np.isnan(ref)):
                self.has_ref = True
            if self.reach_t is None and self.target_deg is not None:
                reach = np.nonzero(np.abs(ref - self.target_deg) < 1e-9)[0]
                if len(reach):
                    self.reach_t = float(t[reach[0]])
        if self.target_deg is not None:
            outside = np.nonzero(np.abs(self.target_deg - angle) > self.band_deg)[0]
            if self.settle_t is None and not self.outside_seen and len(outside) == 0:
                self.settle_t = self.t_first  # inside from the start (so far)
            if len(outside):
                self.outside_seen = True
                last = outside[-1]
                if last + 1 < len(t):
                    self.settle_t = float(t[last + 1])
                else:
                    self.settle_t = None
                    self._pending_settle = True
        ok = ~np.isnan(angle)
        tt = t[ok] - self.t_first
        y = angle[ok]
        self._s += (len(tt), tt.sum(), (tt * tt).sum(), y.sum(), (tt * y).sum())

    def angle_trend(self, t: np.ndarray) -> np.ndarray:
        """The whole run's least-squares line through the hub angle, evaluated at ``t``."""
        n, st, stt, sy, sty = self._s
        t0 = self.t_first or 0.0
        den = n * stt - st * st
        if n < 2 or den == 0:
            return np.full_like(t, sy / n if n else 0.0)
        slope = (n * sty - st * sy) / den
        icpt = (sy - slope * st) / n
        return icpt + slope * (t - t0)
