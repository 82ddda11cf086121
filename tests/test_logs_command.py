"""`harness logs`: every run directory, how it ended, including killed runs."""

from __future__ import annotations

import json

from harness.cli import main
from harness.core.runs import load_run
from harness.core.session import execute_run
from rig_models.faults import parse_fault


def test_logs_lists_completed_fault_and_killed_runs(tmp_path, capsys):
    execute_run(load_run("slew-rw", {"duration_s": 1.0}), out_dir=tmp_path, show_progress=False)
    execute_run(load_run("slew-rw", {"duration_s": 2.0}), out_dir=tmp_path, show_progress=False,
                faults=[parse_fault("silent_sensor@0.5:hub_sensor")])
    killed = tmp_path / "20991231T000000.000000Z-slew-rw"  # sorts last
    killed.mkdir()
    (killed / "config.yaml").write_text("run: {}\n")
    (tmp_path / "not-a-run").mkdir()

    assert main(["logs", "--logs", str(tmp_path), "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [r["status"] for r in rows] == ["completed", "fault", "no summary.json (killed?)"]
    assert rows[0]["run"] == "slew-rw" and rows[0]["simulated_s"] > 0.9
    assert rows[1]["first_fault"].startswith("hub_sensor: silent")

    assert main(["logs", "--logs", str(tmp_path), "--last", "1"]) == 0
    out = capsys.readouterr().out
    assert "killed" in out and "completed" not in out

    assert main(["logs", "--logs", str(tmp_path / "none")]) == 1
    assert main(["logs", "--last", "-1"]) == 2
