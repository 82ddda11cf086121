"""Verdicts that cannot lie (issue 24, part A): ``--lf`` for bracketed test names, ``harness
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

ENV = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")


def harness(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "harness", *args], capture_output=True,
                          text=True, env=ENV, cwd=cwd, timeout=300, check=False)


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
    first = harness("test", str(path), "--out", str(out), "--workers", "1")
    return tmp, path, out, first


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
    assert list(tmp_path.iterdir()) == []
    assert harness("logs", "--logs", str(tmp_path), "--failed").returncode == 1
