"""`harness identify RUN_DIR|RRD|CSV [--json]`: vibration modes from the tip accelerometer.

Two views side by side: the paper's (peaks of the windowed, zero-padded FFT of the free
decay, interpolated) and a parametric fit of the free decay (matrix pencil, then nonlinear
least squares) with damping and 1-sigma uncertainties. For a run directory the free decay
starts after the wheel pulse (from its config.yaml) unless ``--start-s`` says otherwise, and
the model's true hub-free modes of the run's rig are printed beside ours. The spectrum and
the picked peaks are written to ``identify.rrd`` in the run directory (open it together with
run.rrd: same recording id).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from harness.identification import identify
from harness.identification.csv_input import read_accel_csv
from harness.recording_reader import read_scalar_channel
from rig_models.rig_file import rig_from_dict

# Paper 003 Table 1 (rad/s), comparison only.
PAPER_TABLE1 = {"measured_fft": [2.7382, 13.9487], "calculated": [2.8081, 13.643]}


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
    cfg = yaml.safe_load(cfg_path.read_text()) if cfg_path.exists() else None
    return t, a, cfg, run_dir


def default_start(cfg: dict[str, Any] | None) -> float | None:
    """End of the excitation of a wheel-pulse run (plus 0.1 s), else None."""
    if not cfg:
        return None
    c = cfg.get("run", {}).get("controller", {})
    if c.get("type") == "wheel_pulse":
        return float(c["start_s"] + c["width_s"] + 0.1)
    if c.get("type") == "wheel_bursts":
        from harness.controllers.registry import WheelBursts, _bursts

        return float(WheelBursts(c["torque_n_m"], c["start_s"], _bursts(c)).end_s + 0.1)
    return None


def model_modes(cfg: dict[str, Any] | None) -> dict[str, list[float]] | None:
    if not cfg or "rig" not in cfg:
        return None
    rig = rig_from_dict(cfg["rig"], source="config.yaml rig")
    wn, zeta = rig.plant.hub_free_modal_damping()
    return {"omega_rad_s": wn.tolist(), "damping_ratio": zeta.tolist()}


def write_spectrum_rrd(run_dir: Path, result: Any) -> Path:
    import rerun as rr
    import rerun.blueprint as rrb

    path = run_dir / "identify.rrd"
    rec = rr.RecordingStream("sgsrt-harness", recording_id=run_dir.name)
    bp = rrb.Blueprint(rrb.Spatial2DView(origin="/identify", name="Spectrum (Hz, m/s^2)"))
    rec.save(str(path), default_blueprint=bp)
    sp = result.spectrum
    sel = sp.freq_hz <= max(10.0, 3 * max((p.freq_hz for p in result.fft_peaks), default=1.0))
    pts = np.column_stack([sp.freq_hz[sel], sp.amplitude[sel]])
    rec.log("/identify/spectrum", rr.LineStrips2D([pts], colors=[[80, 160, 255]]), static=True)
    peaks = np.array([[p.freq_hz, p.amplitude] for p in result.fft_peaks]).reshape(-1, 2)
    rec.log("/identify/fft_peaks", rr.Points2D(
        peaks, radii=0.02, colors=[[255, 80, 80]],
        labels=[f"{p.omega_rad_s:.4f} rad/s" for p in result.fft_peaks]), static=True)
    fits = np.array([[m.omega_damped_rad_s / (2 * math.pi), 0.0] for m in result.modes])
    rec.log("/identify/fitted_modes", rr.Points2D(
        fits.reshape(-1, 2), radii=0.03, colors=[[60, 200, 60]],
        labels=[f"fit {m.omega_rad_s:.4f} rad/s, zeta {m.damping_ratio:.4f}"
                for m in result.modes]), static=True)
    rec.flush()
    rec.disconnect()
    return path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("identify", help="identify vibration modes from the tip accelerometer",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("source", type=Path, help="run directory, run.rrd, or CSV of time,accel")
    p.add_argument("--start-s", type=float, help="start of the free decay (s)")
    p.add_argument("--n-modes", type=int, default=2, help="modes to report (default 2)")
    p.add_argument("--f-max-hz", type=float, help="upper edge of the analysed band (Hz)")
    p.add_argument("--json", action="store_true", help="JSON on stdout")
    p.set_defaults(func=cmd_identify)


def cmd_identify(args: argparse.Namespace) -> int:
    try:
        t, a, cfg, run_dir = load_record(args.source)
        start = args.start_s if args.start_s is not None else default_start(cfg)
        print(f"harness identify: {len(t)} samples, {t[-1] - t[0]:.1f} s, free decay from "
              f"{start if start is not None else t[0]:.2f} s ...", file=sys.stderr)
        result = identify(t, a, n_modes=args.n_modes, f_max_hz=args.f_max_hz, start_s=start)
        truth = model_modes(cfg)
    except (ValueError, OSError) as exc:
        print(f"harness identify: {exc}", file=sys.stderr)
        return 2
    out = result.to_dict()
    if truth is not None:
        out["model_hub_free"] = truth
        for i, m in enumerate(out["modes"]):
            if i < len(truth["omega_rad_s"]):
                m["model_omega_rad_s"] = truth["omega_rad_s"][i]
                m["omega_error_percent"] = 100 * (m["omega_rad_s"] / truth["omega_rad_s"][i] - 1)
                m["model_damping_ratio"] = truth["damping_ratio"][i]
                m["damping_error_percent"] = 100 * (
                    m["damping_ratio"] / truth["damping_ratio"][i] - 1)
    out["paper_003_table1_rad_s"] = PAPER_TABLE1
    if run_dir is not None:
        out["spectrum_rrd"] = str(write_spectrum_rrd(run_dir, result))
    if args.json:
        print(json.dumps(out, indent=2, default=float))
        return 0
    print(f"{'mode':>4} {'fit rad/s':>10} {'+-':>8} {'Hz':>8} {'zeta':>7} {'+-':>7} "
          f"{'FFT rad/s':>10} {'model rad/s':>11} {'model zeta':>10} {'paper meas.':>11} "
          f"{'paper calc.':>11}")
    for i, m in enumerate(out["modes"]):
        fft = m.get("fft_peak_omega_rad_s")
        print(f"{i + 1:>4} {m['omega_rad_s']:>10.4f} {m['sigma_omega_rad_s']:>8.4f} "
              f"{m['freq_hz']:>8.4f} {m['damping_ratio']:>7.4f} {m['sigma_damping']:>7.4f} "
              f"{fft if fft is not None else float('nan'):>10.4f} "
              f"{m.get('model_omega_rad_s', float('nan')):>11.4f} "
              f"{m.get('model_damping_ratio', float('nan')):>10.4f} "
              f"{PAPER_TABLE1['measured_fft'][i] if i < 2 else float('nan'):>11.4f} "
              f"{PAPER_TABLE1['calculated'][i] if i < 2 else float('nan'):>11.4f}")
    for note in out.get("notes", []):
        print(f"note: {note}")
    return 0
