"""Many runs in one process (a suite worker, a benchmark) leave nothing behind: threads and
resident memory stay flat after the first runs (the 50-run measurement is
benchmarks/bench_many_runs.py)."""

from __future__ import annotations

import gc
import threading
from pathlib import Path

import pytest

from harness.core.runs import load_run
from harness.core.session import execute_run
from harness.record.recording import Recorder
from harness.review.reader import read_blueprints


def footprint() -> tuple[float, int]:
    """(resident MB, OS threads) of this process, as benchmarks/bench_many_runs.py."""
    status = dict(line.split(":", 1) for line in
                  Path("/proc/self/status").read_text().splitlines() if ":" in line)
    return int(status["VmRSS"].split()[0]) / 1024.0, int(status["Threads"])


def _one_run(out: Path) -> Path:
    res = execute_run(load_run("slew-rw", {"duration_s": 0.1}), out_dir=out,
                      show_progress=False)
    return res.run_dir


@pytest.mark.slow
def test_threads_and_memory_flat_over_runs(tmp_path):
    # Python threads other tests of the session left (a Dask cluster's) are not the runs'
    threads_before = set(threading.enumerate())
    rows = []
    for _ in range(9):
        run_dir = _one_run(tmp_path)
        gc.collect()
        rows.append(footprint())
    # before the fix each run left its recording stream and two blueprint streams alive:
    # 6 OS threads and about 4 MB a run
    ref_mb, ref_threads = rows[3]
    last_mb, last_threads = rows[-1]
    assert last_threads - ref_threads <= 1, rows
    assert last_mb - ref_mb < 8.0, rows  # 5 runs: the leak was about 18 MB
    left = [t.name for t in threading.enumerate() if t not in threads_before]
    assert not left, f"threads the runs left: {left}"
    # the layouts still reach the file: the default one and the final one with the ranges
    assert len(read_blueprints(run_dir / "run.rrd")) == 2


def test_a_closed_recorder_refuses_to_log(tmp_path):
    rec = Recorder(tmp_path / "r.rrd", ["/a"], 10, "r")
    rec.row(0.0)[:] = 1.0
    rec.commit()
    rec.close()
    rec.close()  # idempotent
    with pytest.raises(RuntimeError, match="closed"):
        rec.log_static_text("/x", "late")


def test_judging_many_times_in_one_process_leaves_no_threads(tmp_path):
    """A suite worker judges every run it makes: each judgement writes verdict.rrd and
    appends the verdict to run.rrd, each through a recording stream and a blueprint stream
    that must end with it (before: 2 OS threads left per judgement)."""
    from harness.testing.judge import judge_run, write_verdict

    run_dir = _one_run(tmp_path)
    counts = []
    for _ in range(8):
        write_verdict(judge_run(run_dir), run_dir)
        gc.collect()
        counts.append(footprint()[1])
    assert counts[-1] <= counts[2] + 1, counts
