"""Evaluating parsed criteria: pure functions of measures, channels and facts (no files).

A criterion's result is a record that is data (OpenHTF's measurement record): its value and
unit, its limits (keys with their unit, as in the run file), its margin (distance to the
nearest limit in the value's unit, positive inside), its verdict, the time of the worst
sample and a one-line message. Verdicts: PASS, MARGINAL (passed, inside the marginal band),
FAIL, ERROR (the run or the harness broke, the data is missing, or a real-time budget
criterion failed). The worst wins.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from harness.testing.criteria import Criterion, Window
from harness.testing.measures import NULL_MEANS_FAIL, WORST_SAMPLE, FieldMissing, find

PASS, MARGINAL, FAIL, ERROR = "PASS", "MARGINAL", "FAIL", "ERROR"
SEVERITY = {PASS: 0, MARGINAL: 1, FAIL: 2, ERROR: 3}

Channel = Callable[[str], tuple[np.ndarray, np.ndarray]]
"""entity -> (time s, values); raises KeyError/ValueError if the channel is missing."""
BaselineChannel = Callable[[str, str], tuple[np.ndarray, np.ndarray]]
"""(baseline path, entity) -> (time s, values)."""

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
    baseline_channel: BaselineChannel | None = None
    left_safe: Callable[[], list[str]] | None = None
    """-> what was not left safe (empty: safe); raises MissingData without a CAN log."""


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


def limit_dict(c: Criterion) -> dict[str, Any]:
    """The limits as written in the run file (keys with their unit)."""
    if c.kind in ("scalar", "channel"):
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
        verdict = ERROR
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
            not math.isfinite(float(value)):
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
    unit = "" if c.unit in ("ratio", "count") else f" {c.unit}"
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


def _violation_starts(t: np.ndarray, bad: np.ndarray, worst: float | None) -> list[float]:
    starts = np.nonzero(bad & ~np.concatenate(([False], bad[:-1])))[0]
    out = [float(t[i]) for i in starts[:MAX_EVENTS - 1]]
    if worst is not None and worst not in out:
        out.append(worst)
    return out


def evaluate_channel(c: Criterion, facts: Facts) -> CriterionResult:
    t, x, _ = _samples(c, facts)
    where = c.window.describe()
    if c.reduce == "each":
        margins = band_margins(x, c.limit)
        i = int(np.argmin(margins))
        margin = float(margins[i])
        verdict = grade(margin, c.marginal)
        worst = float(t[i])
        violations = _violation_starts(t, margins < 0, worst) if verdict == FAIL else []
        return _result(c, float(x[i]), margin, verdict, worst,
                       f"{c.target} worst sample {_fmt(float(x[i]))} {c.unit} at t = "
                       f"{worst:.3f} s ({where}) {_verb(verdict)} {_limits_text(c)}",
                       violations)
    if c.reduce == "rms":
        value, worst = float(np.sqrt(np.mean(x ** 2))), None
    elif c.reduce == "mean":
        value, worst = float(np.mean(x)), None
    else:  # final
        value, worst = float(x[-1]), float(t[-1])
    margin = float(band_margins(np.array([value]), c.limit)[0])
    verdict = grade(margin, c.marginal)
    at = worst if worst is not None else float(t[-1])
    return _result(c, value, margin, verdict, worst,
                   f"{c.reduce} of {c.target} ({where}) = {_fmt(value)} {c.unit} "
                   f"{_verb(verdict)} {_limits_text(c)}",
                   [at] if verdict == FAIL else [])


def evaluate_settles(c: Criterion, facts: Facts) -> CriterionResult:
    t, x, trigger = _samples(c, facts)
    band, center, stays = c.params["band"], c.params["center"], c.params["stays_s"]
    u = c.params["channel_unit"]
    inside = np.abs(x - center) <= band
    # segments of consecutive samples inside the band
    edges = np.diff(np.concatenate(([0], inside.astype(np.int8), [0])))
    starts, ends = np.nonzero(edges == 1)[0], np.nonzero(edges == -1)[0] - 1
    entry = None
    for a, b in zip(starts, ends, strict=True):
        if t[b] - t[a] >= stays - 1e-9:
            entry = float(t[a])
            break
    what = f"{c.target} within {center:g} +- {band:g} {u} for {stays:g} s"
    if entry is None and len(starts) and ends[-1] == len(t) - 1 \
            and t[starts[-1]] - trigger <= c.limit["max"] + 1e-9:
        # in the band in time and still in it at the end, but the run ended before it had
        # stayed stays_s: too short to judge, not a failure to settle
        a = float(t[starts[-1]])
        raise MissingData(
            f"{what}: in the band from t = {a:.3f} s to the run's end at t = "
            f"{float(t[-1]):.3f} s; judging needs the run to last until t = {a + stays:.3f} s")
    if entry is None:
        dev = np.abs(x - center)
        late = t >= trigger + c.limit["max"] - 1e-9
        sel = late if late.any() else np.ones_like(late)
        i = int(np.argmax(np.where(sel, dev, -np.inf)))
        return _result(c, None, None, FAIL, float(t[i]),
                       f"{what}: never settled after t = {trigger:.3f} s (worst "
                       f"{_fmt(float(x[i]))} {u} at t = {float(t[i]):.3f} s)",
                       [float(t[i])])
    value = round(entry - trigger, 9)  # sample times minus an event time: no float dust
    margin = c.limit["max"] - value
    verdict = grade(margin, c.marginal)
    return _result(c, value, margin, verdict, entry,
                   f"{what}: settled {_fmt(value)} s after t = {trigger:.3f} s "
                   f"{_verb(verdict)} within_s {c.limit['max']:g}", [entry] *
                   (verdict == FAIL))


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
        f"{c.target} vs baseline {base}: worst deviation {_fmt(dev)} {c.unit} at t = "
        f"{worst:.3f} s (run {_fmt(float(xc[i]))}, baseline {_fmt(float(b[i]))}; tolerance "
        f"{_fmt(tol_i)} {c.unit}; time shift {shift:+.3f} s) {_verb(verdict)} tolerance",
        _violation_starts(tc, excess > 0, worst) if verdict == FAIL else [])


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
    return _result(c, n, float(-n), FAIL if n else PASS, None,
                   "rig left safe (last command of each device safe, heartbeat disarmed)"
                   if not n else "rig not left safe: " + "; ".join(unsafe))


def scalar_worst_time(c: Criterion, facts: Facts) -> float | None:
    """The time of the sample a summary peak or final came from (None if unknown)."""
    if c.target == "settle_time_s":
        v = facts.measures.get("settle_time_s")
        return float(v) if isinstance(v, int | float) else None
    if c.target not in WORST_SAMPLE or facts.channel is None:
        return None
    entity, how = WORST_SAMPLE[c.target]
    try:
        t, x = facts.channel(entity)
    except (KeyError, ValueError, OSError, MissingData):
        return None
    ok = ~np.isnan(x)
    if how == "abs_residual":
        window = facts.measures.get("residual_window_s")
        if isinstance(window, int | float) and len(t):
            ok &= t >= t[-1] - float(window)
    if not ok.any():
        return None
    t, x = t[ok], x[ok]
    return float(t[-1]) if how == "last" else float(t[int(np.argmax(np.abs(x)))])


def _scalar(c: Criterion, facts: Facts) -> CriterionResult:
    r = evaluate_scalar(c, facts.measures)
    if r.worst_time_s is None and r.value is not None:
        r.worst_time_s = scalar_worst_time(c, facts)
        if r.verdict == FAIL and r.worst_time_s is not None:
            r.violations_s = [r.worst_time_s]
            r.message += f" (at t = {r.worst_time_s:.3f} s)"
    return r


EVALUATORS: dict[str, Callable[[Criterion, Facts], CriterionResult]] = {
    "scalar": _scalar,
    "channel": evaluate_channel,
    "settles": evaluate_settles,
    "baseline": evaluate_baseline,
    "fault": evaluate_fault,
    "left_safe": evaluate_left_safe,
}


def evaluate(criteria: Sequence[Criterion], facts: Facts) -> list[CriterionResult]:
    """Every criterion; missing data gives that criterion ERROR (never an exception)."""
    out = []
    for c in criteria:
        try:
            out.append(EVALUATORS[c.kind](c, facts))
        except MissingData as exc:
            out.append(_error(c, f"missing data: {exc}"))
    return out


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


def worst_verdict(results: Sequence[CriterionResult]) -> str:
    return max((r.verdict for r in results), key=SEVERITY.__getitem__, default=PASS)


def exit_code(verdict: str, results: Sequence[CriterionResult]) -> int:
    """0 PASS, 1 FAIL, 3 ERROR by an unexpected fault, 4 ERROR otherwise, 5 MARGINAL,
    130 interrupted."""
    if verdict == ERROR:
        causes = {r.cause for r in results if r.verdict == ERROR}
        return 130 if "interrupted" in causes else 3 if "fault" in causes else 4
    return {PASS: 0, MARGINAL: 5, FAIL: 1}[verdict]


def reason(verdict: str, results: Sequence[CriterionResult]) -> str:
    if not results:
        return "no criteria"
    worst = [r for r in results if r.verdict == verdict]
    if verdict == PASS:
        return f"all {len(results)} criteria passed"
    first = f"{worst[0].name}: {worst[0].message}"
    return first if len(worst) == 1 else f"{len(worst)} criteria {verdict}; first: {first}"
