"""`harness identify` holds only the samples of its free-decay windows: a record ten times
longer (the same free decay, then noise) takes the same peak memory, and a window to the end
of the record is analysed over at most ``DECAY_CAP_S`` from its start, the output saying
where it was cut."""

from __future__ import annotations

import tracemalloc
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import rerun as rr

from harness.core.identify import (
    ACCEL_CHANNEL,
    DECAY_CAP_S,
    collect_windows,
    identify_record,
    identify_samples,
    load_windows,
)
from harness.identification.windows import AnalysisWindow, identify_windows
from harness.record.reader import read_scalar_channel

DT = 0.02  # s: 50 Hz keeps the 600 s window's fit quick
BLOCK = 500  # rows a chunk, as the recorder writes a run
MODES = ((2.9, 0.05, 0.08, 0.3), (13.3, 0.01, 0.05, 1.0))  # rad/s, zeta, m/s^2, rad
NOISE_RMS = 0.005  # m/s^2


def _accel(n: int, seed: int = 3) -> np.ndarray:
    """A free decay of two modes from t = 0, then noise: the first samples of any ``n`` are
    the same (one noise sequence drawn block by block)."""
    t = np.arange(n) * DT
    x = np.zeros(n)
    for w, z, amp, phi in MODES:
        wd = w * np.sqrt(1 - z * z)
        x += amp * np.exp(-z * w * t) * np.cos(wd * t + phi)
    rng = np.random.default_rng(seed)
    noise = np.concatenate([rng.standard_normal(BLOCK) for _ in range(-(-n // BLOCK))])
    return x + NOISE_RMS * noise[:n]


def _record(folder: Path, seconds: float) -> Path:
    """An .rrd of the tip acceleration alone (no config.yaml: one window over the record)."""
    folder.mkdir()
    n = int(round(seconds / DT))
    a = _accel(n)
    rec = rr.RecordingStream("sgsrt-test")
    rec.save(str(folder / "run.rrd"))
    for k0 in range(0, n, BLOCK):
        k = np.arange(k0, min(n, k0 + BLOCK))
        rec.send_columns(ACCEL_CHANNEL, indexes=[rr.TimeColumn("time", duration=k * DT)],
                         columns=rr.Scalars.columns(scalars=a[k]))
    rec.flush()
    rec.disconnect()
    return folder / "run.rrd"


def _peak_mb(fn: Callable[[], object]) -> float:
    tracemalloc.start()
    try:
        fn()
        return tracemalloc.get_traced_memory()[1] / 1e6
    finally:
        tracemalloc.stop()


@pytest.fixture(scope="module")
def records(tmp_path_factory: pytest.TempPathFactory) -> dict[int, Path]:
    root = tmp_path_factory.mktemp("identify-memory")
    return {s: _record(root / f"r{s}", s) for s in (700, 7000)}


def test_identify_memory_does_not_grow_with_the_record(records: dict[int, Path]) -> None:
    """700 s and 7000 s (ten times the samples: the whole channel held would be 5 MB more)
    give the same peak of Python's allocations, and the same modes."""
    def run(rrd: Path) -> object:
        return identify_samples(load_windows(rrd))

    def whole(rrd: Path) -> object:  # the channel read whole, the same window fitted
        t, a = read_scalar_channel(rrd, ACCEL_CHANNEL)
        return identify_windows(t, a, [AnalysisWindow(0.0, DECAY_CAP_S)])

    run(records[700])  # the modules it imports, outside the measure
    peaks = {s: _peak_mb(lambda r=rrd: run(r)) for s, rrd in records.items()}
    whole_peak = _peak_mb(lambda: whole(records[7000]))
    assert 16 * int(round(7000 / DT)) / 1e6 > 5.5  # time and value of every sample, in MB
    assert peaks[7000] < peaks[700] + 0.5, peaks
    assert whole_peak > peaks[7000] + 4.0, (whole_peak, peaks)
    short, long = (identify_samples(load_windows(records[s])) for s in (700, 7000))
    assert [(m.omega_rad_s, m.damping_ratio, m.sigma_omega_rad_s) for m in short.modes] == \
        [(m.omega_rad_s, m.damping_ratio, m.sigma_omega_rad_s) for m in long.modes]
    assert [round(m.omega_rad_s, 1) for m in long.modes] == [2.9, 13.3]


def test_a_window_to_the_end_is_cut_and_says_where(records: dict[int, Path]) -> None:
    rec = load_windows(records[7000])
    assert rec.windows == [AnalysisWindow(0.0)]
    assert rec.cut_at_s == [DECAY_CAP_S]
    t, _ = rec.segments[0]
    assert t[-1] < DECAY_CAP_S <= t[-1] + DT
    assert not rec.read_to_end and rec.last_read_s < DECAY_CAP_S + BLOCK * DT
    out = identify_record(rec)
    assert out["windows"][0]["cut_at_s"] == DECAY_CAP_S
    assert out["windows"][0]["duration_s"] == pytest.approx(DECAY_CAP_S)
    assert any(n.startswith("window 0 [0.00, end) s: analysed to 600.00 s only")
               for n in out["notes"])
    # a window that ends before the cap is read to the sample and not cut
    short = load_windows(records[7000], windows=[(10.0, 50.0)])
    assert short.cut_at_s == [None]
    t, _ = short.segments[0]
    assert t[0] <= 10.0 and t[-1] >= 50.0 - DT and t[-1] - t[0] < 45.0


def test_windows_keep_only_their_samples() -> None:
    """Blocks split anywhere give each window its samples and the margin, nothing else."""
    t = np.arange(100_000) * 0.01
    a = np.sin(t)
    wins = [AnalysisWindow(5.0, 7.0, 3.0), AnalysisWindow(20.0)]
    for block in (1, 333, 10**6):
        rec = collect_windows(((t[i:i + block], a[i:i + block])
                               for i in range(0, t.size, block)), wins, 30.0)
        (t0, a0), (t1, a1) = rec.segments
        assert np.array_equal(t0, t[(t >= 4.0) & (t < 8.0)])
        assert np.array_equal(a1, a[(t >= 19.0) & (t < 50.0)])
        assert rec.cut_at_s == [None, 50.0]
        assert rec.last_read_s >= 50.0 and not rec.read_to_end
    whole = collect_windows([(t, a)], [AnalysisWindow(5.0, 7.0)], 30.0)
    assert whole.cut_at_s == [None]
    with pytest.raises(ValueError, match=r"window 0 \[2000.00, end\) s: no samples"):
        collect_windows([(t, a)], [AnalysisWindow(2000.0)], 30.0)
