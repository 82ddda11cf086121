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
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from harness.controllers.registry import WheelBursts, _bursts
from harness.identification.csv_input import read_accel_csv
from harness.identification.windows import AnalysisWindow, MultiWindowResult, identify_windows
from harness.record.output import fresh_output_path
from harness.record.reader import read_scalar_channel
from harness.review.spectrum import write_identify_rrd
from rig_models.paper003 import PAPER_TABLE1
from rig_models.rig_file import rig_from_dict
from rig_models.yaml_file import load_yaml

SETTLE_S = 0.1  # a free-decay window starts this long after its excitation ends


def load_record(path: Path) -> tuple[np.ndarray, np.ndarray, dict[str, Any] | None, Path | None]:
    """(t, accel, resolved config or None, run dir or None) from a run dir, .rrd or CSV."""
    if path.is_dir():
        rrd, run_dir = path / "run.rrd", path
    elif path.suffix == ".rrd":
        rrd, run_dir = path, path.parent
    else:
        rec = read_accel_csv(path)
        return np.asarray(rec.t), np.asarray(rec.accel), None, None
    if not rrd.exists():
        raise ValueError(f"{path}: no run.rrd (expected a run directory, an .rrd or a CSV)")
    t, a = read_scalar_channel(rrd, "/tip/accel_m_s2")
    cfg_path = run_dir / "config.yaml"
    # bounded like any YAML input (a hand-edited copy); ConfigError is a ValueError
    cfg = load_yaml(cfg_path, "config.yaml") if cfg_path.exists() else None
    return t, a, cfg, run_dir


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


def chosen_windows(t: np.ndarray, cfg: dict[str, Any] | None, start_s: float | None = None,
                   windows: list[tuple[float, float | None]] | None = None
                   ) -> list[AnalysisWindow]:
    """The windows to analyse: one from ``start_s``, or the (start, end) ``windows`` given,
    else the run's own, else one over the whole record."""
    if start_s is not None and windows:
        raise ValueError("give --start-s or --window, not both")
    if start_s is not None:
        return [AnalysisWindow(start_s)]
    if windows:
        return [AnalysisWindow(s, e) for s, e in windows]
    return analysis_windows(cfg) or [AnalysisWindow(float(t[0]))]


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


def identify_record(t: np.ndarray, a: np.ndarray, cfg: dict[str, Any] | None,
                    run_dir: Path | None, windows: list[AnalysisWindow],
                    n_modes: int | None = None, f_max_hz: float | None = None
                    ) -> dict[str, Any]:
    """What ``harness identify --json`` prints (also writes identify.rrd in ``run_dir``)."""
    result = identify_windows(t, a, windows, n_modes=n_modes, f_max_hz=f_max_hz)
    truth = model_modes(cfg)
    # top-level keys of the long window (fs, fft, fit, ...) as before; modes from all windows
    out = result.primary.to_dict()
    out.update(result.to_dict())
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
    t, a, cfg, run_dir = load_record(source)
    windows = analysis_windows(cfg) or [AnalysisWindow(float(t[0]))]
    return identify_record(t, a, cfg, run_dir, windows, n_modes, f_max_hz)
