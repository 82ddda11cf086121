"""The identification of a recorded run: what ``harness identify`` computes.

A run directory's (or an .rrd's, or a CSV's) tip acceleration is read back, cut into the
free-decay windows of the run's own excitation schedule (from its config.yaml) and
identified window by window (``harness.identification.windows``). After a wheel pulse there
is one window from its end; after ``wheel_bursts`` (or ``valve_bursts``), one window in every
zero-torque gap that a burst's ``free_decay_s`` leaves before the next burst, and one from the
end of the last burst to the end of the record, each starting ``SETTLE_S`` after its burst
(the wheel's torque lag). A CSV or an .rrd without config.yaml is one window over the whole
record.

The model's hub-free modes of the run's rig are set beside each identified mode (the nearest
one), and the spectra with every mode marked are written to ``identify.rrd`` in the run
directory (``harness.review.spectrum``).

Bounded memory: a recording is read block by block (``aligned_scalar_blocks``) and only the
samples of the windows are kept; reading stops once every window is complete. A window is
analysed over at most ``decay_cap_s`` from its start: the last free decay (to the end of the
record) and the whole-record window would otherwise hold a run of any length (16 bytes a
sample: 0.7 GB a day at 500 Hz). The output says where a window was cut (``cut_at_s`` of
each window, and a note). A CSV is a user's file, read whole (``read_accel_csv``); its
windows are cut the same way.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from harness.controllers.registry import WheelBursts, _bursts
from harness.identification.csv_input import read_accel_csv
from harness.identification.windows import (
    AnalysisWindow,
    MultiWindowResult,
    identify_window_segments,
)
from harness.record.output import fresh_output_path
from harness.record.reader import aligned_scalar_blocks
from harness.review.spectrum import write_identify_rrd
from rig_models.paper003 import PAPER_TABLE1
from rig_models.rig_file import rig_from_dict
from rig_models.yaml_file import load_yaml

SETTLE_S = 0.1  # a free-decay window starts this long after its excitation ends


ACCEL_CHANNEL = "/tip/accel_m_s2"

DECAY_CAP_S = 600.0
"""The longest stretch of a window analysed, from its start (s), unless the rig's slowest
mode needs more (``decay_cap_s``). A free decay is a few time constants 1/(zeta omega) long
before it is below the accelerometer's noise: SGSRT's slowest mode (2.88 rad/s, zeta 0.069)
has a time constant of 5.1 s and is under the noise after about 35 s (the free-decay run's
last window), so 600 s is over 100 of its time constants. What follows is noise or rest,
which adds nothing to the fit but samples."""

DECAY_CAP_TIME_CONSTANTS = 20.0
"""A window is analysed over at least this many time constants of the rig's slowest model
mode: its amplitude is then e^-20 = 2e-9 of its start, below any accelerometer's noise."""

SEGMENT_MARGIN_S = 1.0
"""Samples kept on either side of a window (s): ``identify`` cuts the window itself, to the
sample, from a stretch that holds it."""


def decay_cap_s(cfg: dict[str, Any] | None) -> float:
    """How long a window is analysed at most, from its start (s): ``DECAY_CAP_S``, or
    ``DECAY_CAP_TIME_CONSTANTS`` time constants of the slowest damped mode of the run's rig
    (config.yaml's rig) if that is longer."""
    truth = model_modes(cfg)
    rates = [] if truth is None else [
        z * w for w, z in zip(truth["omega_rad_s"], truth["damping_ratio"], strict=True)
        if z * w > 0]
    if not rates:
        return DECAY_CAP_S
    return max(DECAY_CAP_S, DECAY_CAP_TIME_CONSTANTS / min(rates))


@dataclass
class WindowSamples:
    """The samples of a record's free-decay windows (only those), and what was read."""

    windows: list[AnalysisWindow]
    segments: list[tuple[np.ndarray, np.ndarray]]  # (t s, accel m/s^2) holding window k
    cut_at_s: list[float | None]  # where window k's analysis ends early (None: not cut)
    cap_s: float  # a window is analysed over at most this long from its start
    n_read: int  # samples read (the record's, up to where reading stopped)
    first_s: float  # time of the record's first sample
    last_read_s: float  # time of the last sample read
    read_to_end: bool  # False: reading stopped after the last window's samples
    cfg: dict[str, Any] | None
    run_dir: Path | None

    def notes(self) -> list[str]:
        return [f"window {k} {w.label()}: analysed to {cut:.2f} s only ({self.cap_s:g} s "
                "from its start: a free decay is over by then); later samples not read"
                for k, (w, cut) in enumerate(zip(self.windows, self.cut_at_s, strict=True))
                if cut is not None]


def _source(path: Path) -> tuple[Path, dict[str, Any] | None, Path | None]:
    """(run.rrd or CSV, resolved config or None, run dir or None) of a run dir, .rrd or CSV."""
    if path.is_dir():
        rrd, run_dir = path / "run.rrd", path
    elif path.suffix == ".rrd":
        rrd, run_dir = path, path.parent
    else:
        return path, None, None
    if not rrd.exists():
        raise ValueError(f"{path}: no run.rrd (expected a run directory, an .rrd or a CSV)")
    cfg_path = run_dir / "config.yaml"
    # bounded like any YAML input (a hand-edited copy); ConfigError is a ValueError
    cfg = load_yaml(cfg_path, "config.yaml") if cfg_path.exists() else None
    return rrd, cfg, run_dir


def load_windows(path: Path, start_s: float | None = None,
                 windows: list[tuple[float, float | None]] | None = None) -> WindowSamples:
    """The samples of the windows to analyse (``chosen_windows``) of a run directory, an
    .rrd or a CSV: a recording read block by block, keeping only the windows' samples."""
    source, cfg, run_dir = _source(path)
    wins = chosen_windows(cfg, start_s, windows)
    blocks: Iterable[tuple[np.ndarray, np.ndarray]]
    if run_dir is None:
        rec = read_accel_csv(source)  # a user's file, read whole
        blocks = [(np.asarray(rec.t), np.asarray(rec.accel))]
    else:
        blocks = _channel_blocks(source, ACCEL_CHANNEL)
    return collect_windows(blocks, wins, decay_cap_s(cfg), cfg, run_dir)


def _channel_blocks(rrd: Path, entity: str) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    for t, cols in aligned_scalar_blocks(rrd, [entity]):
        yield t, cols[entity]


def collect_windows(blocks: Iterable[tuple[np.ndarray, np.ndarray]],
                    windows: list[AnalysisWindow] | None, cap_s: float,
                    cfg: dict[str, Any] | None = None, run_dir: Path | None = None
                    ) -> WindowSamples:
    """Keep, from (t, values) blocks in time order, the samples of each window (``None``:
    one window from the first sample), ``SEGMENT_MARGIN_S`` on either side, and none past
    ``cap_s`` from a window's start; stop once every window is complete. Holds the
    windows' samples and one block."""
    wins = list(windows) if windows is not None else None
    lo: list[float] = []
    hi: list[float] = []
    limit: list[float] = []
    parts: list[list[tuple[np.ndarray, np.ndarray]]] = []
    n_read, first, last, done = 0, math.nan, math.nan, False
    for t, v in blocks:
        if not len(t):
            continue
        if wins is None:
            wins = [AnalysisWindow(float(t[0]))]
        if not parts:
            first = float(t[0])
            for w in wins:
                limit.append(w.start_s + cap_s)
                lo.append(w.start_s - SEGMENT_MARGIN_S)
                hi.append(limit[-1] if w.end_s is None
                          else min(w.end_s + SEGMENT_MARGIN_S, limit[-1]))
            parts = [[] for _ in wins]
        n_read += len(t)
        last = float(t[-1])
        for k in range(len(wins)):
            i, j = np.searchsorted(t, [lo[k], hi[k]], side="left")
            if j > i:  # copies: the block is let go
                parts[k].append((t[i:j].copy(), np.asarray(v[i:j], dtype=float).copy()))
        if last >= max(hi):
            done = True
            break
    if wins is None or not parts:
        raise ValueError("the record holds no samples")
    segments, cut_at = [], []
    for k, w in enumerate(wins):
        if not parts[k]:
            raise ValueError(f"window {k} {w.label()}: no samples (the record's samples read "
                             f"span [{first:g}, {last:g}] s)")
        segments.append((np.concatenate([p[0] for p in parts[k]]),
                         np.concatenate([p[1] for p in parts[k]])))
        capped = w.end_s is None or w.end_s > limit[k]
        cut_at.append(limit[k] if capped and last >= limit[k] else None)
    return WindowSamples(wins, segments, cut_at, cap_s, n_read, first, last, not done, cfg,
                         run_dir)


def analysis_windows(cfg: dict[str, Any] | None) -> list[AnalysisWindow] | None:
    """The free-decay windows of a run (see the module docstring), else None."""
    if not cfg:
        return None
    c = cfg.get("run", {}).get("controller", {})
    if c.get("type") == "wheel_pulse":
        return [AnalysisWindow(float(c["start_s"] + c["width_s"] + SETTLE_S))]
    if c.get("type") in ("wheel_bursts", "valve_bursts"):
        wb = WheelBursts(c.get("torque_n_m", 1.0), c["start_s"], _bursts(c))
        wins = [AnalysisWindow(t0 + SETTLE_S, t1, omega) for t0, t1, omega in wb.free_intervals
                if t1 - t0 > 2 * SETTLE_S]
        return [*wins, AnalysisWindow(wb.end_s + SETTLE_S, None, wb.last_omega_rad_s)]
    return None


def default_start(cfg: dict[str, Any] | None) -> float | None:
    """Start of a run's final free decay (after all of its excitation), else None."""
    wins = analysis_windows(cfg)
    return None if wins is None else wins[-1].start_s


def chosen_windows(cfg: dict[str, Any] | None, start_s: float | None = None,
                   windows: list[tuple[float, float | None]] | None = None
                   ) -> list[AnalysisWindow] | None:
    """The windows to analyse: one from ``start_s``, or the (start, end) ``windows`` given,
    else the run's own, else None (one window from the record's first sample)."""
    if start_s is not None and windows:
        raise ValueError("give --start-s or --window, not both")
    if start_s is not None:
        return [AnalysisWindow(start_s)]
    if windows:
        return [AnalysisWindow(s, e) for s, e in windows]
    return analysis_windows(cfg)


def model_modes(cfg: dict[str, Any] | None) -> dict[str, list[float]] | None:
    if not cfg or "rig" not in cfg:
        return None
    rig = rig_from_dict(cfg["rig"], source="config.yaml rig")
    wn, zeta = rig.plant.hub_free_modal_damping()
    return {"omega_rad_s": wn.tolist(), "damping_ratio": zeta.tolist()}


def write_spectrum_rrd(run_dir: Path, result: MultiWindowResult,
                       modes: list[dict[str, Any]] | None = None,
                       cfg: dict[str, Any] | None = None) -> Path:
    """identify.rrd in the run directory (harness.review.spectrum): the spectra over
    frequency in Hz, every mode marked, the modes' table, with the run's own layout."""
    # never through a link placed in the run folder (Rerun's file sink follows links)
    return write_identify_rrd(fresh_output_path(run_dir / "identify.rrd"), run_dir, result,
                              modes, cfg)


def _nearest_model_mode(omega: float, truth: dict[str, list[float]]) -> int:
    return int(np.argmin([abs(math.log(omega / w)) for w in truth["omega_rad_s"]]))


def identify_samples(rec: WindowSamples, n_modes: int | None = None,
                     f_max_hz: float | None = None) -> MultiWindowResult:
    """The modes of a record's windows (``identify_window_segments``); a note for every
    window cut at ``rec.cap_s``."""
    result = identify_window_segments(rec.segments, rec.windows, n_modes=n_modes,
                                      f_max_hz=f_max_hz)
    result.notes[:0] = rec.notes()
    return result


def identify_record(rec: WindowSamples, run_dir: Path | None = None,
                    n_modes: int | None = None, f_max_hz: float | None = None
                    ) -> dict[str, Any]:
    """What ``harness identify --json`` prints (also writes identify.rrd in ``run_dir``)."""
    result = identify_samples(rec, n_modes, f_max_hz)
    cfg = rec.cfg
    truth = model_modes(cfg)
    # top-level keys of the long window (fs, fft, fit, ...) as before; modes from all windows
    out = result.primary.to_dict()
    out.update(result.to_dict())
    for w, cut in zip(out["windows"], rec.cut_at_s, strict=True):
        w["cut_at_s"] = cut
    out["record"] = {"samples_read": rec.n_read, "first_s": rec.first_s,
                     "last_read_s": rec.last_read_s, "read_to_end": rec.read_to_end,
                     "window_cap_s": rec.cap_s}
    if truth is not None:
        out["model_hub_free"] = truth
        for m in out["modes"]:
            i = _nearest_model_mode(m["omega_rad_s"], truth)
            m["model_mode"] = i + 1
            m["model_omega_rad_s"] = truth["omega_rad_s"][i]
            m["omega_error_percent"] = 100 * (m["omega_rad_s"] / truth["omega_rad_s"][i] - 1)
            m["model_damping_ratio"] = truth["damping_ratio"][i]
            m["damping_error_percent"] = 100 * (
                m["damping_ratio"] / truth["damping_ratio"][i] - 1)
    out["paper_003_table1_rad_s"] = PAPER_TABLE1
    if run_dir is not None:
        out["spectrum_rrd"] = str(write_spectrum_rrd(run_dir, result, out["modes"], cfg))
    return out


def identify_run(source: Path, n_modes: int | None = None,
                 f_max_hz: float | None = None) -> dict[str, Any]:
    """Identify a run directory (.rrd, CSV) over its own free-decay windows."""
    rec = load_windows(source)
    return identify_record(rec, rec.run_dir, n_modes, f_max_hz)
