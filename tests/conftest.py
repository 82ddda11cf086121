from __future__ import annotations

import os

# one BLAS thread: on these shared 2-core machines threaded BLAS made small solves 5x slower
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

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
