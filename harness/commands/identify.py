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

Only the windows' samples are read and held, and a window is analysed over at most 600 s
from its start (or 20 time constants 1/(zeta omega) of the rig's slowest model mode, if
longer): a free decay is over by then, and the rest of a long run's record (noise or rest)
would only take memory. A window so cut is named on stderr, with ``cut_at_s`` in its JSON
entry and a note.

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
import sys
from pathlib import Path

from harness.commands import examples


def _window_arg(text: str) -> tuple[float, float | None]:
    try:
        start, _, end = text.partition(":")
        return float(start), (float(end) if end.strip() else None)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected START_S:END_S (END_S may be empty), got {text!r}") from None


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("identify", help="identify vibration modes from the tip accelerometer",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter,
                       epilog=examples("harness identify logs/20260101T120000.000000Z-free-decay",
                                       "harness identify run.rrd --window 2:4 --window 6:8 --json",
                                       "harness identify accel.csv --start-s 1.5 --n-modes 2"))
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


def cmd_identify(args: argparse.Namespace) -> int:
    # numpy, scipy and Rerun only when a command identifies (start-up of `harness --help`)
    from harness.core.identify import identify_record, load_windows
    from rig_models.paper003 import PAPER_TABLE1

    try:
        if args.n_modes is not None and args.n_modes < 1:
            raise ValueError(f"--n-modes must be >= 1, got {args.n_modes}")
        rec = load_windows(args.source, args.start_s, args.window)
        run_dir, windows = rec.run_dir, rec.windows
        span = rec.last_read_s - rec.first_s
        read = (f"{rec.n_read} samples, {span:.1f} s" if rec.read_to_end
                else f"{rec.n_read} samples read ({span:.1f} s, to the windows' end)")
        labels = [w.label() + ("" if cut is None else f" cut at {cut:.2f} s")
                  for w, cut in zip(windows, rec.cut_at_s, strict=True)]
        print(f"harness identify: {read}, free decay{'s' if len(windows) > 1 else ''} "
              f"{', '.join(labels)} ...", file=sys.stderr)
        out = identify_record(rec, run_dir, args.n_modes, args.f_max_hz)
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
