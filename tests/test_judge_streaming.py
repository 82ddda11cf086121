"""Judging streams the recording: the channel forms fed block by block (chunk boundaries
anywhere: inside a violation, inside the settling segment, windows starting and ending
mid-block, ``last_s``, NaN samples) give the results the whole-array code gave. The
reference below is that code (before streaming), kept here as the oracle."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from harness.testing import Facts, evaluate, parse_criteria
from harness.testing.evaluate import (
    FAIL,
    MAX_EVENTS,
    CriterionResult,
    MissingData,
    _error,
    _fmt,
    _limits_text,
    _result,
    _verb,
    band_margins,
    evaluate_scalar,
    grade,
    window_mask,
)
from harness.testing.measures import WORST_SAMPLE, unit_text

ROOT = Path(__file__).resolve().parents[1]


# ------------------------------------------------------------ the whole-array reference
def _ref_samples(c, measures, t, x):
    mask, start = window_mask(t, c.window, measures)
    mask &= ~np.isnan(x)
    if not mask.any():
        raise MissingData(f"no {c.target} samples in the window ({c.window.describe()})")
    return t[mask], x[mask], start


def _ref_violation_starts(t, bad, worst):
    starts = np.nonzero(bad & ~np.concatenate(([False], bad[:-1])))[0]
    out = [float(t[i]) for i in starts[:MAX_EVENTS - 1]]
    if worst is not None and worst not in out:
        out.append(worst)
    return out


def _ref_channel(c, measures, t, x):
    t, x, _ = _ref_samples(c, measures, t, x)
    where = c.window.describe()
    if c.reduce == "each":
        margins = band_margins(x, c.limit)
        i = int(np.argmin(margins))
        margin = float(margins[i])
        verdict = grade(margin, c.marginal)
        worst = float(t[i])
        violations = _ref_violation_starts(t, margins < 0, worst) if verdict == FAIL else []
        return _result(c, float(x[i]), margin, verdict, worst,
                       f"{c.target} worst sample {_fmt(float(x[i]))} {unit_text(c.unit)} at t = "
                       f"{worst:.3f} s ({where}) {_verb(verdict)} {_limits_text(c)}",
                       violations)
    if c.reduce == "rms":
        value, worst = float(np.sqrt(np.mean(x ** 2))), None
    elif c.reduce == "std":
        value, worst = float(np.std(x)), None
    elif c.reduce == "mean":
        value, worst = float(np.mean(x)), None
    else:
        value, worst = float(x[-1]), float(t[-1])
    margin = float(band_margins(np.array([value]), c.limit)[0])
    verdict = grade(margin, c.marginal)
    at = worst if worst is not None else float(t[-1])
    return _result(c, value, margin, verdict, worst,
                   f"{c.reduce} of {c.target} ({where}) = {_fmt(value)} {unit_text(c.unit)} "
                   f"{_verb(verdict)} {_limits_text(c)}", [at] if verdict == FAIL else [])


def _ref_settles(c, measures, t, x):
    t, x, trigger = _ref_samples(c, measures, t, x)
    band, center, stays = c.params["band"], c.params["center"], c.params["stays_s"]
    u = c.params["channel_unit"]
    inside = np.abs(x - center) <= band
    edges = np.diff(np.concatenate(([0], inside.astype(np.int8), [0])))
    starts, ends = np.nonzero(edges == 1)[0], np.nonzero(edges == -1)[0] - 1
    entry = None
    for a, b in zip(starts, ends, strict=True):
        if t[b] - t[a] >= stays - 1e-9:
            entry = float(t[a])
            break
    what = f"{c.target} within {center:g} +- {band:g} {unit_text(u)} for {stays:g} s"
    if entry is None and len(starts) and ends[-1] == len(t) - 1 \
            and t[starts[-1]] - trigger <= c.limit["max"] + 1e-9:
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
                       f"{_fmt(float(x[i]))} {unit_text(u)} at t = {float(t[i]):.3f} s)",
                       [float(t[i])])
    value = round(entry - trigger, 9)
    margin = c.limit["max"] - value
    verdict = grade(margin, c.marginal)
    return _result(c, value, margin, verdict, entry,
                   f"{what}: settled {_fmt(value)} s after t = {trigger:.3f} s "
                   f"{_verb(verdict)} within_s {c.limit['max']:g}", [entry] * (verdict == FAIL))


def _ref_scalar(c, measures, channels):
    r = evaluate_scalar(c, measures)
    if r.worst_time_s is not None or r.value is None or c.target not in WORST_SAMPLE:
        return r
    entity, how = WORST_SAMPLE[c.target]
    t, x = channels[entity]
    ok = ~np.isnan(x)
    if how == "abs_residual":
        window = measures.get("residual_window_s")
        if isinstance(window, int | float) and len(t):
            ok &= t >= t[-1] - float(window)
    if ok.any():
        t, x = t[ok], x[ok]
        r.worst_time_s = float(t[-1]) if how == "last" else float(t[int(np.argmax(np.abs(x)))])
        if r.verdict == FAIL:
            r.violations_s = [r.worst_time_s]
            r.message += f" (at t = {r.worst_time_s:.3f} s)"
    return r


def reference(criteria, measures, channels) -> list[CriterionResult]:
    out = []
    for c in criteria:
        try:
            if c.kind == "scalar":
                out.append(_ref_scalar(c, measures, channels))
            else:
                f = _ref_channel if c.kind == "channel" else _ref_settles
                out.append(f(c, measures, *channels[c.target]))
        except MissingData as exc:
            out.append(_error(c, f"missing data: {exc}"))
    return out


# ------------------------------------------------------------------------ the data
RATE = 500.0
T = np.arange(0, 30.0, 1 / RATE)


def _channels() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(7)
    accel = 0.05 * np.sin(2 * np.pi * 1.3 * T) + 0.002 * rng.normal(size=len(T))
    for k in range(14):  # more violation episodes than MAX_EVENTS, of various lengths
        a = 1.0 + 1.7 * k
        accel[(T >= a) & (T < a + 0.05 * (k + 1))] = 0.3 + 0.01 * k
    accel[rng.choice(len(T), 40, replace=False)] = np.nan
    accel[-3:] = np.nan  # a channel that ends on NaN samples
    err = 3.0 * np.exp(-(T - 2.0).clip(0)) * np.cos(5 * T)
    err[(T > 9.3) & (T < 9.31)] = 0.5  # leaves the band once after a first entry
    err[(T > 20.0) & (T < 20.1)] = -0.5  # and once more, flat: equal worst samples
    err[rng.choice(len(T), 25, replace=False)] = np.nan
    err[-1] = np.nan
    torque = np.where(T < 2.0, 0.05, 0.0) + 0.001 * np.sin(T)
    torque[4321] = -0.07  # the peak, mid-block
    torque[4400] = 0.07  # as large, later: the first one counts
    return {"/tip/accel_m_s2": (T, accel), "/attitude/error_deg": (T, err),
            "/wheel/torque_cmd_n_m": (T, torque)}


MEASURES = {"run": "x", "rate_hz": RATE, "stopped_by": "completed", "slew_profile_end_s": 2.0,
            "faults": [], "injected_faults": [], "residual_window_s": 6.0,
            "peak_tip_accel_m_s2": 0.43, "residual_tip_accel_m_s2": 0.4,
            "max_wheel_torque_cmd_n_m": 0.07, "final_angle_error_deg": 0.001}

ACC, ERR = "/tip/accel_m_s2", "/attitude/error_deg"
CRITERIA = {
    "each": {"channel": ACC, "max_abs_m_s2": 0.2},
    "each_pass": {"channel": ACC, "max_abs_m_s2": 0.5, "marginal_m_s2": 0.2},
    "each_min": {"channel": ACC, "min_m_s2": -0.04, "from_s": 3.1234, "to_s": 17.0011},
    "after": {"channel": ACC, "max_abs_m_s2": 0.2, "after": "slew_profile_end_s",
              "from_s": 4.0037, "to_s": 9.9991},
    "last": {"channel": ACC, "max_abs_m_s2": 0.2, "last_s": 7.3},
    "last_rms": {"channel": ACC, "reduce": "rms", "max_m_s2": 0.05, "last_s": 12.345},
    "rms": {"channel": ACC, "reduce": "rms", "max_m_s2": 0.05},
    "std": {"channel": ACC, "reduce": "std", "max_m_s2": 0.05, "last_s": 12.345},
    "mean": {"channel": ACC, "reduce": "mean", "max_abs_m_s2": 0.01, "from_s": 0.7771},
    "final": {"channel": ERR, "reduce": "final", "max_abs_deg": 1e-6},
    "final_window": {"channel": ERR, "reduce": "final", "max_abs_deg": 0.1, "to_s": 12.345},
    "empty_window": {"channel": ACC, "max_abs_m_s2": 0.2, "from_s": 40.0},
    "settles": {"settles": ERR, "band_deg": 0.1, "after": "slew_profile_end_s",
                "within_s": 11.1, "stays_s": 3.0},
    "settles_late": {"settles": ERR, "band_deg": 0.1, "within_s": 5.0, "stays_s": 3.0},
    "settles_never": {"settles": ERR, "band_deg": 0.1, "center_deg": 1.0, "within_s": 5.0,
                      "stays_s": 3.0},
    "settles_never_late": {"settles": ERR, "band_deg": 0.1, "center_deg": 1.0,
                           "within_s": 50.0, "stays_s": 3.0},
    "settles_short": {"settles": ERR, "band_deg": 0.1, "within_s": 25.0, "stays_s": 25.0},
    "settles_from": {"settles": ERR, "band_deg": 0.1, "within_s": 1.0, "stays_s": 2.0,
                     "after": "slew_profile_end_s", "from_s": 5.4321},
    "peak": {"measure": "peak_tip_accel_m_s2", "max_m_s2": 0.4},
    "residual": {"measure": "residual_tip_accel_m_s2", "max_m_s2": 0.3},
    "torque": {"measure": "max_wheel_torque_cmd_n_m", "max_n_m": 0.065},
    "final_error": {"measure": "final_angle_error_deg", "max_abs_deg": 0.0001},
}


def _blocks(channels, sizes):
    """(entity, t, x) blocks as the recording's chunks come: entities interleaved, each
    cut at ``sizes`` (cycled)."""
    cuts = {}
    for e, (t, _) in channels.items():
        edges, k, i = [0], 0, 0
        while edges[-1] < len(t):
            edges.append(min(len(t), edges[-1] + sizes[i % len(sizes)]))
            i += 1
        cuts[e] = edges
        k = max(k, len(edges))
    for j in range(max(len(v) for v in cuts.values()) - 1):
        for e, edges in cuts.items():
            if j + 1 < len(edges):
                t, x = channels[e]
                yield e, t[edges[j]:edges[j + 1]], x[edges[j]:edges[j + 1]]


def _same(got: CriterionResult, want: CriterionResult, rel: float = 0.0) -> None:
    assert (got.name, got.verdict, got.worst_time_s, got.violations_s) == \
        (want.name, want.verdict, want.worst_time_s, want.violations_s), got.name
    assert got.message == want.message, got.name
    for a, b in ((got.value, want.value), (got.margin, want.margin)):
        if rel and isinstance(b, float):
            assert a == pytest.approx(b, rel=rel, abs=1e-15), got.name
        else:
            assert a == b, got.name


@pytest.mark.parametrize("sizes", [[500], [1], [37, 500, 3, 1024, 11], [len(T)]])
def test_streamed_forms_equal_the_whole_array_results(sizes: list[int]) -> None:
    channels = _channels()
    crits = parse_criteria(CRITERIA, "t")
    want = reference(crits, MEASURES, channels)
    got = evaluate(crits, Facts(MEASURES, blocks=lambda es: _blocks(
        {e: channels[e] for e in es}, sizes)))
    by_name = {r.name: r for r in want}
    for r in got:  # sums in blocks: the rms and mean may differ in their last digits
        _same(r, by_name[r.name], rel=1e-11 if r.name in ("rms", "last_rms", "mean", "std") else 0)
    # the cases are what they say
    assert by_name["each"].verdict == FAIL and len(by_name["each"].violations_s) == MAX_EVENTS
    assert by_name["settles"].verdict != FAIL
    assert "never settled" in by_name["settles_never"].message
    assert by_name["settles_never"].worst_time_s == T[T > 20.0][0]
    assert "never settled" in by_name["settles_never_late"].message
    assert "judging needs the run to last" in by_name["settles_short"].message
    assert "no /tip/accel_m_s2 samples in the window" in by_name["empty_window"].message
    assert by_name["torque"].worst_time_s == T[4321]
    assert by_name["final_error"].worst_time_s == T[-2]  # the last sample is NaN
    # one block (as ``Facts.channel`` gives): the sums are the same sums, exactly
    got = evaluate(crits, Facts(MEASURES, channel=lambda e: channels[e]))
    for r in got:
        _same(r, by_name[r.name])


def test_blocks_out_of_time_order_are_judged_whole() -> None:
    channels = _channels()
    crits = parse_criteria(CRITERIA, "t")
    want = {r.name: r for r in reference(crits, MEASURES, channels)}

    def shuffled(es):
        blocks = list(_blocks({e: channels[e] for e in es}, [500]))
        blocks[3], blocks[7] = blocks[7], blocks[3]
        return iter(blocks)

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        got = evaluate(crits, Facts(MEASURES, channel=lambda e: channels[e], blocks=shuffled))
    assert any("not in time order" in str(w.message) for w in caught)
    for r in got:
        _same(r, want[r.name])


def test_missing_channel_and_unreadable_recording() -> None:
    crits = parse_criteria({k: CRITERIA[k] for k in ("each", "settles", "peak")}, "t")

    def no_channels(es):
        return iter(())

    def channel(e):
        raise KeyError(f"run.rrd has no channel {e}")

    each, settles, peak = evaluate(crits, Facts(MEASURES, channel=channel,
                                                blocks=no_channels))
    assert each.message == "missing data: channel /tip/accel_m_s2 not readable: " \
        "'run.rrd has no channel /tip/accel_m_s2'"
    assert settles.verdict == "ERROR" and peak.verdict == FAIL and peak.worst_time_s is None

    def broken(es):
        yield from _blocks({e: _channels()[e] for e in es}, [500])
        raise MissingData("run.rrd: cannot read (x)")

    each, settles, peak = evaluate(crits, Facts(MEASURES, blocks=broken))
    assert each.message == settles.message == "missing data: run.rrd: cannot read (x)"
    assert peak.worst_time_s is None and not math.isnan(peak.value)


# ------------------------------------------------------------------------ memory
_JUDGE_TWICE = """
import json, resource, sys
from harness.testing import judge_run, write_verdict
def judge(run_dir):
    v = judge_run(run_dir)
    write_verdict(v, run_dir)
    return [c.verdict for c in v.criteria]
first = judge(sys.argv[1])  # warm-up: imports, the reader, a first pass
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
second = judge(sys.argv[2])
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(json.dumps({"growth_kb": peak - base, "verdicts": second}))
"""


def _recorded_run(run_dir: Path, seconds: float) -> Path:
    """A run directory with a recording of ``seconds`` at 500 Hz written as harness.record.recording
    writes a run's (blocks of 500 rows), and the criteria that read channels."""
    import json as json_

    import yaml

    from harness.record.recording import Recorder

    run_dir.mkdir()
    expect = {
        "settles": {"settles": ERR, "band_deg": 0.1, "after": "slew_profile_end_s",
                    "within_s": 11.1, "stays_s": 10},
        "accel": {"channel": ACC, "max_abs_m_s2": 0.5, "after": "slew_profile_end_s"},
        "accel_rms": {"channel": ACC, "reduce": "rms", "max_m_s2": 0.1, "last_s": 6.0},
        "peak": {"measure": "peak_tip_accel_m_s2", "max_m_s2": 0.4},
        "final_error": {"measure": "final_angle_error_deg", "max_abs_deg": 0.1},
    }
    (run_dir / "config.yaml").write_text(yaml.safe_dump({"run": {"name": "mem",
                                                                 "expect": expect}}))
    (run_dir / "summary.json").write_text(json_.dumps(dict(MEASURES, ticks=0)))
    rec = Recorder(run_dir / "run.rrd", [ERR, ACC], 0, run_dir.name)
    for k in range(int(seconds * RATE)):
        t = k / RATE
        row = rec.row(t)
        row[0] = 3.0 * math.exp(-t) * math.cos(5 * t)
        row[1] = 0.05 * math.sin(8.0 * t)
        rec.commit()
        if k % 500 == 499:
            rec.drain()
    rec.close()
    return run_dir


@pytest.mark.slow
def test_judging_memory_does_not_grow_with_recording_length(tmp_path: Path) -> None:
    """In fresh processes: judging a 4000 s recording after a 20 s one grows no more than
    judging the 20 s one again (whole channels read into arrays: 139 MB more; streamed: 0)."""
    short = _recorded_run(tmp_path / "short", 20.0)
    long = _recorded_run(tmp_path / "long", 4000.0)
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    got = {}
    for name, second in (("short", short), ("long", long)):
        out = subprocess.run([sys.executable, "-c", _JUDGE_TWICE, str(short), str(second)],
                             cwd=ROOT, env=env, capture_output=True, text=True, check=True)
        got[name] = json.loads(out.stdout.strip().splitlines()[-1])
    # the long recording was judged (the channel forms had samples to judge)
    assert "ERROR" not in got["long"]["verdicts"][:3], got
    assert got["long"]["growth_kb"] - got["short"]["growth_kb"] < 1_500, got
