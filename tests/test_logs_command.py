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


def test_logs_name_each_runs_rig_bus_and_clock(tmp_path, capsys):
    from rig_models.rig_file import load_rig, rig_sha256

    for rig in ("sgsrt-canopen", "sgsrt-dbc2"):
        execute_run(load_run("slew-rw", {"duration_s": 0.2, "rig": rig}), out_dir=tmp_path,
                    show_progress=False)
    old = tmp_path / "20000101T000000.000000Z-slew-rw"  # a summary from before it named its rig
    old.mkdir()
    (old / "config.yaml").write_text("rig: {name: lab-rig}\nrun: {name: slew-rw}\n")
    (old / "summary.json").write_text(json.dumps({"run": "slew-rw", "clock": "lockstep",
                                                  "bus": "socketcan:can0",
                                                  "stopped_by": "completed"}))
    assert main(["logs", "--logs", str(tmp_path), "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [(r["rig"], r["bus"], r["clock"]) for r in rows] == [
        ("lab-rig", "socketcan:can0", "lockstep"),
        ("sgsrt-canopen", "virtual:sgsrt-canopen", "lockstep"),
        ("sgsrt-dbc2", "virtual:sgsrt-dbc2", "lockstep")]
    assert rows[1]["rig_sha256"] == rig_sha256(load_rig("sgsrt-canopen").data)
    assert rows[1]["binding"]["reaction_wheel"] == {"binding": "canopen", "node_id": 2,
                                                    "eds": "sgsrt_wheel_drive.eds"}
    assert rows[2]["binding"]["hub_sensor"] == {"binding": "dbc", "dbc": "sgsrt_dbc2.dbc"}
    assert main(["logs", "--logs", str(tmp_path)]) == 0
    header, *lines = capsys.readouterr().out.splitlines()
    assert header.split()[4:7] == ["rig", "bus", "clock"]
    assert lines[1].split()[3:6] == ["sgsrt-canopen", "virtual:sgsrt-canopen", "lockstep"]


def test_a_closed_pipe_ends_the_command_quietly(tmp_path):
    """`harness logs | head -1`: the reader closes the pipe after one line; the harness ends
    without a BrokenPipeError traceback (nor Python's 'Exception ignored' at exit)."""
    import os
    import subprocess
    import sys

    for i in range(40):  # about 200 kB of listing: more than a pipe holds
        run = tmp_path / f"202601{i:02d}T000000.000000Z-r"
        run.mkdir()
        (run / "config.yaml").write_text("run: {}\n")
        (run / "summary.json").write_text(json.dumps({"run": "r", "clock": "lockstep",
                                                      "error": "e" * 5000,
                                                      "stopped_by": "completed"}))
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    for extra in ([], ["--json"]):
        proc = subprocess.run(
            f"{sys.executable} -m harness logs --logs {tmp_path} {' '.join(extra)} | head -c 10",
            shell=True, capture_output=True, text=True, env=env, timeout=120, check=False)
        assert len(proc.stdout) == 10
        assert "Traceback" not in proc.stderr and "BrokenPipe" not in proc.stderr, proc.stderr
