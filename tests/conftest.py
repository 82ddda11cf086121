from __future__ import annotations

import os

# one BLAS thread: on these shared 2-core machines threaded BLAS made small solves 5x slower
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import json
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

from harness.core.runs import load_run
from harness.core.session import execute_run


@pytest.fixture(scope="session")
def slew_result(tmp_path_factory):
    """One full slew-rw run on the in-process virtual rig, shared by several tests."""
    out = tmp_path_factory.mktemp("logs")
    return execute_run(load_run("slew-rw"), out_dir=Path(out), show_progress=False)


@pytest.fixture(scope="session")
def free_decay_run(tmp_path_factory):
    """One full free-decay run (70 s simulated, accelerometer noise on), shared by the
    identification tests and the shaped-rig study's identification test."""
    out = tmp_path_factory.mktemp("free_decay")
    res = execute_run(load_run("free-decay"), out_dir=Path(out), show_progress=False)
    assert res.run_dir.exists()
    return res


@dataclass
class PaperSuites:
    """One run of the four paper suites (``harness test paper001 ... paper004``), shared by
    every test that checks a paper study's claims, so that no study runs twice in a
    session: the suites' own verdicts (tests/test_paper_suites.py) and the unit tests that
    read a study's full results (its ``document`` in results.json)."""

    out: Path
    returncode: int
    log: str
    documents: dict[str, dict]  # item (e.g. "shaped-rig-wheel") -> the study's results

    def document(self, item: str) -> dict:
        assert item in self.documents, f"{item}: not in the paper suites' results " \
                                       f"({self.log[-2000:]})"
        return self.documents[item]


@pytest.fixture(scope="session")
def paper_suites(tmp_path_factory) -> PaperSuites:
    from harness.testing.results_docs import PAPER_SUITES

    out = Path(tmp_path_factory.mktemp("paper_suites"))
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    proc = subprocess.run([sys.executable, "-m", "harness", "test", *PAPER_SUITES, "--out",
                           str(out)], capture_output=True, text=True, timeout=1500,
                          env=env, cwd=out)
    documents: dict[str, dict] = {}
    for results in out.glob("*/results.json"):
        for test in json.loads(results.read_text())["tests"]:
            if isinstance(test.get("document"), dict):
                documents[test["item"]] = test["document"]
    return PaperSuites(out, proc.returncode, proc.stdout[-3000:] + proc.stderr[-3000:],
                       documents)


@dataclass
class Calibration:
    """One ``harness calibrate --json --max-verify 2`` of the sgsrt rig's wheel, in process:
    its exit code, the printed JSON and its progress lines."""

    code: int
    data: dict
    err: str


@pytest.fixture(scope="session")
def sgsrt_wheel_calibration(tmp_path_factory) -> Calibration:
    """The wheel calibration of the default rig, shared (read-only: judging it with
    ``--expect`` writes nothing) by the calibrate end-to-end test and the test that its
    generated criteria can fail (tests/test_trust_verdicts.py), so it runs once."""
    import io
    from contextlib import redirect_stderr, redirect_stdout

    from harness.cli import main

    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        code = main(["calibrate", "--json", "--max-verify", "2", "--out",
                     str(tmp_path_factory.mktemp("calibration"))])
    return Calibration(code, json.loads(out.getvalue()) if code == 0 else {}, err.getvalue())
