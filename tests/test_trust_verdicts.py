"""Verdicts that cannot lie: ``--lf`` for bracketed test names, ``harness
logs`` inside suite and calibration folders, ``harness judge --expect`` leaving the run's own
verdict alone, runs without criteria, ``harness test RUN.yaml``, and a refused run leaving
no folder."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from in_process import harness_in_process

ENV = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")


def harness(*args: str, cwd: Path | None = None,
            process: bool = False) -> subprocess.CompletedProcess[str]:
    """`harness ARGS` in this process (tests/in_process.py) unless ``process``: a new
    interpreter, to cover the entry point."""
    if process or cwd is not None:
        return subprocess.run([sys.executable, "-m", "harness", *args], capture_output=True,
                              text=True, env=ENV, cwd=cwd, timeout=300, check=False)
    return harness_in_process(*args)


def results_of(out: Path, name: str) -> dict:
    [folder] = sorted(out.glob(f"*-{name}"))[-1:]
    return json.loads((folder / "results.json").read_text())


@pytest.fixture(scope="module")
def matrix_suite(tmp_path_factory):
    """A suite whose matrix point torque_fraction=0.8 FAILs a torque limit and whose point
    0.5 passes (the profile's torque is still ramping at 3 s: about 0.026 and 0.013 N m
    against 0.02); run once, with --lf after."""
    tmp = tmp_path_factory.mktemp("matrix")
    suite = {"name": "mx", "tests": [{
        "run": "slew-rw", "duration_s": 3, "own_expect": False,
        "matrix": {"controller.torque_fraction": [0.5, 0.8]},
        "expect": {"torque": {"measure": "max_wheel_torque_cmd_n_m", "max_n_m": 0.02}}}]}
    path = tmp / "mx.yaml"
    path.write_text(yaml.safe_dump(suite, sort_keys=False))
    out = tmp / "out"
    first = harness("test", str(path), "--out", str(out), "--workers", "1", "--junit",
                    str(tmp / "junit.xml"))
    return tmp, path, out, first


def test_junit_times_are_the_jobs_and_no_dots_run_into_the_progress_lines(matrix_suite,
                                                                           tmp_path):
    import xml.etree.ElementTree as ET

    _, _, _, first = matrix_suite
    assert "[2/2]" in first.stderr
    # an identification's item comes after its run's, whose setup waited for the job: pytest
    # timed it about 0 (JUnit time="0.000"); its time is the job's
    suite = tmp_path / "ident.yaml"
    suite.write_text(yaml.safe_dump({"name": "ident", "require_criteria": False, "tests": [
        {"run": "slew-rw", "duration_s": 3, "identify": {"n_modes": 1}}]}))
    proc = harness("test", str(suite), "--out", str(tmp_path / "o"), "--workers", "1",
                   "--junit", str(tmp_path / "j.xml"))
    assert proc.returncode in (0, 1, 4), proc.stderr[-2000:]
    times = {c.get("name"): float(c.get("time")) for c in
             ET.parse(tmp_path / "j.xml").iter("testcase")}
    assert set(times) == {"slew-rw", "identify[slew-rw]"}, times
    assert all(t > 0.05 for t in times.values()), times
    assert not any(line.startswith((".F", "F.", "..")) for line in first.stdout.splitlines())


def test_last_failed_reruns_only_the_failed_matrix_point(matrix_suite):
    _, path, out, first = matrix_suite
    assert first.returncode == 1, first.stderr[-2000:]
    by_item = {t["item"]: t["verdict"] for t in results_of(out, "mx")["tests"]}
    assert by_item == {"slew-rw[torque_fraction=0.5]": "PASS",
                       "slew-rw[torque_fraction=0.8]": "FAIL"}
    again = harness("test", str(path), "--out", str(out), "--workers", "1", "--lf")
    assert again.returncode == 1, again.stderr[-2000:]
    assert [t["item"] for t in results_of(out, "mx")["tests"]] == [
        "slew-rw[torque_fraction=0.8]"]


def test_logs_failed_lists_the_failing_runs_inside_a_suite_folder(matrix_suite):
    _, _, out, first = matrix_suite
    assert first.returncode == 1
    proc = harness("logs", "--logs", str(out), "--failed", "--json")
    assert proc.returncode == 0, proc.stderr
    rows = json.loads(proc.stdout)
    assert rows and all(r["run"] == "slew-rw-torque_fraction-0.8" for r in rows)
    assert all(r["verdict"] == "FAIL" and r["group"].endswith("-mx") for r in rows)
    every = json.loads(harness("logs", "--logs", str(out), "--json").stdout)
    assert {r["run"] for r in every} >= {"slew-rw-torque_fraction-0.5",
                                        "slew-rw-torque_fraction-0.8"}
    text = harness("logs", "--logs", str(out), "--failed").stdout
    assert "-mx " in text and "FAIL" in text


def test_a_refused_run_leaves_no_run_folder(tmp_path):
    # a bus that does not open: refused before anything is sent (exit 2), and nothing for
    # 'harness logs --failed' to list as a killed run
    proc = harness("run", "slew-rw", "--bus", "socketcan:nosuch0", "--out", str(tmp_path),
                   "--duration-s", "1")
    assert proc.returncode == 2, proc.stderr
    assert "nosuch0" in proc.stderr and "Traceback" not in proc.stderr
    assert [p for p in tmp_path.iterdir() if p.is_dir()] == []
    # `harness logs` through its entry point
    assert harness("logs", "--logs", str(tmp_path), "--failed", process=True).returncode == 1


def _run_file(tmp: Path, name: str, expect: dict | None) -> Path:
    from harness.core.runs import RUNS_DIR

    raw = yaml.safe_load((RUNS_DIR / "slew-rw.yaml").read_text())
    raw.update(name=name, duration_s=2.0)
    raw.pop("expect", None)
    if expect is not None:
        raw["expect"] = expect
    path = tmp / f"{name}.yaml"
    path.write_text(yaml.safe_dump(raw, sort_keys=False))
    return path


def test_a_run_without_criteria_is_no_criteria_not_pass(tmp_path):
    bare = _run_file(tmp_path, "bare", None)
    out = tmp_path / "logs"
    proc = harness("run", str(bare), "--out", str(out), "--quiet")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "VERDICT NO CRITERIA (exit 0)" in proc.stderr
    assert "WARNING: NO CRITERIA" in proc.stderr
    [run_dir] = [p for p in out.iterdir() if p.is_dir()]
    verdict = json.loads((run_dir / "verdict.json").read_text())
    assert verdict["verdict"] == "NO CRITERIA" and verdict["criteria"] == []
    # not a failure of the run (it completed), but never listed as PASS
    rows = json.loads(harness("logs", "--logs", str(out), "--json").stdout)
    assert [r["verdict"] for r in rows] == ["NO CRITERIA"]

    # a what-if judgement writes nothing unless asked; asked, it is the run's verdict
    strict = tmp_path / "strict.yaml"
    strict.write_text(yaml.safe_dump({"expect": {"tracking": {
        "channel": "/attitude/error_deg", "max_abs_deg": 1e-9}}}))
    proc = harness("judge", str(run_dir), "--expect", str(strict))
    assert proc.returncode == 1 and "VERDICT FAIL" in proc.stdout
    assert "verdict.json left as it was" in proc.stderr
    assert json.loads((run_dir / "verdict.json").read_text())["verdict"] == "NO CRITERIA"
    assert harness("logs", "--logs", str(out), "--failed", "--json").stdout.strip() == "[]"
    proc = harness("judge", str(run_dir), "--expect", str(strict), "--write")
    assert proc.returncode == 1
    assert json.loads((run_dir / "verdict.json").read_text())["verdict"] == "FAIL"
    rows = json.loads(harness("logs", "--logs", str(out), "--failed", "--json").stdout)
    assert [r["verdict"] for r in rows] == ["FAIL"]


def test_a_suite_fails_a_test_without_criteria_unless_it_allows_it(tmp_path):
    bare = _run_file(tmp_path, "bare", None)
    proc = harness("test", str(bare), "--out", str(tmp_path / "a"), "--workers", "1")
    assert proc.returncode == 1, proc.stderr[-2000:]
    [test] = results_of(tmp_path / "a", "bare")["tests"]
    assert test["verdict"] == "FAIL" and test["reason"].startswith("no criteria")
    assert "require_criteria: false" in test["reason"]
    suite = tmp_path / "lenient.yaml"
    suite.write_text(yaml.safe_dump({"name": "lenient", "require_criteria": False,
                                     "tests": [{"run": str(bare)}]}))
    proc = harness("test", str(suite), "--out", str(tmp_path / "b"), "--workers", "1")
    assert proc.returncode == 0, proc.stderr[-2000:]
    doc = results_of(tmp_path / "b", "lenient")
    assert [t["verdict"] for t in doc["tests"]] == ["NO CRITERIA"]
    assert doc["verdict"] == "NO CRITERIA" and doc["exit_code"] == 0


def test_harness_test_runs_a_run_file_as_a_one_test_suite(tmp_path):
    run = _run_file(tmp_path, "short-slew", {"safe": {"left_safe": True}})
    proc = harness("test", str(run), "--out", str(tmp_path), "--workers", "1")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "unknown key" not in proc.stderr
    [test] = results_of(tmp_path, "short-slew")["tests"]
    assert test["item"] == "short-slew" and test["verdict"] == "PASS"
    assert [c["name"] for c in test["criteria"]] == ["safe"]


# ------------------------------------------------------------------ calibrate's criteria
@pytest.mark.slow
def test_the_unshaped_calibration_run_fails_recommended_yaml(sgsrt_wheel_calibration, capsys):
    """The generated criterion must be able to fail: judged by recommended.yaml, the
    unshaped slew of the same calibration must FAIL (and the shaped one PASS); judged by
    baseline.yaml, the shaped slew must FAIL (the baseline no longer unshaped). The session's
    calibration (tests/conftest.py, shared with test_calibrate's end-to-end test)."""
    from harness.cli import main

    assert sgsrt_wheel_calibration.code == 0, sgsrt_wheel_calibration.err[-2000:]
    data = sgsrt_wheel_calibration.data
    runs = Path(data["folder"]) / "runs"
    [unshaped] = runs.glob("*-unshaped")
    rec_key = data["recommended"]
    [shaped] = runs.glob(f"*-{rec_key}")
    measured = next(c for c in data["candidates"] if c["key"] == rec_key)["measured"]

    def judged(run_dir: Path, expect: str) -> tuple[int, dict]:
        capsys.readouterr()
        code = main(["judge", str(run_dir), "--expect", data[expect], "--json"])
        out = capsys.readouterr()
        assert code in (0, 1), out.err[-2000:]
        return code, json.loads(out.out)

    def residual(v: dict) -> dict:
        # recommended.yaml keeps the replaced run's criteria beside the measured one
        return next(c for c in v["criteria"] if c["name"] == "residual_within_calibration")

    code, v = judged(unshaped, "run_file")
    assert code == 1 and v["verdict"] == "FAIL"
    c = residual(v)
    assert c["verdict"] == "FAIL"
    assert [x["name"] for x in v["criteria"] if x["verdict"] != "PASS"] == [c["name"]]
    # it reads what calibrate measured of the unshaped slew: the same fit, the same window
    assert c["value"] == pytest.approx(data["baseline"]["fitted"]["peak_m_s2"], rel=1e-3)
    code, v = judged(shaped, "run_file")
    assert code == 0 and residual(v)["value"] == pytest.approx(
        measured["fitted"]["peak_m_s2"], rel=1e-3)
    code, v = judged(shaped, "baseline_run_file")
    assert code == 1 and v["criteria"][0]["name"] == "vibrates_beyond_shaped_limit"
    assert judged(unshaped, "baseline_run_file")[0] == 0


def test_calibrate_from_the_command_line_refuses_bad_input():
    """`harness calibrate` through its entry point (the calibration itself runs in process,
    once a session): a bad option is one line and exit 2, nothing started."""
    proc = harness("calibrate", "--max-verify", "0", process=True)
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert "--max-verify" in proc.stderr and "Traceback" not in proc.stderr


def test_modal_residual_criterion_refuses_bad_modes():
    from harness.testing import parse_criteria
    from rig_models.schema import ConfigError

    good = {"modal_residual": "/tip/accel_m_s2", "modes": [{"omega_rad_s": 2.9,
                                                            "damping_ratio": 0.07}],
            "after": "slew_profile_end_s", "max_m_s2": 0.003}
    [c] = parse_criteria({"r": good})
    assert c.kind == "modal_residual" and c.limit == {"max": 0.003}
    for change, where in (({"modes": []}, "expect.r.modes"),
                          ({"modes": [{"damping_ratio": 0.1}]}, "expect.r.modes[0].omega_rad_s"),
                          ({"modes": [{"omega_rad_s": 3, "damping_ratio": 1.5}]},
                           "expect.r.modes[0].damping_ratio"),
                          ({"max_m_s2": None, "max_deg": 1}, "expect.r.max_deg")):
        raw = {k: v for k, v in {**good, **change}.items() if v is not None}
        with pytest.raises(ConfigError, match=where.replace("[", r"\[").replace("]", r"\]")):
            parse_criteria({"r": raw})


def test_modal_residual_reads_a_decay_in_blocks_as_whole():
    import numpy as np

    from harness.identification.residual_fit import ModalResidualFit

    rng = np.random.default_rng(3)
    t = np.arange(0, 20, 0.01)
    x = 0.02 * np.exp(-0.07 * 2.9 * (t - 5)) * np.cos(2.9 * (t - 5)) * (t >= 5)
    x = x + 0.005 * rng.standard_normal(len(t))
    whole = ModalResidualFit([(2.9, 0.07)], 5.0)
    whole.add(t, x)
    parts = ModalResidualFit([(2.9, 0.07)], 5.0)
    for i in range(0, len(t), 137):
        parts.add(t[i:i + 137], x[i:i + 137])
    a, b = whole.result(), parts.result()
    assert a.peak == pytest.approx(b.peak, rel=1e-9) and a.samples == b.samples == 1500
    assert a.peak == pytest.approx(0.02, rel=0.1) and a.sigma < 0.002
