"""verdict.rrd's events: criteria violated at the same instant (a fault ends a run: its
unexpected-fault criterion and a channel criterion share the time) are both written."""

from __future__ import annotations

from harness.core.runs import load_run
from harness.core.session import execute_run
from harness.testing.judge import judge_run, write_verdict


def test_two_criteria_violated_at_the_same_time_are_both_events(tmp_path):
    run = load_run("slew-rw", {"duration_s": 1.0})
    res = execute_run(run, out_dir=tmp_path, show_progress=False)
    band = {"channel": "/attitude/angle_deg", "max_abs_deg": 1e-9, "why": "a band nothing meets"}
    v = judge_run(res.run_dir, {"a": dict(band), "b": dict(band)})
    a, b = v.criteria
    assert a.violations_s and a.violations_s == b.violations_s  # the same instants
    write_verdict(v, res.run_dir)  # before: TypeError comparing two CriterionResults
    assert (res.run_dir / "verdict.rrd").stat().st_size > 0
