"""Evaluating parsed criteria: pure functions of measures, channels and facts (no files).

A criterion's result is a record that is data (OpenHTF's measurement record): its value and
unit, its limits (keys with their unit, as in the run file), its margin (distance to the
nearest limit in the value's unit, positive inside), its verdict, the time of the worst
sample and a one-line message. Verdicts: PASS, MARGINAL (passed, inside the marginal band),
INCONCLUSIVE (a real-time budget criterion failed: the bench did not hold its time, so the
run measured nothing trustworthy), FAIL, ERROR (the run or the harness broke, the data is
missing). A run's verdict is ``run_verdict`` of its criteria: ERROR, else INCONCLUSIVE, else
the worst.
"""

from __future__ import annotations

import math
import warnings
from collections import deque
from collections.abc import Callable, Generator, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from harness.identification.residual_fit import ModalResidualFit
from harness.testing.criteria import Criterion, Window
from harness.testing.measures import (
    NULL_MEANS_FAIL,
    WORST_SAMPLE,
    FieldMissing,
    find,
    unit_text,
)

PASS, MARGINAL, FAIL, ERROR = "PASS", "MARGINAL", "FAIL", "ERROR"
INCONCLUSIVE = "INCONCLUSIVE"
"""A run the bench could not hold in time (a budget criterion failed: overruns, lateness,
telemetry missing in ticks the loop held): neither a pass nor a FAIL of what was tested."""
SEVERITY = {PASS: 0, MARGINAL: 1, INCONCLUSIVE: 2, FAIL: 3, ERROR: 4}
"""Across tests (a suite's worst): INCONCLUSIVE is worse than a pass and never hides a
FAIL. Within one run ``run_verdict`` applies instead (a FAIL measured on a bench that lost
its time is not trusted)."""
INCONCLUSIVE_EXIT = 6
NOT_JUDGED = "NOT JUDGED"
"""A criterion's verdict on a run stopped early (a fault, an interruption, an error) when it
does not say ``applies_to_stopped: true``: its value, measured against a run that never got
where it was going, says nothing. It never decides the run's verdict (the stop does)."""
NO_CRITERIA = "NO CRITERIA"
"""A run's verdict when nothing was judged: no criterion, and none of the run's own checks
found a problem. Not PASS (a run whose ``expect:`` was lost must not read as a passing
test); exit code 0 for ``harness run``, a failure in a suite unless it allows it."""

Channel = Callable[[str], tuple[np.ndarray, np.ndarray]]
"""entity -> (time s, values); raises KeyError/ValueError if the channel is missing."""
BaselineChannel = Callable[[str, str], tuple[np.ndarray, np.ndarray]]
"""(baseline path, entity) -> (time s, values)."""
ChannelBlocks = Callable[[list[str]], Iterator[tuple[str, np.ndarray, np.ndarray]]]
"""entities -> one pass over the recording: (entity, time s, values) blocks in the file's
order (each entity's in time order); raises MissingData if the recording cannot be read."""

MAX_EVENTS = 10
"""Violation times kept per criterion (for the recording's events)."""


class MissingData(Exception):
    """A value a criterion needs is not there (ERROR)."""


@dataclass
class CriterionResult:
    name: str
    kind: str
    value: Any
    unit: str
    limit: dict[str, Any]
    margin: float | None
    verdict: str
    worst_time_s: float | None
    message: str
    why: str = ""
    cause: str = ""
    """For ERROR: "fault" (a fault the run did not expect), "interrupted", or ""."""
    violations_s: list[float] = field(default_factory=list)
    """Times at which the criterion was violated (start of each violation, then the worst;
    at most MAX_EVENTS): written as events into verdict.rrd, not into verdict.json."""

    def to_dict(self) -> dict[str, Any]:
        d = {"name": self.name, "kind": self.kind, "value": _clean(self.value),
             "unit": self.unit, "limit": {k: _clean(v) for k, v in self.limit.items()},
             "margin": _clean(self.margin), "verdict": self.verdict,
             "worst_time_s": _clean(self.worst_time_s), "message": self.message}
        if self.why:
            d["why"] = self.why
        return d


@dataclass
class Facts:
    """What the criteria are judged against. Only ``measures`` is needed for scalar
    criteria; the others are called lazily by the forms that need them."""

    measures: Mapping[str, Any]
    channel: Channel | None = None
    """A channel whole (the baseline form; a channel not in time order in ``blocks``)."""
    baseline_channel: BaselineChannel | None = None
    left_safe: Callable[[], list[str]] | None = None
    """-> what was not left safe (empty: safe); raises MissingData without a CAN log."""
    blocks: ChannelBlocks | None = None
    """The channels block by block (bounded memory); without it, each ``channel`` whole."""
    frf: Callable[[str | None, tuple[str, ...]], Mapping[str, Any]] | None = None
    """(input, outputs) -> ``harness frf``'s document of the run (``frf:`` criteria)."""


def _finite(v: int | float) -> bool:
    try:
        return math.isfinite(v)
    except OverflowError:  # a hand-edited int too large for a float
        return False


def _clean(v: Any) -> Any:
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def _fmt(v: Any) -> str:
    if isinstance(v, bool) or v is None:
        return str(v)
    if isinstance(v, int):
        return str(v)
    return f"{v:.4g}"


def _u(unit: str) -> str:
    """`` N m`` after a number, nothing for a dimensionless one."""
    text = unit_text(unit)
    return f" {text}" if text else ""


def limit_dict(c: Criterion) -> dict[str, Any]:
    """The limits as written in the run file (keys with their unit)."""
    if c.kind in ("scalar", "channel", "modal_residual"):
        if "is" in c.limit:
            return {"is": c.limit["is"]}
        return {f"{k}_{c.unit}": v for k, v in c.limit.items()}
    if c.kind == "settles":
        u = c.params["channel_unit"]
        d = {"within_s": c.limit["max"], "stays_s": c.params["stays_s"],
             f"band_{u}": c.params["band"], f"center_{u}": c.params["center"]}
        if "marginal" in c.limit:
            d["marginal_s"] = c.limit["marginal"]
        return d
    if c.kind == "baseline":
        d = {f"tol_{c.unit}": c.limit["tol"], "tol_rel_percent": c.limit["tol_rel_percent"],
             "max_shift_s": c.limit["max_shift_s"]}
        if "marginal" in c.limit:
            d[f"marginal_{c.unit}"] = c.limit["marginal"]
        return d
    if c.kind == "fault":
        return {"within_ticks": c.limit["max"]} if "max" in c.limit else {}
    if c.kind == "frf":
        return {f"{k}_ratio": v for k, v in c.limit.items()}
    return {"max_count": 0}


def grade(margin: float, marginal: float | None) -> str:
    if margin < 0:
        return FAIL
    if marginal is not None and marginal > 0 and margin < marginal:
        return MARGINAL
    return PASS


def band_margins(values: np.ndarray, limit: Mapping[str, float]) -> np.ndarray:
    """Per sample, the distance to the nearest of min / max / max_abs (positive inside)."""
    m = np.full(values.shape, np.inf)
    if "min" in limit:
        m = np.minimum(m, values - limit["min"])
    if "max" in limit:
        m = np.minimum(m, limit["max"] - values)
    if "max_abs" in limit:
        m = np.minimum(m, limit["max_abs"] - np.abs(values))
    return m


def _limits_text(c: Criterion) -> str:
    return ", ".join(f"{k} {_fmt(v)}" for k, v in limit_dict(c).items())


def _result(c: Criterion, value: Any, margin: float | None, verdict: str,
            worst: float | None, message: str, violations: Sequence[float] = ()) -> \
        CriterionResult:
    if c.budget and verdict == FAIL:
        verdict = INCONCLUSIVE
        message = "real-time budget not held: " + message
    return CriterionResult(c.name, c.kind, value, c.unit, limit_dict(c), margin, verdict,
                           worst, message, c.why, violations_s=list(violations)[:MAX_EVENTS])


def _error(c: Criterion, message: str, cause: str = "") -> CriterionResult:
    return CriterionResult(c.name, c.kind, None, c.unit, limit_dict(c), None, ERROR, None,
                           message, c.why, cause)


def _verb(verdict: str) -> str:
    return {PASS: "within", MARGINAL: "within (marginal)", FAIL: "outside"}.get(verdict, "vs")


# ------------------------------------------------------------------------------ scalar
def _judge_value(c: Criterion, value: Any) -> tuple[str, float | None, Any, str]:
    """(verdict, margin, the value judged, what is wrong for ERROR / FAIL) of one value."""
    if value is None:
        if c.target in NULL_MEANS_FAIL:
            return FAIL, None, None, f"is null: {NULL_MEANS_FAIL[c.target]}"
        return ERROR, None, None, "is null"
    if "is" in c.limit:
        ok = value is c.limit["is"] or (type(value) is type(c.limit["is"])
                                        and value == c.limit["is"])
        return (PASS if ok else FAIL), None, value, f"(expected {c.limit['is']})"
    if "len_min" in c.limit or "len_max" in c.limit:
        if not isinstance(value, list | dict | str):
            return ERROR, None, value, f"= {_fmt_any(value)} has no length"
        x = float(len(value))
        lim = {k[4:]: v for k, v in c.limit.items() if k.startswith("len_")}
        margin = float(band_margins(np.array([x]), lim)[0])
        return grade(margin, c.marginal), margin, len(value), ""
    if isinstance(value, bool) or not isinstance(value, int | float) or \
            not _finite(value):
        return ERROR, None, value, f"= {_fmt_any(value)} is not a number"
    if "equals" in c.limit:
        ok = math.isclose(float(value), c.limit["equals"], rel_tol=1e-9, abs_tol=1e-12)
        return (PASS if ok else FAIL), (0.0 if ok else -abs(float(value) - c.limit["equals"])), \
            value, ""
    margin = float(band_margins(np.array([float(value)]), c.limit)[0])
    return grade(margin, c.marginal), margin, value, ""


def _fmt_any(v: Any) -> str:
    if isinstance(v, list | dict):
        return f"a {type(v).__name__} of {len(v)}"
    return repr(v) if isinstance(v, str) else _fmt(v)


def evaluate_scalar(c: Criterion, measures: Mapping[str, Any]) -> CriterionResult:
    """A ``measure:`` criterion against a mapping (summary.json, or any JSON document: a
    study's, the probe report, ``identify --json``). The path is dotted (``lateness_ms.p99``;
    keys may contain dots); with ``[*]`` every element is judged and the worst reported."""
    try:
        found = find(measures, c.target)
    except FieldMissing as exc:
        return _error(c, f"missing data: {c.target} is not in the results ({exc})")
    if not found:
        return _error(c, f"missing data: {c.target}: the list is empty (no element to judge)")
    worst: tuple[tuple[int, float], str, str, float | None, Any, str] | None = None
    for where, value in found:
        verdict, margin, judged, text = _judge_value(c, value)
        key = (SEVERITY[verdict], -(margin if margin is not None else -math.inf))
        if worst is None or key > worst[0]:
            worst = (key, where, verdict, margin, judged, text)
    assert worst is not None
    _, where, verdict, margin, value, text = worst
    length = "len_min" in c.limit or "len_max" in c.limit
    what = f"length of {where}" if length else where
    if verdict == ERROR:
        return _error(c, f"missing data: {where} {text}")
    if "is" in c.limit:
        return _result(c, value, None, verdict, None, f"{where} = {_fmt_any(value)} {text}")
    unit = _u(c.unit)
    shown = f"{what} = {_fmt(value) if value is not None else 'null'}{unit}"
    if text:  # a null that is a result
        msg = f"{where} {text}"
    elif margin is None:
        msg = f"{shown} {_verb(verdict)} {_limits_text(c)}"
    else:
        msg = f"{shown} {_verb(verdict)} {_limits_text(c)} (margin {_fmt(margin)}{unit})"
    if len(found) > 1:
        bad = sum(_judge_value(c, v)[0] == FAIL for _, v in found)
        msg = (f"{bad} of {len(found)} outside; worst " if bad else
               f"all {len(found)} judged; worst ") + msg
    return _result(c, value, margin, verdict, None, msg)


# ------------------------------------------------------------------------------ windows
def event_time(measures: Mapping[str, Any], event: str) -> float:
    if event == "fault":
        faults = measures.get("faults") or []
        if not faults:
            raise MissingData("after: fault, but the run detected no fault")
        return float(faults[0]["time_s"])
    if event == "injected_fault":
        inj = measures.get("injected_faults") or []
        if not inj:
            raise MissingData("after: injected_fault, but no fault was injected")
        return float(min(f["at_s"] for f in inj))
    v = measures.get(event)
    if v is None:
        raise MissingData(f"after: {event}, but summary.json's {event} is null (the run "
                          "ended before it)")
    return float(v)


def window_mask(t: np.ndarray, w: Window, measures: Mapping[str, Any]) -> tuple[np.ndarray,
                                                                                  float]:
    """(samples in the window, the window's start time)."""
    eps = 1e-9
    if len(t) == 0:
        raise MissingData("the channel has no samples")
    if w.last_s is not None:
        start = float(t[-1]) - w.last_s
        return t >= start - eps, start
    base = event_time(measures, w.after) if w.after else 0.0
    start = base + (w.from_s or 0.0) if (w.after or w.from_s is not None) else float(t[0])
    end = base + w.to_s if w.to_s is not None else math.inf
    return (t >= start - eps) & (t <= end + eps), start


def _samples(c: Criterion, facts: Facts) -> tuple[np.ndarray, np.ndarray, float]:
    if facts.channel is None:
        raise MissingData(f"no recording to read {c.target} from")
    try:
        t, x = facts.channel(c.target)
    except (KeyError, ValueError, OSError) as exc:
        raise MissingData(f"channel {c.target} not readable: {exc}") from exc
    mask, start = window_mask(t, c.window, facts.measures)
    mask &= ~np.isnan(x)
    if not mask.any():
        raise MissingData(f"no {c.target} samples in the window ({c.window.describe()})")
    return t[mask], x[mask], start


class _Starts:
    """The start times of violations (a sample bad after one that was not), fed block by
    block in time order; at most MAX_EVENTS - 1 kept, then the worst."""

    def __init__(self) -> None:
        self.out: list[float] = []
        self.prev = False

    def feed(self, t: np.ndarray, bad: np.ndarray) -> _Starts:
        if len(bad) and len(self.out) < MAX_EVENTS - 1:
            before = np.concatenate(([self.prev], bad[:-1]))
            idx = np.nonzero(bad & ~before)[0][:MAX_EVENTS - 1 - len(self.out)]
            self.out += [float(t[i]) for i in idx]
        if len(bad):
            self.prev = bool(bad[-1])
        return self

    def times(self, worst: float | None) -> list[float]:
        out = list(self.out)
        if worst is not None and worst not in out:
            out.append(worst)
        return out


Block = tuple[np.ndarray, np.ndarray]
"""(time s, values) of consecutive samples of one channel, in time order."""
Consumer = Generator[None, Block | None, CriterionResult]
"""Receives a channel's blocks in time order (``send``), then None; returns the result."""


def _finish(gen: Generator[None, Any, Any]) -> Any:
    try:
        gen.send(None)
    except StopIteration as stop:
        return stop.value
    raise RuntimeError("a channel consumer did not finish")  # pragma: no cover


def _started(gen: Generator[None, Any, Any]) -> Generator[None, Any, Any]:
    next(gen)
    return gen


def _windowed(c: Criterion, measures: Mapping[str, Any],
              core: Callable[[float], Generator[None, Any, CriterionResult]]) -> Consumer:
    """The criterion's window over a channel's blocks (NaN samples left out), sent on to
    ``core(window start)``. ``last_s`` keeps only the blocks that can still be in the last
    ``last_s`` of the channel (memory bounded by the window, not the run)."""
    eps = 1e-9
    w = c.window
    gen: Generator[None, Any, CriterionResult] | None = None
    n = kept = 0
    start = end = 0.0
    tail: deque[Block] = deque()
    t_last = 0.0
    while (blk := (yield)) is not None:
        t, x = blk
        if not len(t):
            continue
        n += len(t)
        if w.last_s is not None:
            t_last = float(t[-1])
            tail.append((t, x))
            while tail and float(tail[0][0][-1]) < t_last - w.last_s - eps:
                tail.popleft()
            continue
        if gen is None:
            base = event_time(measures, w.after) if w.after else 0.0
            start = base + (w.from_s or 0.0) if (w.after or w.from_s is not None) \
                else float(t[0])
            end = base + w.to_s if w.to_s is not None else math.inf
            gen = _started(core(start))
        m = (t >= start - eps) & (t <= end + eps) & ~np.isnan(x)
        if m.any():
            kept += int(m.sum())
            gen.send((t[m], x[m]))
    if n == 0:
        raise MissingData("the channel has no samples")
    if w.last_s is not None:
        start = t_last - w.last_s
        t = np.concatenate([b[0] for b in tail])
        x = np.concatenate([b[1] for b in tail])
        m = (t >= start - eps) & ~np.isnan(x)
        gen = _started(core(start))
        if m.any():
            kept = int(m.sum())
            gen.send((t[m], x[m]))
    if not kept:
        raise MissingData(f"no {c.target} samples in the window ({w.describe()})")
    assert gen is not None
    return _finish(gen)


def _channel_core(c: Criterion, start: float) -> Generator[None, Any, CriterionResult]:
    """A ``channel:`` criterion over its window's samples."""
    where = c.window.describe()
    best = math.inf
    best_x = best_t = t_last = x_last = 0.0
    total = total_sq = 0.0
    x_first: float | None = None
    n = 0
    starts = _Starts()
    while (blk := (yield)) is not None:
        t, x = blk
        n += len(t)
        t_last, x_last = float(t[-1]), float(x[-1])
        if c.reduce == "each":
            margins = band_margins(x, c.limit)
            i = int(np.argmin(margins))
            if n == len(t) or margins[i] < best:  # the first of equal worst samples
                best, best_x, best_t = float(margins[i]), float(x[i]), float(t[i])
            starts.feed(t, margins < 0)
        elif c.reduce == "rms":
            total += np.sum(x ** 2, dtype=np.float64)
        elif c.reduce == "std":  # about the first sample: no cancellation for a large mean
            if x_first is None:
                x_first = float(x[0])
            d = x - x_first
            total += np.sum(d, dtype=np.float64)
            total_sq += np.sum(d ** 2, dtype=np.float64)
        elif c.reduce == "mean":
            total += np.sum(x, dtype=np.float64)
    if c.reduce == "each":
        verdict = grade(best, c.marginal)
        return _result(c, best_x, best, verdict, best_t,
                       f"{c.target} worst sample {_fmt(best_x)}{_u(c.unit)} at t = "
                       f"{best_t:.3f} s ({where}) {_verb(verdict)} {_limits_text(c)}",
                       starts.times(best_t) if verdict == FAIL else [])
    worst: float | None
    if c.reduce == "rms":
        value, worst = float(np.sqrt(total / n)), None
    elif c.reduce == "std":
        value, worst = float(np.sqrt(max(0.0, total_sq / n - (total / n) ** 2))), None
    elif c.reduce == "mean":
        value, worst = float(total / n), None
    else:  # final
        value, worst = x_last, t_last
    margin = float(band_margins(np.array([value]), c.limit)[0])
    verdict = grade(margin, c.marginal)
    at = worst if worst is not None else t_last
    return _result(c, value, margin, verdict, worst,
                   f"{c.reduce} of {c.target} ({where}) = {_fmt(value)}{_u(c.unit)} "
                   f"{_verb(verdict)} {_limits_text(c)}",
                   [at] if verdict == FAIL else [])


def _settles_core(c: Criterion, trigger: float) -> Generator[None, Any, CriterionResult]:
    """A ``settles:`` criterion: the first entry into the band that then stays ``stays_s``
    (segments carried across blocks); else the worst sample after trigger + within_s."""
    band, center, stays = c.params["band"], c.params["center"], c.params["stays_s"]
    u = c.params["channel_unit"]
    late_from = trigger + c.limit["max"] - 1e-9
    entry: float | None = None
    seg: float | None = None  # start time of the segment in the band at the last sample
    t_last = 0.0
    worst = [(-math.inf, 0.0, 0.0, False), (-math.inf, 0.0, 0.0, False)]  # all, late
    while (blk := (yield)) is not None:
        t, x = blk
        t_last = float(t[-1])
        if entry is not None:
            continue
        dev = np.abs(x - center)
        inside = dev <= band
        before = np.concatenate(([seg is not None], inside[:-1]))
        first = np.where(inside & ~before, np.arange(len(t)), -1)
        idx = np.maximum.accumulate(first)
        seg_t = np.where(idx >= 0, t[np.maximum(idx, 0)], math.nan if seg is None else seg)
        ok = inside & (t - seg_t >= stays - 1e-9)
        if ok.any():
            entry = float(seg_t[int(np.argmax(ok))])
            continue
        seg = float(seg_t[-1]) if inside[-1] else None
        for k, sel in enumerate((None, t >= late_from)):
            if sel is not None and not sel.any():
                continue
            i = int(np.argmax(dev if sel is None else np.where(sel, dev, -np.inf)))
            if not worst[k][3] or dev[i] > worst[k][0]:
                worst[k] = (float(dev[i]), float(t[i]), float(x[i]), True)
    what = f"{c.target} within {center:g} +- {band:g}{_u(u)} for {stays:g} s"
    if entry is None and seg is not None and seg - trigger <= c.limit["max"] + 1e-9:
        # in the band in time and still in it at the end, but the run ended before it had
        # stayed stays_s: too short to judge, not a failure to settle
        raise MissingData(
            f"{what}: in the band from t = {seg:.3f} s to the run's end at t = "
            f"{t_last:.3f} s; judging needs the run to last until t = {seg + stays:.3f} s")
    if entry is None:
        _, wt, wx, _ = worst[1] if worst[1][3] else worst[0]
        return _result(c, None, None, FAIL, wt,
                       f"{what}: never settled after t = {trigger:.3f} s (worst "
                       f"{_fmt(wx)}{_u(u)} at t = {wt:.3f} s)", [wt])
    value = round(entry - trigger, 9)  # sample times minus an event time: no float dust
    margin = c.limit["max"] - value
    verdict = grade(margin, c.marginal)
    return _result(c, value, margin, verdict, entry,
                   f"{what}: settled {_fmt(value)} s after t = {trigger:.3f} s "
                   f"{_verb(verdict)} within_s {c.limit['max']:g}", [entry] *
                   (verdict == FAIL))


def evaluate_channel(c: Criterion, measures: Mapping[str, Any]) -> Consumer:
    """A ``channel:`` criterion (reduce each / rms / mean / final over its window) as a
    consumer of its channel's blocks."""
    return _windowed(c, measures, lambda start: _channel_core(c, start))


def evaluate_settles(c: Criterion, measures: Mapping[str, Any]) -> Consumer:
    """A ``settles:`` criterion as a consumer of its channel's blocks."""
    return _windowed(c, measures, lambda start: _settles_core(c, start))


def _modal_core(c: Criterion, start: float) -> Generator[None, Any, CriterionResult]:
    """A ``modal_residual:`` criterion: its modes fitted to the window's samples (normal
    equations accumulated block by block), judged on the fitted modal part's peak."""
    fit = ModalResidualFit(c.params["modes"], start)
    while (blk := (yield)) is not None:
        fit.add(*blk)
    try:
        r = fit.result()
    except ValueError as exc:
        raise MissingData(f"{c.target}: {exc}") from exc
    margin = float(band_margins(np.array([r.peak]), c.limit)[0])
    verdict = grade(margin, c.marginal)
    at = start + r.peak_tau_s
    return _result(c, r.peak, margin, verdict, at,
                   f"{len(c.params['modes'])} modes fitted to {c.target} "
                   f"({c.window.describe()}, from t = {start:.3f} s): residual peak "
                   f"{_fmt(r.peak)} +- {r.sigma:.2g}{_u(c.unit)} (1 sigma; noise rms "
                   f"{r.noise_rms:.2g}) at t = {at:.3f} s {_verb(verdict)} {_limits_text(c)}",
                   [at] if verdict == FAIL else [])


def evaluate_modal_residual(c: Criterion, measures: Mapping[str, Any]) -> Consumer:
    """A ``modal_residual:`` criterion as a consumer of its channel's blocks."""
    return _windowed(c, measures, lambda start: _modal_core(c, start))


def evaluate_baseline(c: Criterion, facts: Facts) -> CriterionResult:
    t, x, _ = _samples(c, facts)
    base = c.params["baseline"]
    if facts.baseline_channel is None:
        raise MissingData("no baseline reader")
    try:
        tb, xb = facts.baseline_channel(base, c.target)
    except (KeyError, ValueError, OSError) as exc:
        raise MissingData(f"baseline {base}: {c.target} not readable: {exc}") from exc
    ok = ~np.isnan(xb)
    tb, xb = tb[ok], xb[ok]
    if len(tb) < 2:
        raise MissingData(f"baseline {base}: {c.target} has no samples")
    tol, rel = c.limit["tol"], c.limit["tol_rel_percent"] / 100.0
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    max_shift = c.limit["max_shift_s"]
    n = int(math.floor(max_shift / dt + 1e-9)) if dt > 0 else 0
    best: tuple[float, float, np.ndarray, np.ndarray, np.ndarray] | None = None
    for k in sorted(range(-n, n + 1), key=abs):
        shift = k * dt
        ts = t + shift
        cover = (ts >= tb[0] - 1e-9) & (ts <= tb[-1] + 1e-9)
        if cover.sum() < 0.9 * len(t):
            continue
        b = np.interp(ts[cover], tb, xb)
        excess = np.abs(x[cover] - b) - (tol + rel * np.abs(b))
        score = float(excess.max())
        if best is None or score < best[0] - 1e-15:
            best = (score, shift, excess, b, cover)
    if best is None:
        raise MissingData(f"baseline {base} covers t = {tb[0]:.3f}..{tb[-1]:.3f} s, less "
                          f"than 90 % of the judged window {t[0]:.3f}..{t[-1]:.3f} s")
    score, shift, excess, b, cover = best
    tc, xc = t[cover], x[cover]
    i = int(np.argmax(excess))
    dev = float(abs(xc[i] - b[i]))
    margin = -score
    verdict = grade(margin, c.marginal)
    worst = float(tc[i])
    tol_i = tol + rel * abs(float(b[i]))
    return _result(
        c, dev, margin, verdict, worst,
        f"{c.target} vs baseline {base}: worst deviation {_fmt(dev)}{_u(c.unit)} at t = "
        f"{worst:.3f} s (run {_fmt(float(xc[i]))}, baseline {_fmt(float(b[i]))}; tolerance "
        f"{_fmt(tol_i)}{_u(c.unit)}; time shift {shift:+.3f} s) {_verb(verdict)} tolerance",
        _Starts().feed(tc, excess > 0).times(worst) if verdict == FAIL else [])


def fault_ticks(measures: Mapping[str, Any], fault: Mapping[str, Any]) -> int | None:
    """Ticks from the earliest injected fault (its ``at_s``) to the detection of ``fault``."""
    inj = [f for f in measures.get("injected_faults") or []
           if float(f.get("at_s", math.inf)) <= float(fault["time_s"]) + 1e-9]
    rate = measures.get("rate_hz")
    if not inj or not rate:
        return None
    at = min(float(f["at_s"]) for f in inj)
    return int(fault["tick"]) - int(math.ceil(at * float(rate) - 1e-9))


def evaluate_fault(c: Criterion, facts: Facts) -> CriterionResult:
    faults = facts.measures.get("faults")
    if not isinstance(faults, list):
        raise MissingData("summary.json has no faults list")
    kind = c.params["kind"]
    match = [f for f in faults if f.get("device") == c.target and f.get("kind") == kind]
    seen = "; ".join(f"{f.get('device')}: {f.get('kind')}" for f in faults) or "none"
    if not match:
        return _result(c, None, None, FAIL, None,
                       f"fault {c.target}: {kind} not detected (detected: {seen})")
    f = match[0]
    ticks = fault_ticks(facts.measures, f)
    when = float(f["time_s"])
    if "max" not in c.limit:
        return _result(c, ticks, None, PASS, when,
                       f"fault {c.target}: {kind} detected at t = {when:.3f} s"
                       + (f", {ticks} ticks after injection" if ticks is not None else ""))
    if ticks is None:
        raise MissingData("within_ticks needs the injected fault's time (summary.json "
                          "injected_faults and rate_hz)")
    margin = float(c.limit["max"] - ticks)
    verdict = grade(margin, None)
    return _result(c, ticks, margin, verdict, when,
                   f"fault {c.target}: {kind} detected {ticks} ticks after injection "
                   f"(t = {when:.3f} s) {_verb(verdict)} within_ticks {c.limit['max']}",
                   [when] if verdict == FAIL else [])


def evaluate_left_safe(c: Criterion, facts: Facts) -> CriterionResult:
    if facts.left_safe is None:
        raise MissingData("no CAN log to check the last commands in")
    unsafe = facts.left_safe()
    n = len(unsafe)
    frames = facts.measures.get("frames")
    refused = frames.get("not_sent") if isinstance(frames, Mapping) else None
    why = (f" (the bus refused {refused} frames the harness sent, the safe state at the "
           "end among them when the bus had failed)"
           if isinstance(refused, int) and not isinstance(refused, bool) and refused > 0
           else "")
    return _result(c, n, float(-n), FAIL if n else PASS, None,
                   "rig left safe (last command of each device safe, heartbeat disarmed)"
                   if not n else "rig not left safe: " + "; ".join(unsafe) + why)


def scalar_worst_time(c: Criterion, measures: Mapping[str, Any]
                      ) -> Generator[None, Any, float | None]:
    """The time of the sample a summary peak or final came from (None if unknown), from
    the blocks of its channel (WORST_SAMPLE)."""
    how = WORST_SAMPLE[c.target][1]
    window = measures.get("residual_window_s")
    residual = how == "abs_residual" and isinstance(window, int | float)
    tail: deque[Block] = deque()
    best, best_t, found = -math.inf, 0.0, False
    last_t: float | None = None
    while (blk := (yield)) is not None:
        t, x = blk
        if not len(t):
            continue
        if residual:  # the blocks that can still be in the last ``window`` s
            tail.append((t, x))
            while tail and float(tail[0][0][-1]) < float(t[-1]) - float(window):
                tail.popleft()
            continue
        ok = ~np.isnan(x)
        if not ok.any():
            continue
        if how == "last":
            last_t = float(t[ok][-1])
            continue
        a = np.where(ok, np.abs(x), -np.inf)
        i = int(np.argmax(a))
        if not found or a[i] > best:
            best, best_t, found = float(a[i]), float(t[i]), True
    if residual and tail:
        t = np.concatenate([b[0] for b in tail])
        x = np.concatenate([b[1] for b in tail])
        ok = ~np.isnan(x) & (t >= t[-1] - float(window))
        if ok.any():
            return float(t[ok][int(np.argmax(np.abs(x[ok])))])
        return None
    if how == "last":
        return last_t
    return best_t if found else None


def _scalar_consumer(c: Criterion, measures: Mapping[str, Any], r: CriterionResult
                     ) -> Consumer:
    """A ``measure:`` result completed with the time of its sample, where the recording
    names it (an unreadable channel leaves it without)."""
    try:
        r.worst_time_s = yield from scalar_worst_time(c, measures)
    except MissingData:
        return r
    if r.verdict == FAIL and r.worst_time_s is not None:
        r.violations_s = [r.worst_time_s]
        r.message += f" (at t = {r.worst_time_s:.3f} s)"
    return r


def _scalar(c: Criterion, facts: Facts) -> tuple[CriterionResult, str | None]:
    """The result, and the channel to read for its sample's time (or None)."""
    r = evaluate_scalar(c, facts.measures)
    if r.worst_time_s is None and r.value is not None:
        if c.target == "settle_time_s":
            v = facts.measures.get("settle_time_s")
            r.worst_time_s = float(v) if isinstance(v, int | float) else None
            if r.verdict == FAIL and r.worst_time_s is not None:
                r.violations_s = [r.worst_time_s]
                r.message += f" (at t = {r.worst_time_s:.3f} s)"
        elif c.target in WORST_SAMPLE and (facts.channel or facts.blocks) is not None:
            return r, WORST_SAMPLE[c.target][0]
    return r, None


def evaluate_frf(c: Criterion, facts: Facts) -> CriterionResult:
    """An ``frf:`` criterion (harness.testing.frf_criterion)."""
    from harness.testing.frf_criterion import judge_frf

    if facts.frf is None:
        raise MissingData("no run directory to measure the frequency response of")
    result: CriterionResult = judge_frf(c, facts.frf)
    return result


EVALUATORS: dict[str, Callable[[Criterion, Facts], CriterionResult]] = {
    "frf": evaluate_frf,
    "baseline": evaluate_baseline,
    "fault": evaluate_fault,
    "left_safe": evaluate_left_safe,
}
"""The forms judged from whole data; ``scalar``, ``channel`` and ``settles`` stream."""
STREAMED: dict[str, Callable[[Criterion, Mapping[str, Any]], Consumer]] = {
    "channel": evaluate_channel,
    "settles": evaluate_settles,
    "modal_residual": evaluate_modal_residual,
}


@dataclass
class _Reader:
    """One criterion reading a channel: how to start it, and its consumer while running."""

    index: int
    criterion: Criterion
    start: Callable[[], Consumer]
    gen: Consumer | None = None


def evaluate(criteria: Sequence[Criterion], facts: Facts) -> list[CriterionResult]:
    """Every criterion; missing data gives that criterion ERROR (never an exception). The
    criteria that read channels are judged in one pass over the recording's blocks
    (``facts.blocks``; or each ``facts.channel`` whole, as one block), in bounded memory."""
    out: list[CriterionResult | None] = [None] * len(criteria)
    readers: dict[str, list[_Reader]] = {}
    for i, c in enumerate(criteria):
        try:
            if c.kind == "scalar":
                r, entity = _scalar(c, facts)
                out[i] = r
                if entity is not None:
                    readers.setdefault(entity, []).append(_Reader(
                        i, c, lambda c=c, r=r: _scalar_consumer(c, facts.measures, r)))
            elif c.kind in STREAMED:
                if facts.channel is None and facts.blocks is None:
                    raise MissingData(f"no recording to read {c.target} from")
                readers.setdefault(c.target, []).append(_Reader(
                    i, c, lambda c=c: STREAMED[c.kind](c, facts.measures)))
            else:
                out[i] = EVALUATORS[c.kind](c, facts)
        except MissingData as exc:
            out[i] = _error(c, f"missing data: {exc}")
    if readers:
        _read_channels(readers, facts, out)
    assert all(r is not None for r in out)
    return out  # type: ignore[return-value]


def _send(rd: _Reader, blk: Block | None, out: list[CriterionResult | None]) -> None:
    if rd.gen is None:
        return
    try:
        rd.gen.send(blk)
    except StopIteration as stop:
        out[rd.index], rd.gen = stop.value, None
    except MissingData as exc:
        out[rd.index], rd.gen = _error(rd.criterion, f"missing data: {exc}"), None


def _throw(rd: _Reader, exc: MissingData, out: list[CriterionResult | None]) -> None:
    if rd.gen is None:
        return
    try:
        rd.gen.throw(exc)
    except StopIteration as stop:
        out[rd.index] = stop.value
    except MissingData as err:
        out[rd.index] = _error(rd.criterion, f"missing data: {err}")
    rd.gen = None


def _whole_blocks(facts: Facts, entities: list[str]) -> Iterator[tuple[str, np.ndarray,
                                                                       np.ndarray]]:
    assert facts.channel is not None
    for e in entities:
        try:
            t, x = facts.channel(e)
        except (KeyError, ValueError, OSError):
            continue  # not seen: the reader asks again for the message
        yield e, t, x


def _read_channels(readers: dict[str, list[_Reader]], facts: Facts,
                   out: list[CriterionResult | None]) -> None:
    """Feeds every reader its channel's blocks in one pass. A channel whose blocks go back
    in time is judged again from the whole channel, sorted (as read whole)."""
    for rds in readers.values():
        for rd in rds:
            rd.gen = _started(rd.start())
    last: dict[str, float] = {}
    unordered: set[str] = set()
    blocks = facts.blocks(sorted(readers)) if facts.blocks is not None \
        else _whole_blocks(facts, sorted(readers))
    try:
        for e, t, x in blocks:
            if e not in readers or e in unordered:
                continue
            if len(t) and (t[0] < last.get(e, -math.inf) or bool(np.any(np.diff(t) < 0))):
                unordered.add(e)
                warnings.warn(f"{e}: recorded blocks not in time order; judged from the "
                              "whole channel", stacklevel=2)
                continue
            if len(t):
                last[e] = float(t[-1])
            for rd in readers[e]:
                _send(rd, (t, x), out)
    except MissingData as exc:  # the recording cannot be read (any more)
        for rds in readers.values():
            for rd in rds:
                _throw(rd, exc, out)
        return
    for e, rds in readers.items():
        if e in last and e not in unordered:
            for rd in rds:
                _send(rd, None, out)
            continue
        try:  # not seen in the pass (or out of order): the channel whole, or why not
            if facts.channel is None:
                raise KeyError(f"no channel {e}")
            t, x = facts.channel(e)
        except (KeyError, ValueError, OSError) as exc:
            err = MissingData(f"channel {e} not readable: {exc}")
            for rd in rds:
                _throw(rd, err, out)
            continue
        except MissingData as err:
            for rd in rds:
                _throw(rd, err, out)
            continue
        for rd in rds:
            if e in unordered:
                rd.gen = _started(rd.start())
            _send(rd, (t, x), out)
            _send(rd, None, out)


def run_checks(criteria: Sequence[Criterion], measures: Mapping[str, Any]
               ) -> list[CriterionResult]:
    """Checks of the run itself, beside the criteria: it raised, it was interrupted, or a
    fault stopped it that no ``fault:`` criterion expects (each an ERROR record)."""
    out: list[CriterionResult] = []
    stopped = measures.get("stopped_by")
    if stopped == "error":
        out.append(CriterionResult("run", "run", stopped, "", {}, None, ERROR, None,
                                   f"the run raised: {measures.get('error') or '?'}"))
    elif stopped == "interrupted":
        out.append(CriterionResult("run", "run", stopped, "", {}, None, ERROR, None,
                                   f"the run was interrupted ({measures.get('error') or '?'})",
                                   cause="interrupted"))
    expected = {(c.target, c.params["kind"]) for c in criteria if c.kind == "fault"}
    for f in measures.get("faults") or []:
        if (f.get("device"), f.get("kind")) not in expected:
            t = f.get("time_s")
            out.append(CriterionResult(
                "unexpected_fault", "fault", f"{f.get('device')}: {f.get('kind')}", "", {},
                None, ERROR, t, f"fault the run did not expect: {f.get('device')}: "
                f"{f.get('kind')}: {f.get('message', '')}"
                + (f" (t = {float(t):.3f} s)" if t is not None else ""),
                cause="fault", violations_s=[float(t)] if t is not None else []))
    return out


def run_verdict(verdicts: Iterable[str]) -> str:
    """One run's verdict from its criteria's: ERROR if any (the run or the judge broke),
    else INCONCLUSIVE if any (the bench lost its time: a FAIL measured then is not
    trusted, nor is a pass), else the worst (PASS < MARGINAL < FAIL)."""
    seen = set(verdicts)
    if ERROR in seen:
        return ERROR
    if INCONCLUSIVE in seen:
        return INCONCLUSIVE
    return max(seen, key=SEVERITY.__getitem__, default=PASS)


def worst_verdict(results: Sequence[CriterionResult]) -> str:
    """A run's verdict (``run_verdict``) from its criteria's judged results; nothing but
    NOT JUDGED is an ERROR (the run stopped)."""
    judged = [r.verdict for r in results if r.verdict != NOT_JUDGED]
    if results and not judged:
        return ERROR
    return run_verdict(judged)

def stopped_early(measures: Mapping[str, Any]) -> str | None:
    """Why the run stopped before its end (a fault, an interruption, an error), or None."""
    stopped = measures.get("stopped_by")
    if stopped == "fault":
        faults = [f for f in measures.get("faults") or [] if isinstance(f, Mapping)]
        if faults:
            f = faults[0]
            t = f.get("time_s")
            at = f" at t = {float(t):.3f} s" if isinstance(t, int | float) else ""
            return f"a fault ({f.get('device')}: {f.get('kind')}){at} stopped the run"
        return "a fault stopped the run"
    if stopped == "interrupted":
        return "the run was interrupted"
    if stopped == "error":
        return "the run raised an error"
    return None


def not_judged(c: Criterion, why: str, ending: str = " before its end") -> CriterionResult:
    """A criterion left unjudged on a run stopped early, a fault test or a dry run (see
    NOT_JUDGED)."""
    return CriterionResult(c.name, c.kind, None, c.unit, limit_dict(c), None, NOT_JUDGED,
                           None, f"not judged: {why}{ending}; this criterion does "
                           "not apply to a stopped run (applies_to_stopped: true judges it)",
                           c.why)


def exit_code(verdict: str, results: Sequence[CriterionResult]) -> int:
    """0 PASS (or NO CRITERIA), 1 FAIL, 3 ERROR by an unexpected fault, 4 ERROR otherwise,
    5 MARGINAL, 6 INCONCLUSIVE, 130 interrupted."""
    if verdict == ERROR:
        causes = {r.cause for r in results if r.verdict == ERROR}
        return 130 if "interrupted" in causes else 3 if "fault" in causes else 4
    return {PASS: 0, MARGINAL: 5, FAIL: 1, INCONCLUSIVE: INCONCLUSIVE_EXIT,
            NO_CRITERIA: 0}[verdict]


def reason(verdict: str, results: Sequence[CriterionResult]) -> str:
    if not results:
        return "no criteria: nothing was judged (the run has no expect: criteria)"
    worst = [r for r in results if r.verdict == verdict]
    if verdict == PASS:
        return f"all {len(results)} criteria passed"
    first = f"{worst[0].name}: {worst[0].message}"
    text = first if len(worst) == 1 else f"{len(worst)} criteria {verdict}; first: {first}"
    if verdict == INCONCLUSIVE:
        failed = [r.name for r in results if r.verdict == FAIL]
        text = "the bench did not hold real time: " + text + (
            f"; not trusted, measured on that bench: {', '.join(failed)} FAIL" if failed
            else "")
    return text
