from __future__ import annotations

import os

# Python's bytecode cache on for the tests and every process they start. This machine's
# environment sets PYTHONDONTWRITEBYTECODE=1, and a fresh clone has no __pycache__: every
# process the tests start (harness commands, suite workers, studies: a few hundred) compiled
# the harness from source again, about 0.2 s of CPU each. What is written is
# Python's own __pycache__ beside the sources (ignored by git); a read-only tree is skipped.
os.environ.pop("PYTHONDONTWRITEBYTECODE", None)

# one BLAS thread: on these shared 2-core machines threaded BLAS made small solves 5x slower
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import json
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

from harness.core.runs import load_run
from harness.core.session import RunResult, execute_run

sys.dont_write_bytecode = False  # this process too, from here on (the test modules)


@pytest.fixture(scope="session")
def slew_result(tmp_path_factory):
    """One full slew-rw run on the in-process virtual rig, shared by several tests."""
    out = tmp_path_factory.mktemp("logs")
    return execute_run(load_run("slew-rw"), out_dir=Path(out), show_progress=False)


def pytest_collection_finish(session: pytest.Session) -> None:
    """Note the fixtures the selected tests use (after ``-m`` / ``-k``), so that a session
    fixture can borrow a run another session fixture makes anyway (``free_decay_run``)."""
    session.config.stash[USED_FIXTURES] = frozenset(
        name for item in session.items for name in getattr(item, "fixturenames", ()))


USED_FIXTURES = pytest.StashKey[frozenset]()

# Session fixtures that cost minutes (the four paper suites, 160 s on a quiet 2-core
# machine) are built once per process. Under pytest-xdist's `--dist loadgroup` every test
# that uses one goes to the same worker, so the suites run once, not once per worker
# (``free_decay_run`` borrows the suites' free decay, so its tests go there too). The
# PostgreSQL tests share CI's one database (each starts by dropping its tables): one
# worker runs them, one after the other.
SHARED_FIXTURE_GROUPS = {"paper_suites": "paper_suites", "free_decay_run": "paper_suites",
                         "sgsrt_wheel_calibration": "calibration", "pg_url": "postgresql"}


@pytest.hookimpl(tryfirst=True)  # before xdist reads the groups
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        for name in getattr(item, "fixturenames", ()):
            if name in SHARED_FIXTURE_GROUPS:
                item.add_marker(pytest.mark.xdist_group(SHARED_FIXTURE_GROUPS[name]))
                break
# a run directory's own files, as execute_run leaves them (not what judging or identifying
# it adds: verdict.*, identify.*)
RUN_FILES = ("run.rrd", "can.blf", "config.yaml", "summary.json", "layout.json")


def _suites_free_decay(paper_suites: PaperSuites, out: Path) -> RunResult | None:
    """paper003's free-decay run (the built-in run file as it is, on the sgsrt rig: the same
    frames and recording as ``execute_run(load_run("free-decay"))``; only the bus's name
    and the wall times in summary.json differ), copied without what judging and identifying
    it added, or None if the suites left none."""
    found = sorted(paper_suites.out.glob("*/*-free-decay"))
    if len(found) != 1 or not all((found[0] / f).is_file() for f in RUN_FILES):
        return None
    run_dir = out / found[0].name
    run_dir.mkdir()
    for f in RUN_FILES:
        shutil.copy2(found[0] / f, run_dir / f)
    summary = json.loads((run_dir / "summary.json").read_text())
    if summary.get("stopped_by") != "completed":
        return None
    return RunResult(run_dir=run_dir, summary=summary, stats=None, recorder=None,
                     virtual_rig=None)


@pytest.fixture(scope="session")
def free_decay_run(request, tmp_path_factory) -> RunResult:
    """One full free-decay run (70 s simulated, accelerometer noise on), shared by the
    identification tests and the shaped-rig study's identification test: paper003's when
    the session runs the paper suites anyway (``paper_suites``, which runs that same run
    file), else run here. Its run directory, summary and ``columns()``; no loop statistics
    or virtual rig (``load_run("free-decay").rig`` is its rig)."""
    out = Path(tmp_path_factory.mktemp("free_decay"))
    if "paper_suites" in request.config.stash.get(USED_FIXTURES, frozenset()):
        res = _suites_free_decay(request.getfixturevalue("paper_suites"), out)
        if res is not None:
            return res
    res = execute_run(load_run("free-decay"), out_dir=out, show_progress=False)
    assert res.run_dir.exists()
    return RunResult(run_dir=res.run_dir, summary=res.summary, stats=None, recorder=None,
                     virtual_rig=None)


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
