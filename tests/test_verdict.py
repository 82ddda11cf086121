"""The verdict layer's pure parts: parsing criteria (and refusing bad ones, naming the key
path), each criterion form on synthetic data, verdicts, margins and exit codes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from harness.testing import (
    ERROR,
    FAIL,
    MARGINAL,
    PASS,
    Facts,
    apply_overrides,
    evaluate,
    evaluate_scalar,
    make_verdict,
    parse_criteria,
    run_checks,
)
from harness.testing.measures import SUMMARY_MEASURES, numeric_leaves
from rig_models.schema import ConfigError

SUMMARY = {
    "run": "x", "rate_hz": 500.0, "stopped_by": "completed", "error": "",
    "final_angle_error_deg": 0.03, "settle_time_s": None, "overruns": 0,
    "lateness_ms": {"p50": 0.0, "p99": 0.4, "max": 2.0}, "frames": {"missing": 0},
    "slew_profile_end_s": 2.0, "faults": [], "injected_faults": [],
}


def one(raw: dict, **kw) -> object:
    return parse_criteria({"c": raw}, "test.yaml", **kw)[0]


def scalar(raw: dict, measures: dict | None = None):
    return evaluate_scalar(one(raw), measures or SUMMARY)


# ------------------------------------------------------------------------- scalar
def test_scalar_pass_marginal_fail_with_margin():
    r = scalar({"measure": "final_angle_error_deg", "max_abs_deg": 0.1, "marginal_deg": 0.02})
    assert (r.verdict, r.value, r.unit) == (PASS, 0.03, "deg")
    assert r.margin == pytest.approx(0.07)
    assert r.limit == {"max_abs_deg": 0.1, "marginal_deg": 0.02}
    r = scalar({"measure": "final_angle_error_deg", "max_abs_deg": 0.04, "marginal_deg": 0.02})
    assert r.verdict == MARGINAL and r.margin == pytest.approx(0.01)
    r = scalar({"measure": "final_angle_error_deg", "max_abs_deg": 0.02})
    assert r.verdict == FAIL and r.margin == pytest.approx(-0.01)
    assert "final_angle_error_deg = 0.03 deg" in r.message and "max_abs_deg 0.02" in r.message
    r = scalar({"measure": "final_angle_error_deg", "min_deg": 0.05, "max_deg": 0.2})
    assert r.verdict == FAIL and r.margin == pytest.approx(-0.02)


def test_scalar_dotted_paths_null_missing_and_budget():
    assert scalar({"measure": "lateness_ms.p99", "max_ms": 1}).verdict == PASS
    r = scalar({"measure": "settle_time_s", "max_s": 10})
    assert r.verdict == FAIL and "never stayed" in r.message  # null settle time is a result
    r = scalar({"measure": "steady_tip_accel_amplitude_m_s2", "max_m_s2": 1})
    assert r.verdict == ERROR and "missing data" in r.message
    # the real-time budget: a failed lateness criterion makes the test inconclusive (the
    # bench did not hold its time), not failed
    r = scalar({"measure": "lateness_ms.max", "max_ms": 1})
    assert r.verdict == "INCONCLUSIVE" and "real-time budget" in r.message
    r = scalar({"measure": "lateness_ms.max", "max_ms": 1, "budget": False})
    assert r.verdict == FAIL
    r = scalar({"measure": "wheel_torque_within_limit", "is": True},
               {"wheel_torque_within_limit": False})
    assert r.verdict == FAIL


def test_scalar_on_any_result_mapping():
    """The suites reuse the scalar part on non-run results (a study's JSON output)."""
    [c] = parse_criteria([{"measure": "modes.f1_hz", "min_hz": 0.4, "max_hz": 0.5}],
                         "study", known_measures=["modes.f1_hz"], channels=())
    assert c.unit == "hz" and c.name == "modes.f1_hz"
    assert evaluate_scalar(c, {"modes": {"f1_hz": 0.46}}).verdict == PASS
    assert evaluate_scalar(c, {"modes": {"f1_hz": 0.52}}).verdict == FAIL


def test_scalar_on_a_document_wildcards_lengths_equality_and_dotted_keys():
    """The one scalar form on any JSON document (a suite's check:): [*] judged element by
    element reporting the worst, keys with dots, equals_<unit>, len_min_count, is: TEXT."""
    doc = {"modes": [{"err_percent": 0.1}, {"err_percent": -0.42}, {"err_percent": 0.3}],
           "laws": {"best_beta_gt_0.5": 0.8}, "n_count": 3, "bus": "virtual:x",
           "settle_s": None}

    def judge(raw: dict):
        [c] = parse_criteria({"c": raw}, "suite file s.yaml", channels=(), key="check",
                             open_paths=True)
        return evaluate_scalar(c, doc)

    r = judge({"measure": "modes[*].err_percent", "max_abs_percent": 0.5,
               "marginal_percent": 0.1, "why": "the model's modes"})
    assert (r.verdict, r.value, r.unit, r.why) == (MARGINAL, -0.42, "percent", "the model's modes")
    assert r.margin == pytest.approx(0.08) and "worst modes[1].err_percent" in r.message
    assert r.to_dict()["limit"] == {"max_abs_percent": 0.5, "marginal_percent": 0.1}
    r = judge({"measure": "modes[*].err_percent", "max_percent": 0.2})
    assert r.verdict == FAIL and r.value == 0.3 and "1 of 3 outside" in r.message
    assert judge({"measure": "modes[2].err_percent", "min_percent": 0.3}).verdict == PASS
    assert judge({"measure": "laws.best_beta_gt_0.5", "min_ratio": 0.6,
                  "max_ratio": 0.85}).verdict == PASS
    assert judge({"measure": "n_count", "equals_count": 3}).verdict == PASS
    r = judge({"measure": "n_count", "equals_count": 4})
    assert r.verdict == FAIL and r.margin == -1
    r = judge({"measure": "modes", "len_min_count": 4})
    assert (r.verdict, r.value, r.unit, r.margin) == (FAIL, 3, "count", -1)
    assert judge({"measure": "modes", "len_max_count": 3}).verdict == PASS
    assert judge({"measure": "bus", "is": "virtual:x"}).verdict == PASS
    r = judge({"measure": "settle_s", "max_s": 1})
    assert r.verdict == ERROR and "null" in r.message
    r = judge({"measure": "modes[*].nope_s", "max_s": 1})
    assert r.verdict == ERROR and "modes[0]" in r.message
    r = judge({"measure": "bus", "max_ratio": 1})
    assert r.verdict == ERROR and "not a number" in r.message


@pytest.mark.parametrize("raw, where, what", [
    ({"measure": "modes[*].err_percent", "max_abs_s": 1}, "check.c.max_abs_s",
     "expected max_abs_percent"),
    ({"measure": "modes[*].err_percent", "max_abs": 1}, "check.c.max_abs", "missing unit"),
    ({"measure": "modes", "len_min": 3}, "check.c.len_min", "expected len_min_count"),
    ({"measure": "modes", "len_min_count": 3, "max_ratio": 1}, "check.c.max_ratio",
     "takes only len_min_count"),
    ({"measure": "gain", "max_s": 1}, "check.c.max_s", "expected max_ratio or max_count"),
    ({"measure": "x_deg", "equals_deg": 1, "max_deg": 2}, "check.c.equals_deg",
     "stands alone"),
    ({"measure": "x_deg", "equals_deg": 1, "marginal_deg": 0.1}, "check.c.marginal_deg",
     "no marginal band"),
    ({"measure": "x_deg", "max_deg": 1, "colour": 1}, "check.c.colour", "unknown key"),
    ({"measure": "a[b].x_deg", "max_deg": 1}, "check.c.measure", "[N] or [*]"),
    ({"measure": "ok", "is": 3}, "check.c.is", "is: true|false"),
])
def test_bad_document_criteria_are_refused_naming_the_key_path(raw, where, what):
    with pytest.raises(ConfigError) as exc:
        parse_criteria({"c": raw}, "suite file s.yaml", channels=(), key="check",
                       open_paths=True)
    msg = str(exc.value)
    assert msg.startswith(f"suite file s.yaml: {where}: "), msg
    assert what in msg, msg


def test_run_files_keep_summary_measures_but_take_equals():
    """In a run file the path is one of summary.json's measures (a typo is refused before
    the run); the limits are the same keys as a suite's."""
    with pytest.raises(ConfigError, match=r"expect\.c\.measure: unknown measure"):
        one({"measure": "faults[*].tick", "max_count": 1})
    assert scalar({"measure": "overruns", "equals_count": 0}).verdict == PASS
    with pytest.raises(ConfigError, match=r"expect\.c\.len_min_count: len_min_<unit> is for "
                       r"measure: criteria only"):
        parse_criteria({"c": {"channel": "/tip/accel_m_s2", "len_min_count": 1}}, "t")


# ------------------------------------------------------------------------- refused
@pytest.mark.parametrize("raw, where, what", [
    ({"measure": "final_angle_eror_deg", "max_deg": 1}, "expect.c.measure", "unknown measure"),
    ({"channel": "/tip/acel_m_s2", "max_abs_m_s2": 1}, "expect.c.channel", "unknown channel"),
    ({"measure": "final_angle_error_deg", "min_deg": 1, "max_deg": 0},
     "expect.c.min_deg", "min 1 > max 0"),
    ({"measure": "final_angle_error_deg", "max_abs": 1}, "expect.c.max_abs",
     "missing unit"),
    ({"measure": "final_angle_error_deg", "max_abs_s": 1}, "expect.c.max_abs_s",
     "expected max_abs_deg"),
    ({"measure": "overruns", "max": 0}, "expect.c.max", "expected max_count"),
    ({"measure": "final_angle_error_deg"}, "expect.c", "no limit"),
    ({"measure": "final_angle_error_deg", "max_deg": 1, "typo": 2}, "expect.c.typo",
     "unknown key"),
    ({"channel": "/tip/accel_m_s2", "max_abs_m_s2": 1, "after": "lunch"}, "expect.c.after",
     "expected one of"),
    ({"settles": "/attitude/error_deg", "band_s": 0.1, "within_s": 1, "stays_s": 1},
     "expect.c.band_s", "expected band_deg"),
    ({"baseline": "no/such/run", "channel": "/attitude/angle_deg", "tol_deg": 0.1},
     "expect.c.baseline", "does not exist"),
    ({"fault": "hub_sensor", "within_ticks": 3}, "expect.c.kind", "expected the kind"),
    ({"measure": "final_angle_error_deg", "max_abs_deg": 0.1, "marginal_deg": 0.1},
     "expect.c.marginal_deg", "covers the whole pass band"),
])
def test_bad_criteria_are_refused_naming_the_key_path(raw, where, what, tmp_path):
    with pytest.raises(ConfigError) as exc:
        parse_criteria({"c": raw}, "run file t.yaml", base_dir=tmp_path)
    msg = str(exc.value)
    assert msg.startswith(f"run file t.yaml: {where}: "), msg
    assert what in msg, msg


def test_list_form_names_and_key_paths():
    with pytest.raises(ConfigError, match=r"expect\[1\]\.max_abs_s"):
        parse_criteria([{"measure": "overruns", "max_count": 0},
                        {"measure": "final_angle_error_deg", "max_abs_s": 1}], "t.yaml")


def test_overrides_change_limits_only():
    expect = {"e": {"measure": "final_angle_error_deg", "max_abs_deg": 0.1}}
    out = apply_overrides(expect, {"e": {"max_abs_deg": 0.2}, "other": {"max_s": 1}}, "rig")
    assert out["e"]["max_abs_deg"] == 0.2 and "other" not in out
    assert expect["e"]["max_abs_deg"] == 0.1
    with pytest.raises(ConfigError, match=r"rig: expect_overrides\.e\.measure: only limits"):
        apply_overrides(expect, {"e": {"measure": "overruns"}}, "rig")


# ------------------------------------------------------------------------- channels
def facts_with(channels: dict, measures: dict | None = None, baselines: dict | None = None
               ) -> Facts:
    return Facts(measures or SUMMARY, channel=lambda e: channels[e],
                 baseline_channel=lambda b, e: baselines[b][e] if baselines else None)


T = np.arange(0, 10.0001, 0.01)


def test_channel_stays_within_band_names_worst_sample_time():
    x = 0.1 * np.sin(T)
    x[700] = 0.5  # one bad sample at t = 7 s
    f = facts_with({"/tip/accel_m_s2": (T, x)})
    [whole, before, after_event, last, rms] = evaluate(parse_criteria({
        "whole": {"channel": "/tip/accel_m_s2", "max_abs_m_s2": 0.2},
        "before": {"channel": "/tip/accel_m_s2", "max_abs_m_s2": 0.2, "to_s": 6.0},
        "after": {"channel": "/tip/accel_m_s2", "max_abs_m_s2": 0.2, "after":
                  "slew_profile_end_s", "from_s": 5.5},
        "last": {"channel": "/tip/accel_m_s2", "max_abs_m_s2": 0.2, "last_s": 2.0},
        "rms": {"channel": "/tip/accel_m_s2", "reduce": "rms", "max_m_s2": 0.08,
                "marginal_m_s2": 0.01, "to_s": 6.0},
    }, "t"), f)
    assert whole.verdict == FAIL and whole.worst_time_s == pytest.approx(7.0)
    assert whole.value == 0.5 and "t = 7.000 s" in whole.message
    assert whole.violations_s == [pytest.approx(7.0)]
    assert before.verdict == PASS
    assert after_event.verdict == PASS  # 2 s + 5.5 s: the spike at 7 s is before
    assert last.verdict == PASS
    rms_true = np.sqrt(np.mean((0.1 * np.sin(T[T <= 6.0])) ** 2))
    assert rms.value == pytest.approx(rms_true)
    assert rms.verdict == MARGINAL  # 0.0712 within 0.01 of 0.08


def test_channel_window_after_event_excludes_earlier_samples():
    x = np.where(T < 3.0, 1.0, 0.0)
    f = facts_with({"/wheel/torque_cmd_n_m": (T, x)})
    [r] = evaluate(parse_criteria({"c": {"channel": "/wheel/torque_cmd_n_m", "max_abs_n_m": 0,
                                         "after": "slew_profile_end_s", "from_s": 1.0}}, "t"),
                   f)
    assert r.verdict == PASS  # the window starts at 2 + 1 = 3 s
    measures = dict(SUMMARY, slew_profile_end_s=None)
    [r] = evaluate(parse_criteria({"c": {"channel": "/wheel/torque_cmd_n_m", "max_abs_n_m": 0,
                                         "after": "slew_profile_end_s"}}, "t"),
                   facts_with({"/wheel/torque_cmd_n_m": (T, x)}, measures))
    assert r.verdict == ERROR and "slew_profile_end_s is null" in r.message


def test_settles_within_and_stays():
    x = 2.0 * np.exp(-T)  # enters |x| <= 0.1 at ln 20 = 2.996 s
    f = facts_with({"/attitude/error_deg": (T, x)})
    crit = {"settles": "/attitude/error_deg", "band_deg": 0.1, "within_s": 5.0, "stays_s": 2.0}
    [r] = evaluate(parse_criteria({"s": crit}, "t"), f)
    assert r.verdict == PASS and r.value == pytest.approx(3.0, abs=0.011)
    assert r.limit["within_s"] == 5.0 and r.unit == "s"
    [r] = evaluate(parse_criteria({"s": dict(crit, within_s=3.5, marginal_s=1.0)}, "t"), f)
    assert r.verdict == MARGINAL
    [r] = evaluate(parse_criteria({"s": dict(crit, within_s=2.0)}, "t"), f)
    assert r.verdict == FAIL
    # after an event: counted from slew_profile_end_s (2 s)
    [r] = evaluate(parse_criteria({"s": dict(crit, after="slew_profile_end_s")}, "t"), f)
    assert r.value == pytest.approx(1.0, abs=0.011)
    # leaves the band again before stays_s: the later entry counts; never: FAIL
    y = x.copy()
    y[(T > 4.0) & (T < 4.5)] = 1.0
    [r] = evaluate(parse_criteria({"s": crit}, "t"), facts_with({"/attitude/error_deg": (T, y)}))
    assert r.value == pytest.approx(4.5, abs=0.011)
    never = facts_with({"/attitude/error_deg": (T, 2.0 + 0.0 * T)})
    [r] = evaluate(parse_criteria({"s": crit}, "t"), never)
    assert r.verdict == FAIL and r.value is None and "never settled" in r.message
    # in the band at the end but the record is shorter than stays_s: too short to judge
    [r] = evaluate(parse_criteria({"s": dict(crit, stays_s=20.0)}, "t"), f)
    assert r.verdict == ERROR and "judging needs the run to last until" in r.message


def test_baseline_tolerance_and_time_shift(tmp_path):
    base = tmp_path / "base"
    base.mkdir()
    (base / "run.rrd").write_bytes(b"")
    x = np.sin(T)
    baselines = {str(base.resolve()): {"/attitude/angle_deg": (T, x)}}
    crit = {"baseline": str(base), "channel": "/attitude/angle_deg", "tol_deg": 0.01}

    def judge(run_x: np.ndarray, **kw):
        return evaluate(parse_criteria({"b": dict(crit, **kw)}, "t"),
                        facts_with({"/attitude/angle_deg": (T, run_x)}, baselines=baselines))[0]

    r = judge(x)
    assert r.verdict == PASS and r.value == 0.0
    shifted = np.sin(T - 0.05)  # 50 ms late
    r = judge(shifted)
    assert r.verdict == FAIL and "/attitude/angle_deg" in r.message
    r = judge(shifted, max_shift_s=0.1)
    assert r.verdict == PASS and "time shift -0.050 s" in r.message
    bumped = x + np.where(np.abs(T - 6.0) < 0.2, 0.1 * np.cos((T - 6.0) * 7.8), 0.0)
    r = judge(bumped, max_shift_s=0.02)
    assert r.verdict == FAIL and r.worst_time_s == pytest.approx(6.0, abs=0.03)
    assert "t = 6.0" in r.message
    r = judge(x * 1.004, tol_rel_percent=0.5)
    assert r.verdict == PASS


def test_fault_expectations_and_unexpected_faults():
    fault = {"tick": 1003, "time_s": 2.006, "device": "hub_sensor", "kind": "silent",
             "message": "no telemetry for 4 ticks"}
    m = dict(SUMMARY, stopped_by="fault", faults=[fault],
             injected_faults=[{"kind": "silent_sensor", "at_s": 2.0, "device": "hub_sensor"}])
    crits = parse_criteria({"f": {"fault": "hub_sensor", "kind": "silent", "within_ticks": 4}},
                           "t")
    [r] = evaluate(crits, Facts(m))
    assert r.verdict == PASS and r.value == 3 and r.worst_time_s == pytest.approx(2.006)
    assert run_checks(crits, m) == []
    assert make_verdict([r]).exit_code == 0
    late = parse_criteria({"f": {"fault": "hub_sensor", "kind": "silent", "within_ticks": 2}},
                          "t")
    assert evaluate(late, Facts(m))[0].verdict == FAIL
    other = parse_criteria({"f": {"fault": "accelerometer", "kind": "stuck"}}, "t")
    results = evaluate(other, Facts(m)) + run_checks(other, m)
    assert [r.verdict for r in results] == [FAIL, ERROR]
    v = make_verdict(results)
    assert v.verdict == ERROR and v.exit_code == 3
    assert "did not expect: hub_sensor: silent" in v.reason


def test_verdict_worst_wins_and_exit_codes():
    p = scalar({"measure": "overruns", "max_count": 5})
    m = scalar({"measure": "overruns", "max_count": 1, "marginal_count": 0.4}, {"overruns": 0.8})
    assert (p.verdict, m.verdict) == (PASS, MARGINAL)
    # nothing judged is not a pass: NO CRITERIA, exit 0 (harness run warns)
    assert make_verdict([]).exit_code == 0 and make_verdict([]).verdict == "NO CRITERIA"
    assert make_verdict([]).reason.startswith("no criteria")
    assert make_verdict([p]).exit_code == 0
    assert make_verdict([p, m]).exit_code == 5
    fail = scalar({"measure": "final_angle_error_deg", "max_abs_deg": 0.01})
    assert make_verdict([p, m, fail]).exit_code == 1
    # the bench did not hold its time: INCONCLUSIVE (exit 6), over a FAIL measured on it
    late = scalar({"measure": "lateness_ms.max", "max_ms": 1})
    v = make_verdict([p, m, fail, late])
    assert v.verdict == "INCONCLUSIVE" and v.exit_code == 6
    assert v.reason.startswith("the bench did not hold real time") and "not trusted" in v.reason
    stopped = run_checks([], dict(SUMMARY, stopped_by="error", error="ValueError: x"))
    assert make_verdict(stopped).exit_code == 4 and "raised" in make_verdict(stopped).reason
    # an ERROR (the run broke) outranks INCONCLUSIVE
    assert make_verdict([late, *stopped]).verdict == ERROR
    interrupted = run_checks([], dict(SUMMARY, stopped_by="interrupted"))
    assert make_verdict(interrupted).exit_code == 130


def test_summary_catalogue_covers_a_real_summary(slew_result):
    """Every number in summary.json is a known measure (the catalogue cannot drift)."""
    leaves = set(numeric_leaves(slew_result.summary))
    assert leaves - set(SUMMARY_MEASURES) == set()


def test_docs_show_every_form():
    doc = (Path(__file__).parent.parent / "docs" / "criteria.md").read_text()
    for key in ("measure:", "channel:", "settles:", "baseline:", "fault:", "left_safe:",
                "expect_overrides:", "reduce: rms"):
        assert key in doc
