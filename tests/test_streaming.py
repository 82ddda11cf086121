"""Bounded memory for any run length: streaming statistics, the recorder's blocks, the CAN
log's containers, and what is left after a SIGKILL."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from harness.core.loop import CHANNELS
from harness.core.streaming import LatencyHistogram, RunningSummary
from harness.record.blf_frames import read_blocks
from harness.record.can_log import CanLog, read_can_log
from harness.record.reader import RecordedColumns, read_scalar_channels
from harness.record.recording import Recorder

ROOT = Path(__file__).resolve().parents[1]


def test_histogram_percentiles_match_numpy() -> None:
    rng = np.random.default_rng(1)
    x = np.r_[rng.exponential(50e-6, 50_000), rng.uniform(0.02, 0.5, 30)]
    h = LatencyHistogram()
    for v in x:
        h.add(float(v))
    p = h.percentiles_ms()
    assert p["max"] == pytest.approx(x.max() * 1e3)
    assert p["p50"] == pytest.approx(np.percentile(x, 50) * 1e3, abs=1e-3)  # 1 us bins
    assert p["p99"] == pytest.approx(np.percentile(x, 99) * 1e3, abs=1e-3)
    assert len(h) == len(x)
    assert h.count_above(0.01) == 30
    assert LatencyHistogram().percentiles_ms() == {"p50": 0.0, "p99": 0.0, "max": 0.0}
    # fixed memory: the same number of bins after a million more samples
    n_bins = len(h.counts)
    for _ in range(1000):
        h.add(1e-3)
    assert len(h.counts) == n_bins


def _batch_settle(t, err, band):
    outside = np.nonzero(np.abs(err) > band)[0]
    if len(outside) == 0:
        return float(t[0])
    last = outside[-1]
    return None if last + 1 >= len(t) else float(t[last + 1])


@pytest.mark.parametrize("block", [1, 7, 500, 5000])
def test_running_summary_equals_whole_run_figures(block: int) -> None:
    rng = np.random.default_rng(2)
    n = 3000
    t = np.arange(n) * 0.002
    data = rng.normal(size=(n, len(CHANNELS)))
    ix = {c: i for i, c in enumerate(CHANNELS)}
    target = 10.0
    angle = target - 5 * np.exp(-t) + 0.01 * rng.normal(size=n)
    angle[2900] = target + 1  # one last excursion
    data[:, ix["/attitude/angle_deg"]] = angle
    ref = np.minimum(t * 20, target)
    data[:, ix["/attitude/reference_deg"]] = ref
    rs = RunningSummary(CHANNELS, target, 0.1)
    for k in range(0, n, block):
        rs.update(t[k:k + block], data[k:k + block])
    assert rs.settle_t == _batch_settle(t, target - angle, 0.1) == t[2901]
    assert rs.reach_t == t[np.nonzero(np.abs(ref - target) < 1e-9)[0][0]]
    for ch in ("/tip/accel_m_s2", "/wheel/torque_cmd_n_m"):
        assert rs.max_abs[ch] == np.max(np.abs(data[:, ix[ch]]))
    np.testing.assert_allclose(rs.angle_trend(t), np.polyval(np.polyfit(t, angle, 1), t),
                               atol=1e-9)
    np.testing.assert_array_equal(rs.last_row, data[-1])
    # never settled: outside up to the very last row
    rs2 = RunningSummary(CHANNELS, target, 0.1)
    d2 = data.copy()
    d2[-1, ix["/attitude/angle_deg"]] = 0.0
    for k in range(0, n, block):
        rs2.update(t[k:k + block], d2[k:k + block])
    assert rs2.settle_t is None


def test_recorder_keeps_a_bounded_tail_and_writes_everything(tmp_path: Path) -> None:
    rec = Recorder(tmp_path / "r.rrd", CHANNELS[:3], 0, "test", block_rows=100,
                   retain_rows=250)
    seen = []
    rec.observers.append(lambda t, d: seen.append(len(t)))
    for k in range(1234):
        row = rec.row(k * 0.01)
        row[:] = (k, 2 * k, -k)
        rec.commit()
        rec.drain(1)
        assert rec.pending_blocks <= rec.max_pending_blocks
    tail = rec.column(CHANNELS[0])
    assert 250 <= len(tail) <= 250 + 2 * 100 and tail[-1] == 1233
    np.testing.assert_array_equal(tail, np.arange(1234 - len(tail), 1234))
    rec.close()
    assert sum(seen) == 1234
    back = RecordedColumns(tmp_path / "r.rrd")
    assert back.rows == 1234
    np.testing.assert_array_equal(back.column(CHANNELS[1]), 2 * np.arange(1234))


def test_can_log_flushes_whole_containers(tmp_path: Path) -> None:
    import can

    log = CanLog(tmp_path / "c.blf", flush_every_s=0.5)
    for k in range(5000):
        log.log(can.Message(arbitration_id=0x80, data=k.to_bytes(4, "little"),
                            timestamp=1000.0 + k * 0.001, is_extended_id=False))
        if k % 50 == 49:
            log.drain()
    # not closed (as after a SIGKILL): every flushed container reads back, in order
    size = (tmp_path / "c.blf").stat().st_size
    assert size > 1000
    msgs = read_can_log(tmp_path / "c.blf")
    assert 4000 <= len(msgs) < 5000
    assert [int.from_bytes(m.data, "little") for m in msgs] == list(range(len(msgs)))
    assert log._writer._buffer_size < 32 * 1024 + 100
    log.close()
    assert len(read_can_log(tmp_path / "c.blf")) == 5000


def _run_cmd(out: Path, duration_s: float) -> list[str]:
    return [sys.executable, "-m", "harness", "run", "slew-rw", "--duration-s",
            f"{duration_s:g}", "--out", str(out)]


@pytest.mark.slow
def test_sigkill_leaves_all_but_the_last_blocks_readable(tmp_path: Path) -> None:
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    proc = subprocess.Popen(_run_cmd(tmp_path, 400), cwd=ROOT, env=env,
                            stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True)
    tick = 0
    assert proc.stderr is not None
    for line in proc.stderr:  # progress lines "tick N/M" (not a tty: a few per run)
        if "tick " in line:
            tick = int(line.split("tick ")[1].split("/")[0])
            if tick > 20_000:
                break
    time.sleep(0.2)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert tick > 20_000
    run_dir = next(tmp_path.iterdir())
    assert not (run_dir / "summary.json").exists()
    ch = read_scalar_channels(run_dir / "run.rrd", ["/attitude/angle_deg", "/timing/work_ms"])
    t, _ = ch["/attitude/angle_deg"]
    # a contiguous prefix, at least up to the tick printed minus the unflushed blocks
    assert len(t) >= tick - 3 * 500
    np.testing.assert_allclose(t, np.arange(len(t)) * 0.002, atol=1e-9)
    msgs = read_can_log(run_dir / "can.blf")
    syncs = [m for m in msgs if m.arbitration_id == 0x80]
    assert len(syncs) >= 0.5 * tick  # flushed every second of wall time (~7000 ticks)
    assert [int.from_bytes(m.data[:4], "little") for m in syncs] == list(range(len(syncs)))


_MEM_SCRIPT = """
import json, resource, sys, tempfile
from pathlib import Path
from harness.core.runs import load_run
from harness.core.session import execute_run
from harness.testing import judge_run, write_verdict
out = Path(sys.argv[2])
def run_and_judge(seconds):  # what `harness run` does: the run, then its verdict
    res = execute_run(load_run("slew-rw", {"duration_s": seconds}), out_dir=out,
                      show_progress=False)
    write_verdict(judge_run(res.run_dir), res.run_dir)
    return res
run_and_judge(2.0)
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
res = run_and_judge(float(sys.argv[1]))
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(json.dumps({"base_kb": base, "peak_kb": peak, "run_dir": str(res.run_dir),
                  "ticks": res.summary["ticks"]}))
"""


@pytest.mark.slow
def test_memory_does_not_grow_with_run_length(tmp_path: Path) -> None:
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    res = {}
    for d in (20, 200):
        out = subprocess.run([sys.executable, "-c", _MEM_SCRIPT, str(d), str(tmp_path / str(d))],
                             cwd=ROOT, env=env, capture_output=True, text=True, check=True)
        res[d] = json.loads(out.stdout.strip().splitlines()[-1])
    short, long = res[20], res[200]
    # peak within 10 %, and the run itself (peak over the warmed-up base) grows < 5 MB
    assert long["peak_kb"] <= 1.10 * short["peak_kb"], res
    growth_short = short["peak_kb"] - short["base_kb"]
    growth_long = long["peak_kb"] - long["base_kb"]
    assert growth_long - growth_short < 5_000, res  # a whole-run array would be ~15 MB
    # everything recorded reads back whole
    run_dir = Path(long["run_dir"])
    back = read_scalar_channels(run_dir / "run.rrd", CHANNELS)
    assert all(len(t) == long["ticks"] for t, _ in back.values())
    # read with the review's reader (tests/test_blf_frames.py: python-can's field for
    # field), not a Message a frame: 740 000 frames
    syncs = sum(int(np.count_nonzero((b.arbitration_id == 0x80) & ~b.is_extended_id))
                for b in read_blocks(run_dir / "can.blf"))
    assert syncs == long["ticks"]


def test_histogram_add_repeated_is_n_adds() -> None:
    for x in (0.0, -1e-6, 3.3e-5, 0.02, 7.5):
        one, many = LatencyHistogram(), LatencyHistogram()
        one.add(1e-4)
        many.add(1e-4)
        for _ in range(37):
            one.add(x)
        many.add_repeated(x, 37)
        many.add_repeated(x, 0)
        assert (many.counts, many.n, many.max_s) == (one.counts, one.n, one.max_s)
