"""The cluster path: a suite and a sweep on a local Dask cluster of two worker processes
(what a lab's scheduler and workers look like, on loopback)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from in_process import harness_in_process

distributed = pytest.importorskip("distributed")

ENV = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")


@pytest.fixture(scope="module")
def cluster():
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  host="127.0.0.1", dashboard_address=None) as c:
        yield c.scheduler_address


@pytest.mark.slow
def test_suite_runs_on_two_dask_workers(tmp_path, cluster, monkeypatch):
    suite = tmp_path / "cl.yaml"
    suite.write_text(yaml.safe_dump({"name": "cl", "tests": [
        {"run": "slew-rw", "duration_s": 2, "own_expect": False,
         "matrix": {"controller.torque_fraction": [0.5, 0.6, 0.7, 0.8]},
         "expect": {"safe": {"left_safe": True}}}]}))
    out = tmp_path / "out"
    # the address from the environment variable, as a lab would set it; the command in
    # process (tests/in_process.py; `harness test`'s entry point: tests/test_suites.py)
    monkeypatch.setenv("SGSRT_CLUSTER", cluster)
    proc = harness_in_process("test", str(suite), "--out", str(out))
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert f"on dask {cluster}" in proc.stderr
    folder = next(out.glob("*-cl"))
    results = json.loads((folder / "results.json").read_text())
    assert len(results["tests"]) == 4 and {t["verdict"] for t in results["tests"]} == {"PASS"}
    workers = {t["worker"] for t in results["tests"]}
    assert len(workers) == 2 and all(w.startswith("dask:tcp://127.0.0.1:") for w in workers)
    for t in results["tests"]:  # the workers' files came back to the client's folder
        run_dir = folder / t["run_dir"]
        for name in ("run.rrd", "can.blf", "summary.json", "verdict.json"):
            assert (run_dir / name).is_file()


@pytest.mark.slow
def test_sweep_on_the_cluster_matches_local(tmp_path, cluster):
    def sweep(*extra: str, process: bool = True) -> dict:
        args = ["sweep", "--n-lambda", "6", "--n-beta", "3", "--out", str(tmp_path), "--json",
                *extra]
        if process:  # the entry point, as a lab runs it
            proc = subprocess.run([sys.executable, "-m", "harness", *args], capture_output=True,
                                  text=True, timeout=300, env=ENV, check=False)
        else:  # tests/in_process.py: the same command, no second interpreter
            proc = harness_in_process(*args)
        assert proc.returncode == 0, proc.stderr[-2000:]
        return json.loads(proc.stdout)

    on_cluster = sweep("--cluster", cluster)
    local = sweep("--workers", "1", process=False)
    assert on_cluster["engine"].startswith(f"dask {cluster}")
    assert on_cluster["laws"] == local["laws"]
    csvs = sorted(Path(tmp_path).glob("*-sweep/sweep.csv"))
    assert len(csvs) == 2 and csvs[0].read_text() == csvs[1].read_text()
