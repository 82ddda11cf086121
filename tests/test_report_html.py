"""report.html as a reviewer reads it: units as people write them,
plots at the page's width with the axes on the data, a fault test's injection and detection
marked, a link to each of the run's files and the one command that opens its recordings."""

from __future__ import annotations

import base64
import re
from pathlib import Path

import pytest

from harness.core.runs import load_run
from harness.core.session import execute_run
from harness.testing import judge_run
from harness.testing.judge import write_verdict
from harness.testing.report import HEADER, VERDICT_COL, write_reports
from rig_models.faults import parse_fault


@pytest.fixture(scope="module")
def suite_dir(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("report_html")
    # a fault test: only its fault expectations and the safe state are judged
    run = load_run("slew-rw", {"duration_s": 3.0, "expect": {"detected": {
        "fault": "hub_sensor", "kind": "silent", "within_ticks": 4}}})
    res = execute_run(run, out_dir=out / "runs", show_progress=False,
                      faults=[parse_fault("silent_sensor@1:hub_sensor")])
    v = judge_run(res.run_dir)
    write_verdict(v, res.run_dir)
    rel = str(res.run_dir.relative_to(out))
    record = {"item": "fault-hub", "nodeid": "x::fault-hub", "kind": "run",
              "description": "hub sensor silent", "verdict": v.verdict, "reason": v.reason,
              "criteria": v.to_dict()["criteria"], "wall_s": 1.0, "worker": None,
              "run_dir": rel}
    write_reports(out, [record], not_run=[], suites=[], engine="local", bus=None,
                  preflight=None, refused=None, wall_s=1.0)
    return out


def test_units_are_written_as_people_write_them(suite_dir):
    page = (suite_dir / "report.html").read_text()
    md = (suite_dir / "report.md").read_text()
    assert HEADER[VERDICT_COL] == "verdict"
    for text in (page, md):
        assert "≤ 0" in text  # limits as phrases, not max_count 0
        assert "max_count" not in text


def test_links_every_file_and_the_command_that_opens_the_recordings(suite_dir):
    page = (suite_dir / "report.html").read_text()
    run_dir = next((suite_dir / "runs").iterdir())
    rel = str(run_dir.relative_to(suite_dir))
    for f in ("run.rrd", "verdict.rrd", "can.blf", "verdict.json", "summary.json",
              "config.yaml"):
        assert f"href='{rel}/{f}'" in page, f
    # the verdict is in run.rrd: run.rrd alone opens it all
    assert f"<code>rerun {rel}/run.rrd</code>" in page


def test_fault_test_plots_mark_injection_and_detection_at_full_width(suite_dir):
    page = (suite_dir / "report.html").read_text()
    assert "alt='fault test: the injection and its detection'" in page
    assert "img{width:100%;height:auto}" in page
    png = base64.b64decode(re.findall(r"src='data:image/png;base64,([A-Za-z0-9+/=]+)'",
                                      page)[0])
    width = int.from_bytes(png[16:20], "big")
    assert width >= 1000  # drawn to be read, not 450 px


def test_plot_axes_are_the_data_not_the_band(tmp_path):
    """A settling error of a few mdeg judged on a +-0.1 deg band: the axis is the data's,
    the band's edges are named as off the axis."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from harness.testing.report import _data_ylim, _shade_band

    t = np.linspace(0, 10, 500)
    v = 0.006 * np.sin(t)
    fig, ax = plt.subplots()
    ax.plot(t, v)
    _data_ylim(ax, v)
    _shade_band(ax, {"lo": -0.1, "hi": 0.1, "reduce": "each", "window": "whole run",
                     "verdict": "PASS"}, 0.0, 10.0, v)
    lo, hi = ax.get_ylim()
    assert -0.0075 < lo < -0.006 and 0.006 < hi < 0.0075
    labels = ax.get_legend_handles_labels()[1]
    assert any("edge -0.1, 0.1 off the axis" in x for x in labels)
    plt.close(fig)


def test_criteria_rows_write_units_and_limits_plainly():
    from harness.testing.report import _criteria_rows

    rows = _criteria_rows([
        {"name": "wheel_torque", "kind": "scalar", "value": 0.05298, "unit": "n_m",
         "limit": {"max_n_m": 0.065}, "margin": 0.01202, "verdict": "PASS",
         "worst_time_s": 7.162, "message": "ok"},
        {"name": "tip", "kind": "channel", "value": 0.027, "unit": "m_s2",
         "limit": {"max_abs_m_s2": 0.05}, "margin": 0.023, "verdict": "PASS",
         "worst_time_s": 1.0, "message": "ok"},
        {"name": "settles", "kind": "settles", "value": 0.0, "unit": "s",
         "limit": {"within_s": 11.1, "band_deg": 0.1}, "margin": 11.1, "verdict": "PASS",
         "worst_time_s": None, "message": "settled 0 s after t = 12.000 s"}])
    assert rows[0][2:5] == ["0.05298 N m", "≤ 0.065 N m", "0.01202 N m"]
    assert rows[1][2:5] == ["0.027 m/s²", "|x| ≤ 0.05 m/s²", "0.023 m/s²"]
    assert rows[0][6] == "7.162"
    # a settling time counts from its trigger, not from the start as summary.json's does
    assert rows[2][2] == "0 s after its trigger"
