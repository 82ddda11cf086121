"""What a reviewer sees of a verdict: each criterion's markers under its own name, one event
per failed criterion, criteria of a run stopped early not judged unless they say they apply,
and report.html's criteria failing first with their scalar values plotted."""

from __future__ import annotations

import json
import shutil
import warnings
from pathlib import Path

import pytest

from harness.core.runs import load_run
from harness.core.session import execute_run
from harness.testing.judge import judge_run, write_verdict

TORQUE = {"channel": "/wheel/torque_cmd_n_m", "max_abs_n_m": 0.02, "why": "too tight"}
ERROR_BAND = {"channel": "/attitude/error_deg", "max_abs_deg": 1e-6, "why": "too tight"}


@pytest.fixture(scope="module")
def slew(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("runs")
    return execute_run(load_run("slew-rw", {"duration_s": 6.0}), out_dir=out,
                       show_progress=False).run_dir


def _copy(run: Path, tmp_path: Path) -> Path:
    # the same folder name: run.rrd's recording id is the run folder's name
    return Path(shutil.copytree(run, tmp_path / run.name))


def _rows(rrd: Path, prefix: str, column: str) -> dict[str, list]:
    from rerun.chunk import RrdReader

    out: dict[str, list] = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for chunk in RrdReader(rrd).stream().to_chunks():
            if chunk.entity_path.startswith(prefix):
                batch = chunk.to_record_batch()
                if column in batch.schema.names:
                    out.setdefault(chunk.entity_path, []).extend(
                        x[0] if isinstance(x, list) else x
                        for x in batch.column(column).to_pylist())
    return out


def test_each_marker_carries_its_own_criterion_and_one_event_each(slew, tmp_path):
    d = _copy(slew, tmp_path)
    v = judge_run(d, {"wheel_torque": TORQUE, "tight_error": ERROR_BAND})
    assert [c.verdict for c in v.criteria] == ["FAIL", "FAIL"]
    assert len(v.criteria[1].violations_s) > 1  # violated again and again
    write_verdict(v, d)
    for rrd in (d / "run.rrd", d / "verdict.rrd"):
        names = _rows(rrd, "/markers/", "SeriesPoints:names")
        series = {path: set(n) for path, n in names.items() if "/verdict" in path}
        assert series, rrd
        for path, labels in series.items():
            # one series per criterion, so a legend (the series' last name) is its own
            assert len(labels) == 1, (path, labels)
            criterion = path.rsplit("/", 1)[-1]
            assert labels == {f"VERDICT {criterion} FAIL"}, (path, labels)
        assert {p.rsplit("/", 1)[-1] for p in series} == {"wheel_torque", "tight_error"}
        events = [t for texts in _rows(rrd, "/events/verdict", "TextLog:text").values()
                  for t in texts]
        assert len(events) == 2, events  # one per failed criterion, not one per violation
        assert sum(e.startswith("tight_error FAIL") for e in events) == 1


def _stopped_by_fault(d: Path) -> None:
    s = json.loads((d / "summary.json").read_text())
    s.update(stopped_by="fault", faults=[{"device": "hub_sensor", "kind": "silent",
                                          "time_s": 2.5, "tick": 1250, "message": "quiet"}])
    (d / "summary.json").write_text(json.dumps(s))


def test_a_run_stopped_by_a_fault_leaves_its_goal_criteria_not_judged(slew, tmp_path):
    d = _copy(slew, tmp_path)
    _stopped_by_fault(d)
    final = {"measure": "final_angle_error_deg", "max_abs_deg": 100.0}
    v = judge_run(d, {"final_error": final, "bus": {"measure": "frames.malformed",
                                                    "max_count": 0, "applies_to_stopped": True},
                      "safe": {"left_safe": True}})
    by = {c.name: c for c in v.criteria}
    assert by["final_error"].verdict == "NOT JUDGED"
    assert "not judged" in by["final_error"].message and "hub_sensor" in \
        by["final_error"].message
    assert by["bus"].verdict == "PASS" and by["safe"].verdict == "PASS"
    # the stop decides the run's verdict: an unexpected fault, exit 3
    assert v.verdict == "ERROR" and v.exit_code == 3
    from harness.review.verdict import verdict_markdown

    text = verdict_markdown(v.to_dict(), json.loads((d / "summary.json").read_text()))
    assert "**NOT JUDGED** final_error" in text and "1 not judged" in text
    # the same run completed: judged as before
    assert judge_run(slew, {"final_error": final}).criteria[0].verdict == "PASS"


def test_applies_to_stopped_must_be_a_boolean(slew):
    from rig_models.schema import ConfigError

    with pytest.raises(ConfigError, match="applies_to_stopped"):
        judge_run(slew, {"x": {"measure": "frames.malformed", "max_count": 0,
                               "applies_to_stopped": "yes"}})


def test_report_lists_failing_criteria_first_and_plots_scalar_ones():
    from harness.testing.report import _criteria_rows, scalar_bounds, scalar_plot

    criteria = [
        {"name": "a_pass", "kind": "scalar", "value": 0.01, "unit": "deg",
         "limit": {"max_abs_deg": 0.1}, "verdict": "PASS", "margin": 0.09},
        {"name": "b_fail", "kind": "scalar", "value": 0.07, "unit": "n_m",
         "limit": {"max_n_m": 0.065}, "verdict": "FAIL", "margin": -0.005},
        {"name": "c_flag", "kind": "scalar", "value": True, "unit": "",
         "limit": {"is": True}, "verdict": "PASS"},
    ]
    assert [r[0] for r in _criteria_rows(criteria)] == ["b_fail", "a_pass", "c_flag"]
    assert scalar_bounds({"max_abs_deg": 0.1}) == (-0.1, 0.1)
    assert scalar_bounds({"min_s": 1.0, "max_s": 2.0}) == (1.0, 2.0)
    plot = scalar_plot(criteria)
    assert plot is not None and len(plot["png"]) > 1000
    assert scalar_plot([criteria[2]]) is None  # nothing numeric to draw


def test_every_y_axis_gets_two_labels_at_the_viewers_step():
    """The viewer labels a y axis at powers of ten and drops a step that would crowd the
    plot: a wheel torque of -0.019..0.054 N m was labelled with a lone "0"."""
    import math

    from harness.review import layouts as L

    def labels(lo: float, hi: float) -> int:
        span = hi - lo
        step = 10.0 ** math.floor(math.log10(span))
        if span / step > L.MAX_LABELS:
            step *= 10.0
        return math.floor(hi / step + 1e-9) - math.ceil(lo / step - 1e-9) + 1

    torque = L.axis_range(L.PLOTS["wheel_torque"], {"/wheel/torque_cmd_n_m": [-0.0194, 0.0538]})
    assert labels(*torque) >= 2, torque
    assert torque[1] - torque[0] < 0.2  # widened to the next label, not to +-0.1
    for lo, hi in ((0.0, 0.0), (3.9, 6.1), (-261.2, 0.0), (0.0, 28.2), (-0.021, 0.027),
                   (0.0, 5.0), (1e-4, 1.5e-4)):
        r = L.axis_range(L.PLOTS["rate"], {"/attitude/rate_deg_s": [lo, hi]})
        assert labels(*r) >= 2 and r[0] <= lo and r[1] >= hi, (lo, hi, r)
