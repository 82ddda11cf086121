"""`harness identify RUN_DIR|RRD|CSV [--json]`: vibration modes from the tip accelerometer.

Two views side by side: the paper's (peaks of the windowed, zero-padded FFT of the free
decay, interpolated) and a parametric fit of the free decay (matrix pencil, then nonlinear
least squares) with damping and 1-sigma uncertainties.

Free-decay windows. For a run directory they come from its config.yaml: after a wheel pulse,
one window from its end; after ``wheel_bursts`` (or
``valve_bursts``), one window in every zero-torque gap that a
burst's ``free_decay_s`` leaves before the next burst, and one from the end of the last burst
to the end of the record (each window starts 0.1 s after its burst, for the wheel's torque
lag). Each window is fitted on its own. Windows after bursts of the same nominal frequency
(``repeat``) are repetitions of one experiment: their estimates of a mode are averaged
(1 sigma scaled up by the Birge ratio if they scatter more than their sigmas say). Each mode
is reported from the experiment that determines it best, and only if it is determined
(frequency to 5 %, damping to 50 %, found in half the repetitions; other components are
listed in the notes). A mode found in one window is held (frequency and damping fixed,
amplitude fitted) in the windows that do not show it, so that its leftover does not bias
theirs (``harness.identification.windows``). So the free-decay run's seven 1.9 s decays
after its mode-3 bursts give mode 3 (36.9 rad/s, gone in about 2 s), and the long decay
after the mode-1 and mode-2 bursts gives modes 1 and 2. ``--start-s`` (one window from
there) or ``--window START:END`` (repeatable, each its own experiment) override the run's
windows; a CSV or an .rrd without config.yaml is one window over the whole record.

The FFT view of a short window does not resolve a fast-decaying mode (for mode 3 its
Rayleigh resolution, 3.3 rad/s, is about the peak's half-power width): its FFT peak and
half-power damping are then averaged over the repetitions and marked rough in a note; the
parametric fit is the estimate.

The model's true hub-free modes of the run's rig are printed beside ours (each identified
mode against the nearest model mode). The spectra and the picked peaks are written to
``identify.rrd`` in the run directory, as bar charts over frequency in Hz with every mode
marked, with the run's own layout: open it together with run.rrd (same recording id), in
either order (docs/review.md).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

from harness.identification.csv_input import read_accel_csv
from harness.identification.windows import AnalysisWindow, MultiWindowResult, identify_windows
from harness.record.reader import read_scalar_channel
from rig_models.rig_file import rig_from_dict
from rig_models.yaml_file import load_yaml

# Paper 003 Table 1 (rad/s), comparison only.
PAPER_TABLE1 = {"measured_fft": [2.7382, 13.9487], "calculated": [2.8081, 13.643]}
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
        from harness.controllers.registry import WheelBursts, _bursts

        wb = WheelBursts(c.get("torque_n_m", 1.0), c["start_s"], _bursts(c))
        wins = [AnalysisWindow(t0 + SETTLE_S, t1, omega) for t0, t1, omega in wb.free_intervals
                if t1 - t0 > 2 * SETTLE_S]
        return [*wins, AnalysisWindow(wb.end_s + SETTLE_S, None, wb.last_omega_rad_s)]
    return None


def default_start(cfg: dict[str, Any] | None) -> float | None:
    """Start of a run's final free decay (after all of its excitation), else None."""
    wins = analysis_windows(cfg)
    return None if wins is None else wins[-1].start_s


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
    from harness.record.output import fresh_output_path
    from harness.review.spectrum import write_identify_rrd

    # never through a link placed in the run folder (Rerun's file sink follows links)
    return write_identify_rrd(fresh_output_path(run_dir / "identify.rrd"), run_dir, result,
                              modes, cfg)


def _window_arg(text: str) -> tuple[float, float | None]:
    try:
        start, _, end = text.partition(":")
        return float(start), (float(end) if end.strip() else None)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected START_S:END_S (END_S may be empty), got {text!r}") from None


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("identify", help="identify vibration modes from the tip accelerometer",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("source", type=Path, help="run directory, run.rrd, or CSV of time,accel")
    p.add_argument("--start-s", type=float,
                   help="one free decay from this time (s) to the end, instead of the run's "
                        "windows")
    p.add_argument("--window", type=_window_arg, action="append", metavar="START_S:END_S",
                   help="a free-decay window (s; END_S empty: to the end of the record); "
                        "repeat for several, each analysed on its own")
    p.add_argument("--n-modes", type=int,
                   help="report the N lowest modes (default: every mode identified)")
    p.add_argument("--f-max-hz", type=float, help="upper edge of the analysed band (Hz)")
    p.add_argument("--json", action="store_true", help="JSON on stdout")
    p.set_defaults(func=cmd_identify)


def _windows(args: argparse.Namespace, t: np.ndarray,
             cfg: dict[str, Any] | None) -> list[AnalysisWindow]:
    if args.start_s is not None and args.window:
        raise ValueError("give --start-s or --window, not both")
    if args.start_s is not None:
        return [AnalysisWindow(args.start_s)]
    if args.window:
        return [AnalysisWindow(s, e) for s, e in args.window]
    return analysis_windows(cfg) or [AnalysisWindow(float(t[0]))]


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


def cmd_identify(args: argparse.Namespace) -> int:
    try:
        if args.n_modes is not None and args.n_modes < 1:
            raise ValueError(f"--n-modes must be >= 1, got {args.n_modes}")
        t, a, cfg, run_dir = load_record(args.source)
        windows = _windows(args, t, cfg)
        print(f"harness identify: {len(t)} samples, {t[-1] - t[0]:.1f} s, free decay"
              f"{'s' if len(windows) > 1 else ''} "
              f"{', '.join(w.label() for w in windows)} ...", file=sys.stderr)
        out = identify_record(t, a, cfg, run_dir, windows, args.n_modes, args.f_max_hz)
    except (ValueError, OSError) as exc:
        print(f"harness identify: {exc}", file=sys.stderr)
        return 2
    if run_dir is not None:
        from harness.history.record import record_identify  # the results database

        record_identify(run_dir, out)
    if args.json:
        print(json.dumps(out, indent=2, default=float))
        return 0
    print(f"{'mode':>4} {'fit rad/s':>10} {'+-':>8} {'Hz':>8} {'zeta':>7} {'+-':>7} "
          f"{'FFT rad/s':>10} {'model rad/s':>11} {'model zeta':>10} {'paper meas.':>11} "
          f"{'paper calc.':>11}")
    nan = float("nan")
    for i, m in enumerate(out["modes"]):
        fft = m.get("fft_peak_omega_rad_s")
        j = m.get("model_mode", i + 1) - 1
        print(f"{i + 1:>4} {m['omega_rad_s']:>10.4f} {m['sigma_omega_rad_s']:>8.4f} "
              f"{m['freq_hz']:>8.4f} {m['damping_ratio']:>7.4f} {m['sigma_damping']:>7.4f} "
              f"{fft if fft is not None else nan:>10.4f} "
              f"{m.get('model_omega_rad_s', nan):>11.4f} "
              f"{m.get('model_damping_ratio', nan):>10.4f} "
              f"{PAPER_TABLE1['measured_fft'][j] if j < 2 else nan:>11.4f} "
              f"{PAPER_TABLE1['calculated'][j] if j < 2 else nan:>11.4f}")
    if len(windows) > 1:
        for i, m in enumerate(out["modes"]):
            src = m["source"]
            birge = (f" (Birge ratio {src['birge_ratio_omega']:.2f} / "
                     f"{src['birge_ratio_damping']:.2f})" if src["n_windows"] > 1 else "")
            print(f"mode {i + 1} from {src['experiment']}{birge}")
    for note in out.get("notes", []):
        print(f"note: {note}")
    return 0
