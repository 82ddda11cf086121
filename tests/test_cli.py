"""The command line, as a user runs it (subprocesses; a refusal whose claim is the command's
exit code and message runs in process, tests/in_process.py: `harness run`'s entry point is
covered by the JSON test above it)."""

from __future__ import annotations

import json
import subprocess
import sys

from in_process import harness_in_process


def harness(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "harness", *args], capture_output=True,
                          text=True, cwd=cwd, timeout=300)


def test_cases_lists_builtin_runs():
    out = harness("cases")
    assert out.returncode == 0 and "slew-rw" in out.stdout and "free-decay" in out.stdout


def test_model_json():
    out = harness("model", "--json")
    assert out.returncode == 0
    report = json.loads(out.stdout)
    assert len(report["constrained_omega_rad_s"]) == 3
    assert abs(report["constrained_freq_hz"][0] - report["constrained_omega_rad_s"][0]
               / 6.283185307179586) < 1e-12


def test_run_json_stdout_is_clean(tmp_path):
    out = harness("run", "slew-rw", "--json", "--duration-s", "3", "--out", str(tmp_path))
    # 3 s is before the slew's profile ends: its settling criterion cannot be judged (ERROR)
    assert out.returncode == 4, out.stderr
    summary = json.loads(out.stdout)  # nothing but JSON on stdout
    assert summary["verdict"] == "ERROR"
    assert summary["ticks"] == 1501
    assert "tick" in out.stderr  # progress went to stderr


def test_bad_run_file_exit_code_and_message(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: bad\nduration_s: -1\ncontroller: {type: hold}\n")
    out = harness_in_process("run", str(bad), "--out", str(tmp_path))
    assert out.returncode == 2
    assert "bad.yaml: duration_s: expected a finite number > 0" in out.stderr
