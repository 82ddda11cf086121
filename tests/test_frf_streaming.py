"""The frequency responses estimated as the recording is read: the running sums fed block
by block (blocks splitting periods and segments anywhere) give what the whole-array
estimators give, ``harness.core.frf.analyse`` on a generated recording gives the whole-array
result, and its peak memory does not grow with the record's length."""

from __future__ import annotations

import json
import math
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
import rerun as rr
import yaml
from in_process import harness_in_process
from scipy import signal

from harness.controllers.excitation import schroeder_multisine
from harness.core.frf import INPUTS, OUTPUTS, analyse, model_vectors
from harness.identification.frf import (
    PeriodicSpectra,
    WelchSpectra,
    periodic_frf,
    welch_frf,
)
from harness.record.reader import aligned_scalar_blocks, read_scalar_channels
from rig_models.rig_file import load_rig

DT = 0.002


def _signals(n: int, seed: int = 5) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A random input and two outputs: a resonant filter of it plus noise, and noise."""
    rng = np.random.default_rng(seed)
    u = rng.standard_normal(n)
    b, a = signal.iirpeak(3.0, 5.0, fs=1 / DT)
    y1 = signal.lfilter(b, a, u) + 0.05 * rng.standard_normal(n)
    return u, y1, rng.standard_normal(n)


def _feed(acc: PeriodicSpectra | WelchSpectra, u: np.ndarray, ys: list[np.ndarray],
          block: int) -> None:
    for i in range(0, len(u), block):
        acc.add(u[i:i + block], np.vstack([y[i:i + block] for y in ys]))


@pytest.mark.parametrize("block", [1, 7, 1999, 2000, 2001, 4999, 10**6])
def test_periodic_sums_fed_block_by_block_equal_the_whole_array_estimate(block):
    period = 2000
    u, y1, y2 = _signals(5 * period + 1234)  # a last, partial period is left out
    acc = PeriodicSpectra(period, 2)
    _feed(acc, u, [y1, y2], block)
    for y, got in zip((y1, y2), acc.estimates(DT), strict=True):
        ref = periodic_frf(u, y, period, DT)
        assert got.n_avg == ref.n_avg == 5
        assert np.array_equal(got.freq_hz, ref.freq_hz)
        for name in ("h1", "h2", "coherence"):
            assert np.allclose(getattr(got, name), getattr(ref, name), rtol=1e-12, atol=0)


@pytest.mark.parametrize("block", [1, 13, 1500, 3000, 3001, 7777, 10**6])
def test_welch_sums_fed_block_by_block_equal_scipy_welch(block):
    seg = 3000  # half overlap: a segment every 1500 samples
    u, y1, y2 = _signals(11 * 1500 + 700)
    acc = WelchSpectra(seg, 2, DT)
    _feed(acc, u, [y1, y2], block)
    for y, got in zip((y1, y2), acc.estimates(0.5, 40.0), strict=True):
        ref = welch_frf(u, y, DT, seg, 0.5, 40.0)
        assert got.n_avg == ref.n_avg == 10
        assert np.array_equal(got.freq_hz, ref.freq_hz)
        for name in ("h1", "h2", "coherence"):
            assert np.allclose(getattr(got, name), getattr(ref, name), rtol=1e-12, atol=0)
    assert acc.carry.shape[1] < seg  # never more than one segment's samples held


def test_too_short_a_record_is_refused():
    acc = PeriodicSpectra(100, 1)
    acc.add(np.ones(150), np.ones((1, 150)))
    with pytest.raises(ValueError, match="1 whole period"):
        acc.estimates(DT)
    acc = WelchSpectra(100, 1, DT)
    acc.add(np.ones(150), np.ones((1, 150)))
    with pytest.raises(ValueError, match="at least two segments"):
        acc.estimates()


# ---------------------------------------------------------------- a generated recording
IN_CH = INPUTS["wheel"][0]
OUT_CHS = [OUTPUTS["hub_rate"][0], OUTPUTS["tip_accel"][0]]
PERIOD = 2000  # 4 s


def _record(folder: Path, seconds: float, excitation: str, block: int = 2500,
            short: str | None = None) -> Path:
    """A run folder: a wheel-torque input (a multisine of 4 s periods, or noise for a
    Welch analysis) and the rig model's hub rate and tip acceleration, in blocks of ``block`` rows
    as the recorder writes them; config.yaml the sgsrt rig; summary.json the design.
    ``short``: this output loses its last sample."""
    folder.mkdir(parents=True)
    n = int(round(seconds / DT))
    if excitation == "multisine":
        shape, _ = schroeder_multisine(PERIOD, DT, 0.5, 9.0)
        u = 0.05 * np.tile(shape, n // PERIOD + 1)[:n]
        design = {"excitation": "multisine", "signal": "schroeder", "input": "wheel",
                  "period_samples": PERIOD, "measure_start_s": PERIOD * DT,
                  "end_s": n * DT, "f0_hz": 0.5, "f1_hz": 9.0}
    else:
        u = 0.05 * np.random.default_rng(2).standard_normal(n)
        design = {"excitation": "chirp", "input": "wheel", "sweep_s": 4.0,
                  "measure_start_s": 0.0, "end_s": n * DT, "f0_hz": 0.5, "f1_hz": 9.0}
    # the rig model's responses (a circular convolution: the record's steady state)
    rig = load_rig("sgsrt")
    s = 2j * np.pi * np.fft.rfftfreq(n, DT)
    ys = []
    for out in ("hub_rate", "tip_accel"):
        a, b, c, d = model_vectors(rig, "wheel", out)
        h = np.zeros(len(s), dtype=complex)  # DC: none (a zero-mean input)
        eye = np.eye(len(a))
        for k0 in range(1, len(s), 10_000):
            sk = s[k0:k0 + 10_000, None, None]
            h[k0:k0 + len(sk)] = np.linalg.solve(sk * eye - a, b[:, None])[..., 0] @ c + d
        y = np.fft.irfft(np.fft.rfft(u) * h, n) / OUTPUTS[out][1]
        ys.append(y + 1e-3 * np.std(y) * np.sin(1.7 * np.arange(n)))
    rec = rr.RecordingStream("sgsrt-test")
    rec.save(str(folder / "run.rrd"))
    for k0 in range(0, n, block):
        k = np.arange(k0, min(n, k0 + block))
        for e, x in zip([IN_CH, *OUT_CHS], [u, *ys], strict=True):
            if e == short and k[-1] == n - 1:
                k = k[:-1]
            rec.send_columns(e, indexes=[rr.TimeColumn("time", duration=k * DT)],
                             columns=rr.Scalars.columns(scalars=x[k]))
    rec.flush()
    rec.disconnect()
    rig = json.loads(json.dumps(load_rig("sgsrt").data, default=str))
    (folder / "config.yaml").write_text(yaml.safe_dump({"rig": rig}))
    (folder / "summary.json").write_text(json.dumps({"controller_design": design}))
    return folder


@pytest.mark.parametrize("excitation", ["multisine", "random"])
def test_analyse_streams_to_the_whole_array_result(tmp_path, excitation):
    """Chunks of 2500 rows split the 2000-row periods and the Welch segments."""
    run = _record(tmp_path / "r", 60.0, excitation)
    doc = analyse(run, outputs=["hub_rate", "tip_accel"], plot=False)
    chans = read_scalar_channels(run / "run.rrd", [IN_CH, *OUT_CHS])
    t, u = chans[IN_CH]
    dt = doc["dt_s"]  # the record's (its times are whole nanoseconds)
    assert dt == pytest.approx(DT, rel=1e-6)
    for out, ch in zip(("hub_rate", "tip_accel"), OUT_CHS, strict=True):
        y = chans[ch][1] * OUTPUTS[out][1]
        if excitation == "multisine":
            ref = periodic_frf(u[PERIOD:], y[PERIOD:], PERIOD, dt)
        else:
            ref = welch_frf(u, y, dt, int(round(4.0 / dt)), 0.5, 9.0)
        e = doc["outputs"][out]
        assert e["n_avg"] == ref.n_avg > 10
        assert np.array_equal(e["freq_hz"], ref.freq_hz)
        assert np.allclose(e["h1_real"], ref.h1.real, rtol=1e-12, atol=1e-12 * np.abs(
            ref.h1).max())
        assert np.allclose(e["h1_imag"], ref.h1.imag, rtol=1e-12, atol=1e-12 * np.abs(
            ref.h1).max())
        assert np.allclose(e["coherence"], ref.coherence, rtol=1e-12, atol=1e-14)
        assert np.allclose(e["h2_mag"], np.abs(ref.h2), rtol=1e-12)


def _peak_mb(fn) -> float:
    tracemalloc.start()
    try:
        fn()
        return tracemalloc.get_traced_memory()[1] / 1e6
    finally:
        tracemalloc.stop()


@pytest.mark.parametrize("excitation", ["multisine", "random"])
def test_analyse_memory_does_not_grow_with_the_record(tmp_path, excitation):
    """40 s and 400 s (ten times the rows: three channels whole would be 10 MB more) give
    the same peak of Python's allocations."""
    runs = {s: _record(tmp_path / f"r{s}", s, excitation) for s in (40, 400)}
    analyse(runs[40], plot=False)  # the modules it imports, outside the measure
    peaks = {s: _peak_mb(lambda r=run: analyse(r, plot=False)) for s, run in runs.items()}
    held_whole = 3 * 16 * 400 / DT / 1e6  # time and value of three channels, in MB
    assert held_whole > 9
    assert peaks[400] < peaks[40] + 1.0, peaks


def test_blocks_refuse_channels_of_different_lengths(tmp_path):
    run = _record(tmp_path / "r", 12.0, "multisine", short=OUT_CHS[1])
    with pytest.raises(ValueError, match=f"{OUT_CHS[1]} has 5999 rows, {IN_CH} 6000"):
        for _ in aligned_scalar_blocks(run / "run.rrd", [IN_CH, *OUT_CHS]):
            pass
    blocks = list(aligned_scalar_blocks(run / "run.rrd", [IN_CH, OUT_CHS[0]]))
    t = np.concatenate([b[0] for b in blocks])
    assert len(t) == 6000 and np.all(np.diff(t) > 0)
    assert math.isclose(t[-1], 5999 * DT)


def test_frf_tells_its_progress_on_stderr_when_it_takes_long(tmp_path, monkeypatch):
    """An analysis past the command's threshold says what it does; one below it says
    nothing but its table."""
    import harness.commands.frf as command
    import harness.core.frf as core

    run = _record(tmp_path / "r", 40.0, "multisine")
    monkeypatch.setattr(core, "PROGRESS_EVERY_S", 0.0)
    monkeypatch.setattr(command, "PROGRESS_AFTER_S", 0.0)
    res = harness_in_process("frf", str(run), "--no-plot")
    assert res.returncode == 0, res.stderr
    lines = [ln for ln in res.stderr.splitlines() if ln.endswith(" ...")]
    reads = [ln for ln in lines if ln.startswith("harness frf: read ")]
    assert len(reads) >= 5 and reads[-1] == "harness frf: read 40 of 40 s of the record ..."
    assert "harness frf: fitting the modes of wheel -> tip_accel ..." in lines
    monkeypatch.setattr(command, "PROGRESS_AFTER_S", 1e9)
    res = harness_in_process("frf", str(run), "--no-plot")
    assert res.returncode == 0 and not [ln for ln in res.stderr.splitlines()
                                        if ln.endswith(" ...")], res.stderr
